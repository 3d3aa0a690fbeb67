"""What the repositories share: the session's connection, tables, and rows as plain records.

Every repository function takes the request's ``Session`` and runs SQLAlchemy Core statements on
that session's connection, inside its transaction (the ORM classes of ``app.db.models`` are the
schema; no ORM object crosses a repository's edge). Statements used on every robot request are
built once, at import: SQLAlchemy caches their compiled form, and building them is ours to skip.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any, TypeVar

from sqlalchemy import Connection, Table
from sqlalchemy.orm import Session

__all__ = ["columns", "conn", "names", "record", "table", "values"]

T = TypeVar("T")


def conn(session: Session) -> Connection:
    """The connection of the session's transaction (begun by the first statement)."""
    return session.connection()


def table(model: Any) -> Table:
    tbl: Table = model.__table__
    return tbl


def names(cls: type) -> tuple[str, ...]:
    """The field names of a record class, in order (they are its table's column names)."""
    return tuple(f.name for f in fields(cls))


def columns(tbl: Table, cls: type) -> list[Any]:
    """The columns of ``tbl`` that ``cls``'s fields name, in the same order."""
    return [tbl.c[name] for name in names(cls)]


def record(cls: type[T], row: Any) -> T | None:
    """A record from a result row whose columns follow the record's fields (``None`` stays)."""
    return None if row is None else cls(*row)


def values(rec: Any, which: tuple[str, ...]) -> dict[str, Any]:
    return {name: getattr(rec, name) for name in which}
