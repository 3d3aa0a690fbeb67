"""What the repositories share: the session's connection, tables, and rows as plain records.

Every repository function takes the request's ``Session`` and runs SQLAlchemy Core statements on
that session's connection, inside its transaction (the ORM classes of ``app.db.models`` are the
schema; no ORM object crosses a repository's edge). Statements used on every robot request are
built once, at import: SQLAlchemy caches their compiled form, and building them is ours to skip.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import fields
from typing import Any, TypeVar

from sqlalchemy import Connection, Dialect, Table
from sqlalchemy.orm import Session
from sqlalchemy.sql import ClauseElement

__all__ = ["Prepared", "columns", "conn", "names", "record", "table", "values"]

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


_Convert = Callable[[Any], Any] | None
_DRIVER = "attune_driver"  # session.info: (its transaction, the driver's connection, dialect)


def _convert(f: _Convert, value: Any) -> Any:
    return value if f is None or value is None else f(value)


class _Compiled:
    """One statement compiled for one dialect, with SQLAlchemy's own conversions of its
    parameters and result columns for that dialect."""

    __slots__ = ("sql", "order", "binds", "types", "dialect", "results")

    def __init__(self, stmt: ClauseElement, dialect: Dialect, keys: Sequence[str] | None) -> None:
        compiled: Any = stmt.compile(dialect=dialect, column_keys=list(keys) if keys else None)
        self.sql: str = str(compiled)
        procs: dict[str, _Convert] = dict(compiled._bind_processors)
        # Positional drivers (sqlite3) take a tuple in this order; the others take a dict.
        self.order: tuple[tuple[str, _Convert], ...] | None = (
            tuple((name, procs.get(name)) for name in compiled.positiontup)
            if compiled.positional else None)
        self.binds = procs
        self.types = [entry.type for entry in compiled._result_columns]
        self.dialect = dialect
        self.results: tuple[_Convert, ...] | None = None  # from the first result's description

    def args(self, params: Mapping[str, Any]) -> Any:
        if self.order is not None:
            return tuple(params[k] if f is None else _convert(f, params[k])
                         for k, f in self.order)
        binds = self.binds
        return {k: _convert(binds.get(k), v) for k, v in params.items()}

    def processors(self, cursor: Any) -> tuple[_Convert, ...]:
        """The result columns' conversions, which may depend on the driver's column types
        (PostgreSQL numbers), known once a statement ran."""
        if self.results is None:
            self.results = tuple(
                t._cached_result_processor(self.dialect, d[1])
                for t, d in zip(self.types, cursor.description, strict=True))
        return self.results

    def row(self, processors: tuple[_Convert, ...], raw: Sequence[Any]) -> tuple[Any, ...]:
        return tuple(v if f is None or v is None else f(v)
                     for f, v in zip(processors, raw, strict=True))


class Prepared:
    """A prebuilt Core statement run on the DBAPI cursor of the session's connection, inside
    the session's transaction: compiled once per dialect (and per set of SET or VALUES
    columns), with SQLAlchemy's own parameter and result conversions for that dialect, but
    without the per-execution bookkeeping of ``Connection.execute`` (which costs more than
    the statement itself on the robots' hot path: one request runs about eight of these).

    For the few statements every robot request runs; the rest go through ``conn(session)``.
    """

    __slots__ = ("stmt", "_compiled", "_keyed")

    def __init__(self, stmt: ClauseElement, *, keyed: bool = False) -> None:
        self.stmt = stmt
        self._keyed = keyed  # an INSERT or UPDATE whose columns are its parameters' keys
        self._compiled: dict[tuple[int, tuple[str, ...]], tuple[Dialect, _Compiled]] = {}

    def _for(self, dialect: Dialect, params: Mapping[str, Any]) -> _Compiled:
        key = (id(dialect), tuple(params) if self._keyed else ())
        found = self._compiled.get(key)
        if found is None:
            columns = [k for k in params if not k.startswith("b_")] if self._keyed else None
            found = (dialect, _Compiled(self.stmt, dialect, columns))
            self._compiled[key] = found
        return found[1]

    def _cursor(self, session: Session) -> tuple[Any, Dialect]:
        transaction = session.get_transaction()
        found = session.info.get(_DRIVER)
        if found is None or transaction is None or found[0] is not transaction:
            connection = session.connection()
            found = (session.get_transaction(), connection.connection.driver_connection,
                     connection.dialect)
            session.info[_DRIVER] = found
        cursor = found[1].cursor()  # type: ignore[union-attr]
        return cursor, found[2]

    def first(self, session: Session, params: Mapping[str, Any]) -> tuple[Any, ...] | None:
        cursor, dialect = self._cursor(session)
        compiled = self._for(dialect, params)
        try:
            cursor.execute(compiled.sql, compiled.args(params))
            raw = cursor.fetchone()
            return None if raw is None else compiled.row(compiled.processors(cursor), raw)
        finally:
            cursor.close()

    def all(self, session: Session, params: Mapping[str, Any]) -> list[tuple[Any, ...]]:
        cursor, dialect = self._cursor(session)
        compiled = self._for(dialect, params)
        try:
            cursor.execute(compiled.sql, compiled.args(params))
            processors = compiled.processors(cursor)
            return [compiled.row(processors, raw) for raw in cursor.fetchall()]
        finally:
            cursor.close()

    def run(self, session: Session, params: Mapping[str, Any]) -> None:
        cursor, dialect = self._cursor(session)
        compiled = self._for(dialect, params)
        try:
            cursor.execute(compiled.sql, compiled.args(params))
        finally:
            cursor.close()

    def run_many(self, session: Session, rows: Iterable[Mapping[str, Any]]) -> None:
        rows = list(rows)
        if not rows:
            return
        cursor, dialect = self._cursor(session)
        compiled = self._for(dialect, rows[0])
        try:
            cursor.executemany(compiled.sql, [compiled.args(r) for r in rows])
        finally:
            cursor.close()
