"""Domain errors: each carries its HTTP status and its wire name; one handler renders them all.

The body is always ``{"error": <name>, "detail": <sentence>}`` (plus ``fields`` for validation);
the HTTP layer adds the request's ``request_id``.
Nothing here imports FastAPI: services raise these, ``app.api.errors`` turns them into responses.
What the HTTP layer refuses before any use case runs is answered there, with the same body: a
body over the size limit (413 ``PayloadTooLarge``, ``app.api.middleware``), an unknown path or
method.
"""

from __future__ import annotations

from typing import Any, ClassVar

__all__ = [
    "AppError",
    "BadRequest",
    "Conflict",
    "Forbidden",
    "NotFound",
    "ServiceUnavailable",
    "TooManyRequests",
    "Unauthorized",
    "UnsupportedMediaType",
    "ValidationFailed",
]


class AppError(Exception):
    """Base of the errors a client can act on."""

    status_code: ClassVar[int] = 500
    error: ClassVar[str] = "InternalError"

    def __init__(self, detail: str, *, fields: list[dict[str, Any]] | None = None) -> None:
        super().__init__(detail)
        self.detail = detail
        self.fields = fields

    def headers(self) -> dict[str, str]:
        """Response headers the error adds (``WWW-Authenticate`` for 401, ``Retry-After`` for
        429 and 503)."""
        return {}


class BadRequest(AppError):
    status_code = 400
    error = "BadRequest"


class Unauthorized(AppError):
    """No key, or an unknown or revoked one; the answer says how to send a key
    (``WWW-Authenticate: Bearer``, RFC 6750)."""

    status_code = 401
    error = "Unauthorized"

    def headers(self) -> dict[str, str]:
        return {"WWW-Authenticate": "Bearer"}


class Forbidden(AppError):
    status_code = 403
    error = "Forbidden"


class NotFound(AppError):
    status_code = 404
    error = "NotFound"


class Conflict(AppError):
    status_code = 409
    error = "Conflict"


class UnsupportedMediaType(AppError):
    """A JSON body sent as something else (text/plain, a form, multipart, or no type)."""

    status_code = 415
    error = "UnsupportedMediaType"


class TooManyRequests(AppError):
    """The caller's key is over its rate limit; retry after ``retry_after`` seconds."""

    status_code = 429
    error = "TooManyRequests"

    def __init__(self, detail: str, *, retry_after: int) -> None:
        super().__init__(detail)
        self.retry_after = retry_after

    def headers(self) -> dict[str, str]:
        return {"Retry-After": str(self.retry_after)}


class ValidationFailed(AppError):
    status_code = 422
    error = "ValidationError"


class ServiceUnavailable(AppError):
    status_code = 503
    error = "ServiceUnavailable"

    def __init__(self, detail: str, *, retry_after: int = 1) -> None:
        super().__init__(detail)
        self.retry_after = retry_after

    def headers(self) -> dict[str, str]:
        return {"Retry-After": str(self.retry_after)}
