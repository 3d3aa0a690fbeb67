"""The one error handler family: every failure leaves as ``{"error", "detail"}`` JSON."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DataError, IntegrityError, OperationalError
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.errors import AppError, BadRequest, Conflict, ServiceUnavailable, ValidationFailed
from app.schemas.common import ErrorOut

from .middleware import BodyTooLarge

__all__ = ["ERROR_RESPONSES", "install_error_handlers", "responses"]

log = logging.getLogger("attune.api")

_DESCRIPTIONS = {
    400: "Malformed JSON.",
    401: "Missing, unknown or revoked API key.",
    403: "The key's role may not do this.",
    404: "No such resource in your fleet.",
    409: "Conflict: an ID reused with another body, or a state that does not allow this.",
    413: "Request body over the size limit (64 KiB by default).",
    422: "Validation failed: the detail names the field and the allowed values.",
    429: "The API key is over its rate limit; retry after the Retry-After seconds.",
    500: "Server error (no stack trace is sent; the log has it).",
    503: "The service is at capacity, or the database is busy or unreachable; retry after the "
         "Retry-After seconds.",
}
_RETRY_AFTER = {"Retry-After": {"description": "Whole seconds to wait before retrying.",
                                "schema": {"type": "string", "pattern": "^[0-9]+$"}}}
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorOut, "description": text,
           **({"headers": _RETRY_AFTER} if code in (429, 503) else {})}
    for code, text in _DESCRIPTIONS.items()
}


def responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` for the given error codes (plus the ones every route has)."""
    every = (400, 401, 413, 422, 429, 500, 503)
    return {c: ERROR_RESPONSES[c] for c in sorted({*codes, *every})}


def _render(exc: AppError) -> JSONResponse:
    return JSONResponse(exc.body(), status_code=exc.status_code, headers=exc.headers() or None)


def _loc(loc: tuple[Any, ...]) -> str:
    return ".".join(str(p) for p in loc)


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(AppError)
    async def app_error(_: Request, exc: AppError) -> JSONResponse:
        return _render(exc)

    @app.exception_handler(RequestValidationError)
    async def validation_error(_: Request, exc: RequestValidationError) -> JSONResponse:
        errors = exc.errors()
        for err in errors:
            if err.get("type") == "json_invalid":
                ctx = err.get("ctx") or {}
                return _render(BadRequest(
                    f"The request body is not valid JSON ({ctx.get('error', 'parse error')})."
                ))
        fields = [
            {"loc": [str(p) for p in err.get("loc", ())], "msg": str(err.get("msg", "")),
             "type": str(err.get("type", ""))}
            for err in errors
        ]
        first = errors[0] if errors else {}
        detail = f"{_loc(first.get('loc', ()))}: {first.get('msg', 'invalid')}."
        return _render(ValidationFailed(detail, fields=fields))

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        if isinstance(exc.__cause__, BodyTooLarge):  # a streamed body went over the limit
            return JSONResponse({"error": "PayloadTooLarge", "detail": str(exc.__cause__)},
                                status_code=413)
        names = {400: "BadRequest", 404: "NotFound", 405: "MethodNotAllowed",
                 413: "PayloadTooLarge"}
        name = names.get(exc.status_code, "HTTPError")
        detail = str(exc.detail)
        if exc.status_code == 404:
            detail = "No such endpoint; GET /docs lists them."
        return JSONResponse({"error": name, "detail": detail}, status_code=exc.status_code,
                            headers=getattr(exc, "headers", None))

    @app.exception_handler(IntegrityError)
    async def integrity_error(_: Request, exc: IntegrityError) -> JSONResponse:
        log.warning("integrity error: %s", exc.orig)
        return _render(Conflict("A concurrent write changed the same record; retry."))

    @app.exception_handler(DataError)
    async def data_error(_: Request, exc: DataError) -> JSONResponse:
        # A value the database cannot hold (PostgreSQL: a NUL character in a text) is the
        # client's to fix, not a server failure.
        log.info("data error: %s", exc.orig)
        return _render(ValidationFailed("A value in the request cannot be stored (a NUL "
                                        "character, say); remove it and retry."))

    @app.exception_handler(OperationalError)
    async def operational_error(_: Request, exc: OperationalError) -> JSONResponse:
        log.warning("database error: %s", exc.orig)
        return _render(ServiceUnavailable("The database is busy or unreachable; retry."))

    @app.exception_handler(Exception)
    async def server_error(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse(
            {"error": "InternalError", "detail": "The server failed; the error was logged."},
            status_code=500,
        )
