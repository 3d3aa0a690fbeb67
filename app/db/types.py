"""Column types: UTC datetimes on both engines, and the learner-state document (no pickle)."""

from __future__ import annotations

import datetime as dt
from typing import Any

import orjson
from sqlalchemy import DateTime, Dialect, Text
from sqlalchemy.types import TypeDecorator

from app.learning.state import FORMAT

__all__ = ["LearnerStateType", "UTCDateTime", "json_dumps", "utcnow"]


def json_dumps(value: Any) -> str:
    """JSON text of a document (the JSON columns' serializer): compact, numpy numbers allowed."""
    return orjson.dumps(value, option=orjson.OPT_SERIALIZE_NUMPY).decode()


def utcnow() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


class UTCDateTime(TypeDecorator[dt.datetime]):
    """An aware datetime stored as UTC; SQLite (which keeps no offset) gets naive UTC."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: dt.datetime | None, dialect: Dialect) -> dt.datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("datetimes must carry an offset")
        value = value.astimezone(dt.UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(
        self, value: dt.datetime | None, dialect: Dialect
    ) -> dt.datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=dt.UTC) if value.tzinfo is None else value.astimezone(dt.UTC)


class LearnerStateType(TypeDecorator[dict[str, Any]]):
    """The learning core's self-describing state document, stored as JSON text.

    The document carries its own format name and version (``attune.learner-state``, v1), so a
    reader can refuse what it does not understand; nothing is pickled.
    """

    impl = Text
    cache_ok = True

    def process_bind_param(self, value: dict[str, Any] | None, dialect: Dialect) -> str | None:
        if value is None:
            return None
        if value.get("format") != FORMAT:
            raise ValueError(f"a learner state must have format {FORMAT!r}")
        return orjson.dumps(
            value, option=orjson.OPT_SORT_KEYS | orjson.OPT_SERIALIZE_NUMPY
        ).decode()

    def process_result_value(self, value: str | None, dialect: Dialect) -> dict[str, Any] | None:
        if value is None:
            return None
        doc: dict[str, Any] = orjson.loads(value)
        return doc
