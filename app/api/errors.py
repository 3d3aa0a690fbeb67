"""The one error handler family: every failure leaves as ``{"error", "detail", "request_id"}``
JSON (plus ``fields`` on a 422)."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DataError, DBAPIError, IntegrityError, InterfaceError, OperationalError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount

from app.errors import AppError, BadRequest, Conflict, ServiceUnavailable, ValidationFailed
from app.schemas.common import ErrorOut

from .middleware import BodyTooLarge, error_body

__all__ = [
    "ERROR_RESPONSES",
    "allowed_methods",
    "install_error_handlers",
    "responses",
    "validation_detail",
]

log = logging.getLogger("attune.api")

_DESCRIPTIONS = {
    400: "Malformed JSON.",
    401: "Missing, unknown or revoked API key.",
    403: "The key's role may not do this.",
    404: "No such resource in your fleet.",
    409: "Conflict: an ID reused with another body, or a state that does not allow this.",
    413: "Request body over the size limit (64 KiB by default).",
    415: "The body is not sent as JSON: its Content-Type must be application/json (or "
    "application/*+json); a body without a Content-Type is refused too.",
    422: "Validation failed: the detail names the field and the allowed values.",
    429: "The API key is over its rate limit; retry after the Retry-After seconds.",
    500: "Server error. No stack trace is sent: the service's log has it, under the "
    "response's request_id.",
    503: "The service is at capacity, or the database is busy or unreachable; retry after the "
    "Retry-After seconds.",
}
_RETRY_AFTER = {
    "Retry-After": {
        "description": "Whole seconds to wait before retrying.",
        "schema": {"type": "string", "pattern": "^[0-9]+$"},
    }
}
_WWW_AUTHENTICATE = {
    "WWW-Authenticate": {
        "description": "How to send a key: Bearer (an Authorization: Bearer <key> header).",
        "schema": {"type": "string", "enum": ["Bearer"]},
    }
}
_HEADERS = {401: _WWW_AUTHENTICATE, 429: _RETRY_AFTER, 503: _RETRY_AFTER}
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {
        "model": ErrorOut,
        "description": text,
        **({"headers": _HEADERS[code]} if code in _HEADERS else {}),
    }
    for code, text in _DESCRIPTIONS.items()
}


def responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` for the given error codes (plus the ones every route has)."""
    every = (400, 401, 413, 422, 429, 500, 503)
    return {c: ERROR_RESPONSES[c] for c in sorted({*codes, *every})}


