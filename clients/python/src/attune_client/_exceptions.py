"""The errors this client raises: one class per status the service answers with.

``AttuneError`` is the base of them all. ``APIConnectionError`` means no answer came (after the
retries); ``APIStatusError`` means the service answered with an error status, and carries the
contract's error body: ``error`` (a name such as ``"Conflict"``), ``detail`` (a sentence a
person can act on) and, for validation errors, ``fields``. ``OutboxError`` means the outbox file
cannot be opened where it was asked for.
"""

from __future__ import annotations

import json
from typing import Any

import httpx

from ._models import is_interruption
from ._retry import parse_retry_after

__all__ = [
    "APIConnectionError",
    "APIStatusError",
    "APITimeoutError",
    "AttuneError",
    "AuthenticationError",
    "BadRequestError",
    "ConflictError",
    "EpisodeInterruptedError",
    "InternalServerError",
    "NotFoundError",
    "OutboxError",
    "PayloadTooLargeError",
    "PermissionDeniedError",
    "RateLimitError",
    "ServiceUnavailableError",
    "UnprocessableEntityError",
    "make_status_error",
]


class AttuneError(Exception):
    """Base class of every error raised by this client."""


class APIConnectionError(AttuneError):
    """The service could not be reached, or the connection broke, even after the retries."""

    request: httpx.Request

    def __init__(self, *, request: httpx.Request, message: str = "Connection error.") -> None:
        super().__init__(message)
        self.request = request
        self.message = message


class APITimeoutError(APIConnectionError):
    """The request timed out, even after the retries."""

    def __init__(self, *, request: httpx.Request, message: str = "Request timed out.") -> None:
        super().__init__(request=request, message=message)


class OutboxError(AttuneError):
    """The outbox file cannot be opened or set up: its folder is missing or not writable, or
    the path is not a usable SQLite file. ``path`` is the outbox path as given; the message
    names it and says why."""

    path: str

    def __init__(self, message: str, *, path: str) -> None:
        super().__init__(message)
        self.message = message
        self.path = path


class APIStatusError(AttuneError):
    """The service answered with a 4xx or 5xx status.

    Attributes:
        status_code: the HTTP status.
        error: the error name of the body (``"NotFound"``, ``"Conflict"``...).
        detail: the sentence of the body that says what went wrong.
        fields: for validation errors, where and what (``[{"loc", "msg", "type"}]``), else None.
        body: the decoded JSON body (or the text, when it was not JSON).
        response: the ``httpx.Response``.
        request_id: the ``X-Request-ID`` header of the response, if any (quote it in reports).
    """

    response: httpx.Response
    status_code: int
    error: str
    detail: str
    fields: list[dict[str, Any]] | None
    body: object
    request_id: str | None

    def __init__(
        self,
        message: str,
        *,
        response: httpx.Response,
        error: str,
        detail: str,
        fields: list[dict[str, Any]] | None = None,
        body: object = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.response = response
        self.status_code = response.status_code
        self.error = error
        self.detail = detail
        self.fields = fields
        self.body = body
        self.request_id = response.headers.get("x-request-id")


class BadRequestError(APIStatusError):
    """400: the request was malformed (not JSON, say)."""


class AuthenticationError(APIStatusError):
    """401: the API key is missing, unknown or revoked."""


class PermissionDeniedError(APIStatusError):
    """403: the key's role may not do this (most admin actions with a robot key)."""


class NotFoundError(APIStatusError):
    """404: no such user, episode or endpoint in your fleet."""


class ConflictError(APIStatusError):
    """409: an id reused with another body, or a state that does not allow this write."""


class EpisodeInterruptedError(ConflictError):
    """409 for an outcome: its episode was interrupted when its fleet's mission changed, and
    takes no more outcomes (for good: retrying cannot help). Start a new episode; the person's
    model was carried to the new mission."""


class PayloadTooLargeError(APIStatusError):
    """413: the request body is over the service's size limit."""


class UnprocessableEntityError(APIStatusError):
    """422: validation failed; ``detail`` names the field and the allowed values."""


class RateLimitError(APIStatusError):
    """429: too many requests; ``retry_after`` is the server's wish in seconds, if it said."""

    retry_after: float | None

    def __init__(
        self,
        message: str,
        *,
        response: httpx.Response,
        error: str,
        detail: str,
        fields: list[dict[str, Any]] | None = None,
        body: object = None,
    ) -> None:
        super().__init__(
            message, response=response, error=error, detail=detail, fields=fields, body=body
        )
        self.retry_after = parse_retry_after(response.headers.get("retry-after"))


class InternalServerError(APIStatusError):
    """500 and any other 5xx: the service failed (its log has the reason)."""


class ServiceUnavailableError(InternalServerError):
    """503: the service or its database is busy or unreachable; ``retry_after`` if it said."""

    retry_after: float | None

    def __init__(
        self,
        message: str,
        *,
        response: httpx.Response,
        error: str,
        detail: str,
        fields: list[dict[str, Any]] | None = None,
        body: object = None,
    ) -> None:
        super().__init__(
            message, response=response, error=error, detail=detail, fields=fields, body=body
        )
        self.retry_after = parse_retry_after(response.headers.get("retry-after"))


_BY_STATUS: dict[int, type[APIStatusError]] = {
    400: BadRequestError,
    401: AuthenticationError,
    403: PermissionDeniedError,
    404: NotFoundError,
    409: ConflictError,
    413: PayloadTooLargeError,
    422: UnprocessableEntityError,
    429: RateLimitError,
    503: ServiceUnavailableError,
}


def _status_class(status_code: int) -> type[APIStatusError]:
    if status_code in _BY_STATUS:
        return _BY_STATUS[status_code]
    if status_code >= 500:
        return InternalServerError
    return APIStatusError


def make_status_error(response: httpx.Response) -> APIStatusError:
    """The error for a non-2xx response, whatever its body (the contract's JSON, an HTML page
    from a proxy, nothing at all)."""
    status = response.status_code
    reason = response.reason_phrase or f"HTTP {status}"
    error, detail = reason.title().replace(" ", ""), reason
    fields: list[dict[str, Any]] | None = None
    body: object
    try:
        body = response.json()
    except (json.JSONDecodeError, UnicodeDecodeError):
        body = response.text
        text = " ".join(response.text.split())
        if text:
            detail = text if len(text) <= 200 else text[:199] + "…"
    else:
        if isinstance(body, dict):
            if isinstance(body.get("error"), str) and body["error"]:
                error = body["error"]
            if isinstance(body.get("detail"), str) and body["detail"]:
                detail = body["detail"]
            raw_fields = body.get("fields")
            if isinstance(raw_fields, list):
                fields = [f for f in raw_fields if isinstance(f, dict)]
    message = f"{status} {error}: {detail}"
    cls = EpisodeInterruptedError if is_interruption(status, detail) else _status_class(status)
    return cls(message, response=response, error=error, detail=detail, fields=fields, body=body)
