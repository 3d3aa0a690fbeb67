"""Request ids and log lines.

Every HTTP request runs with a :class:`RequestContext` (its id, and the caller's key id once the
key is known) in a context variable: the API's middleware sets it, and every log line written
while the request runs carries the id. The id is the caller's ``X-Request-ID`` when it is valid
(:data:`REQUEST_ID_PATTERN`), else a fresh one (32 lowercase hex characters).

Log lines come in two formats, ``ATTUNE_LOG_FORMAT=text`` (the default, for people) and ``json``
(one object per line, for log shippers): ``time``, ``level``, ``logger``, ``message``, and
``request_id`` when the line belongs to a request, plus the fields a line adds (the access
line's ``method``, ``route``, ``status``, ``latency_ms``, ``key_id``) and ``exception`` (the
traceback) for an error. :func:`logging_config` is the ``logging.config.dictConfig`` of both,
for ``attune serve`` and each of its worker processes.
"""

from __future__ import annotations

import contextvars
import json
import logging
import re
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

__all__ = [
    "FIELDS",
    "REQUEST_ID_PATTERN",
    "JsonFormatter",
    "RequestContext",
    "RequestIdFilter",
    "TextFormatter",
    "current",
    "current_request_id",
    "logging_config",
    "request_id_from",
]

REQUEST_ID_PATTERN = r"^[A-Za-z0-9._:-]{1,128}$"
_REQUEST_ID = re.compile(REQUEST_ID_PATTERN)
FIELDS = "attune_fields"  # ``extra={FIELDS: {...}}``: fields a line adds to its JSON object
LOG_FORMATS = ("text", "json")


@dataclass
class RequestContext:
    """What the log lines of one request share. Mutable on purpose: the request's threads (the
    route and its dependencies run in a thread pool, each with a copy of the context variables)
    see the same object, so the key id set by the authentication reaches the access line."""

    request_id: str
    key_id: str | None = None


_current: contextvars.ContextVar[RequestContext | None] = contextvars.ContextVar(
    "attune_request", default=None
)


def current() -> RequestContext | None:
    """The context of the request being handled, or None outside a request."""
    return _current.get()


def current_request_id() -> str | None:
    ctx = _current.get()
    return ctx.request_id if ctx is not None else None


def bind(ctx: RequestContext) -> contextvars.Token[RequestContext | None]:
    return _current.set(ctx)


def unbind(token: contextvars.Token[RequestContext | None]) -> None:
    _current.reset(token)


def request_id_from(header: str | None) -> str:
    """The caller's ``X-Request-ID`` when it is valid, else a fresh id."""
    if header is not None and _REQUEST_ID.match(header):
        return header
    return uuid.uuid4().hex


class RequestIdFilter(logging.Filter):
    """Adds ``request_id`` (None outside a request) to every record a handler emits."""

    def filter(self, record: logging.LogRecord) -> bool:
        if getattr(record, "request_id", None) is None:
            record.request_id = current_request_id()
        return True


def _request_id(record: logging.LogRecord) -> str | None:
    rid = getattr(record, "request_id", None)
    return rid if isinstance(rid, str) else current_request_id()


class TextFormatter(logging.Formatter):
    """``2026-11-22 15:10:00,123 INFO attune.access: <message> request_id=<id>``: the request
    id ends the line of any request's record."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s: %(message)s")

    def formatMessage(self, record: logging.LogRecord) -> str:  # logging's name
        line = super().formatMessage(record)
        rid = _request_id(record)
        return f"{line} request_id={rid}" if rid else line


class JsonFormatter(logging.Formatter):
    """One JSON object per record, on one line (a traceback is a string field)."""

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "time": datetime.fromtimestamp(record.created, UTC)
            .isoformat(timespec="milliseconds")
            .replace("+00:00", "Z"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        rid = _request_id(record)
        if rid:
            out["request_id"] = rid
        fields = getattr(record, FIELDS, None)
        if isinstance(fields, dict):
            out.update(fields)
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        elif record.exc_text:
            out["exception"] = record.exc_text
        if record.stack_info:
            out["stack"] = self.formatStack(record.stack_info)
        return json.dumps(out, default=str, ensure_ascii=False)


def logging_config(level: str, fmt: str) -> dict[str, Any]:
    """``dictConfig`` for the service: attune's, uvicorn's and every other library's lines go to
    stderr in one format; uvicorn's own access log is off (``attune.access`` writes one line per
    request instead)."""
    if fmt not in LOG_FORMATS:
        raise ValueError(f"log format must be one of {', '.join(LOG_FORMATS)}")
    formatter = JsonFormatter if fmt == "json" else TextFormatter
    level = level.upper()
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "filters": {"request_id": {"()": RequestIdFilter}},
        "formatters": {"attune": {"()": formatter}},
        "handlers": {
            "stderr": {
                "class": "logging.StreamHandler",
                "stream": "ext://sys.stderr",
                "formatter": "attune",
                "filters": ["request_id"],
            }
        },
        "loggers": {
            "attune": {"level": level, "handlers": ["stderr"], "propagate": False},
            "uvicorn": {"level": level, "handlers": ["stderr"], "propagate": False},
            "uvicorn.error": {"level": level},
            "uvicorn.access": {"level": "WARNING", "handlers": [], "propagate": False},
            # attune serve reports the migrations it applies in a line of its own
            "alembic": {"level": "WARNING"},
        },
        "root": {"level": level, "handlers": ["stderr"]},
    }