def _json(body: dict[str, Any], status: int, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse(body, status_code=status, headers=headers or None)


def _render(exc: AppError) -> JSONResponse:
    more = {"fields": exc.fields} if exc.fields is not None else {}
    return _json(error_body(exc.error, exc.detail, **more), exc.status_code, exc.headers())


def _loc(loc: tuple[Any, ...]) -> str:
    return ".".join(str(p) for p in loc)


def _query_fields(dependant: Any) -> dict[str, Any]:
    """The query parameters of a route and of its dependencies, by name."""
    found: dict[str, Any] = {}
    stack = [dependant]
    while stack:
        current = stack.pop()
        for field in getattr(current, "query_params", ()):
            found.setdefault(field.alias, field)
        stack.extend(getattr(current, "dependencies", ()))
    return found


def _int_range(field: Any) -> tuple[int | None, int | None] | None:
    """(lowest, highest) of an integer parameter, from its ge/gt/le/lt; None if not an int."""
    annotation = getattr(field.field_info, "annotation", None)
    if annotation is not int and int not in getattr(annotation, "__args__", ()):
        return None
    low = high = None
    for rule in field.field_info.metadata:
        if getattr(rule, "ge", None) is not None:
            low = int(rule.ge)
        if getattr(rule, "gt", None) is not None:
            low = int(rule.gt) + 1
        if getattr(rule, "le", None) is not None:
            high = int(rule.le)
        if getattr(rule, "lt", None) is not None:
            high = int(rule.lt) - 1
    return low, high


def _range_sentence(name: str, low: int | None, high: int | None) -> str:
    if low is not None and high is not None:
        return f"{name} must be an integer from {low} to {high}."
    if low is not None:
        return f"{name} must be an integer of at least {low}."
    if high is not None:
        return f"{name} must be an integer of at most {high}."
    return f"{name} must be an integer."


def validation_detail(request: Request, exc: RequestValidationError) -> str:
    """The sentence of a 422: an integer query parameter's error names the parameter and its
    range (``last must be an integer from 1 to 1000000.``); any other names the field and
    what is wrong with it."""
    errors = exc.errors()
    first = errors[0] if errors else {}
    loc = tuple(first.get("loc", ()))
    if len(loc) == 2 and loc[0] == "query":
        field = _query_fields(getattr(request.scope.get("route"), "dependant", None)).get(loc[1])
        bounds = _int_range(field) if field is not None else None
        if bounds is not None:
            return _range_sentence(str(loc[1]), *bounds)
        if loc[1] == "cursor":
            return "cursor is not one this API returned."  # as the services say it
    return f"{_loc(loc)}: {first.get('msg', 'invalid')}."


_PROBED = ("GET", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(request: Request) -> list[str] | None:
    """Every method the request's path answers (``HEAD`` with ``GET``), from all the routes
    that match it, not only the first; None when a mounted app answered (it knows its own)."""
    if isinstance(request.scope.get("route"), Mount):
        return None
    scope = request.scope
    allowed: list[str] = []
    for method in _PROBED:
        probe = {
            "type": "http",
            "method": method,
            "path": scope["path"],
            "root_path": scope.get("root_path", ""),
            "headers": [],
            "query_string": b"",
        }
        for route in request.app.router.routes:
            if isinstance(route, Mount):
                continue
            if route.matches(probe)[0] is Match.FULL:
                allowed.append(method)
                break
    if "GET" in allowed:
        allowed.insert(1, "HEAD")
    return allowed


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(AppError)
    async def app_error(_: Request, exc: AppError) -> JSONResponse:
        return _render(exc)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = exc.errors()
        for err in errors:
            if err.get("type") == "json_invalid":
                ctx = err.get("ctx") or {}
                return _render(
                    BadRequest(
                        f"The request body is not valid JSON ({ctx.get('error', 'parse error')})."
                    )
                )
        fields = [
            {
                "loc": [str(p) for p in err.get("loc", ())],
                "msg": str(err.get("msg", "")),
                "type": str(err.get("type", "")),
            }
            for err in errors
        ]
        return _render(ValidationFailed(validation_detail(request, exc), fields=fields))

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        if isinstance(exc.__cause__, BodyTooLarge):  # a streamed body went over the limit
            return _json(error_body("PayloadTooLarge", str(exc.__cause__)), 413)
        names = {
            400: "BadRequest",
            404: "NotFound",
            405: "MethodNotAllowed",
            413: "PayloadTooLarge",
        }
        name = names.get(exc.status_code, "HTTPError")
        detail = str(exc.detail)
        headers = dict(getattr(exc, "headers", None) or {})
        if exc.status_code == 404:
            detail = "No such endpoint; GET /docs lists them."
        if exc.status_code == 405:
            allowed = allowed_methods(request)
            if allowed:
                headers["Allow"] = ", ".join(allowed)
            detail = (
                f"{request.method} is not a method of this path; it answers "
                f"{headers.get('Allow', 'other methods')}."
            )
        return _json(error_body(name, detail), exc.status_code, headers)

    @app.exception_handler(IntegrityError)
    async def integrity_error(_: Request, exc: IntegrityError) -> JSONResponse:
        log.warning("integrity error: %s", exc.orig)
        return _render(Conflict("A concurrent write changed the same record; retry."))

    @app.exception_handler(DataError)
    async def data_error(_: Request, exc: DataError) -> JSONResponse:
        # A value the database cannot hold is the client's to fix, not a server failure. (A NUL
        # character, which PostgreSQL cannot store in a text, is refused before any SQL, on
        # both engines: app.api.deps.refuse_nul.)
        log.info("data error: %s", exc.orig)
        return _render(
            ValidationFailed("A value in the request cannot be stored; change it and retry.")
        )

    @app.exception_handler(OperationalError)
    async def operational_error(_: Request, exc: OperationalError) -> JSONResponse:
        log.warning("database error: %s", exc.orig)
        return _render(ServiceUnavailable("The database is busy or unreachable; retry."))

    @app.exception_handler(DBAPIError)
    async def lost_connection(_: Request, exc: DBAPIError) -> JSONResponse:
        # A connection that broke under the request (a restart, a failover, a connection ended
        # by the server or a pooler): the pool has dropped it, and a retry gets a new one.
        if not (exc.connection_invalidated or isinstance(exc, InterfaceError)):
            raise exc
        log.warning("database connection lost: %s", exc.orig)
        return _render(ServiceUnavailable("The database connection was lost; retry."))

    # No handler for Exception: RequestContextMiddleware logs an unhandled error once, with
    # its traceback and request id, and answers the contract's 500.
