"""What the repositories share: the session's connection, tables, and rows as plain records.

Every repository function takes the request's ``Session`` and runs SQLAlchemy Core statements on
that session's connection, inside its transaction (the ORM classes of ``app.db.models`` are the
schema; no ORM object crosses a repository's edge). Statements used on every robot request are
built once, at import: SQLAlchemy caches their compiled form, and building them is ours to skip.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import fields
from typing import Any, TypeVar

from sqlalchemy import Connection, Dialect, Table
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session
from sqlalchemy.sql import ClauseElement

from app.db.pool import invalidate_all, is_lost_connection

__all__ = ["Prepared", "batch", "columns", "conn", "names", "record", "table", "values"]

T = TypeVar("T")


@contextmanager
def batch(session: Session) -> Iterator[None]:
    """Statements whose results nobody reads, sent together: on PostgreSQL in one pipeline
    (one round trip for all of them, their errors raised at the end of the block); on SQLite,
    which has no round trips, one after the other as usual."""
    connection = session.connection()
    driver: Any = connection.connection.driver_connection
    dialect = connection.dialect
    session.info[_WRITES_ONLY] = True
    try:
        if dialect.name != "postgresql":
            yield
            return
        with driver.pipeline():
            yield
    except dialect.loaded_dbapi.Error as exc:  # raised when the pipeline syncs
        lost = is_lost_connection(exc) or dialect.is_disconnect(
            exc, connection.connection.dbapi_connection, None
        )
        if lost:
            invalidate_all(connection, exc)
        raise DBAPIError.instance(
            None,
            None,
            exc,
            dialect.loaded_dbapi.Error,
            connection_invalidated=lost,
            dialect=dialect,
        ) from exc
    finally:
        session.info.pop(_WRITES_ONLY, None)


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
_DRIVER = "attune_driver"  # session.info: (its transaction, its connection)
_WRITES_ONLY = "attune_writes_only"  # session.info: inside ``batch``, where nothing is read


class _Compiled:
    """One statement compiled for one dialect, with SQLAlchemy's own conversions of its
    parameters and result columns for that dialect."""

    __slots__ = (
        "sql",
        "order",
        "getter",
        "positional",
        "converts",
        "binds",
        "types",
        "dialect",
        "results",
        "named_converts",
    )

    def __init__(self, stmt: ClauseElement, dialect: Dialect, keys: Sequence[str] | None) -> None:
        compiled: Any = stmt.compile(dialect=dialect, column_keys=list(keys) if keys else None)
        self.sql: str = str(compiled)
        procs: dict[str, _Convert] = dict(compiled._bind_processors)
        self.binds = procs
        # Positional drivers (sqlite3) take a tuple in this order; the others take a dict.
        self.positional: bool = bool(compiled.positional)
        self.order: tuple[str, ...] = tuple(compiled.positiontup) if self.positional else ()
        self.getter = operator.itemgetter(*self.order) if len(self.order) > 1 else None
        self.converts: tuple[tuple[int, Callable[[Any], Any]], ...] = tuple(
            (i, f) for i, name in enumerate(self.order) if (f := procs.get(name)) is not None
        )
        # Named drivers (psycopg): only the parameters with a conversion are touched.
        self.named_converts: tuple[tuple[str, Callable[[Any], Any]], ...] = tuple(
            (name, f) for name, f in procs.items() if f is not None
        )
        self.types = [entry.type for entry in compiled._result_columns]
        self.dialect = dialect
        self.results: tuple[tuple[int, Callable[[Any], Any]], ...] | None = None

    def args(self, params: Mapping[str, Any]) -> Any:
        if not self.positional:
            out = dict(params)
            for name, f in self.named_converts:
                value = out.get(name)
                if value is not None:
                    out[name] = f(value)
            return out
        if self.getter is None:
            values = [params[name] for name in self.order]
        else:
            values = list(self.getter(params))
        for i, f in self.converts:
            if values[i] is not None:
                values[i] = f(values[i])
        return values

    def processors(self, cursor: Any) -> tuple[tuple[int, Callable[[Any], Any]], ...]:
        """The result columns that need a conversion, with it: it may depend on the driver's
        column types (PostgreSQL numbers), known once the statement ran."""
        if self.results is None:
            found = (
                t.dialect_impl(self.dialect).result_processor(self.dialect, d[1])
                for t, d in zip(self.types, cursor.description, strict=True)
            )
            self.results = tuple((i, f) for i, f in enumerate(found) if f is not None)
        return self.results

    @staticmethod
    def row(
        processors: tuple[tuple[int, Callable[[Any], Any]], ...], raw: Sequence[Any]
    ) -> list[Any]:
        values = list(raw)
        for i, f in processors:
            if values[i] is not None:
                values[i] = f(values[i])
        return values


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

    def _execute(
        self, session: Session, params: Mapping[str, Any] | list[Mapping[str, Any]], fetch: int
    ) -> list[list[Any]]:
        """Run on the session's driver connection; ``fetch``: 0 nothing, 1 the first row, 2
        every row. A driver error leaves as SQLAlchemy's own (``DataError``, ``IntegrityError``,
        ``OperationalError``...), and a lost connection is invalidated, as SQLAlchemy does."""
        if fetch and session.info.get(_WRITES_ONLY):
            # On PostgreSQL a pipeline has no result to give yet; on every engine, a read here
            # is a read that the batch's single round trip was meant to have done before.
            raise RuntimeError(f"a read inside a batch of writes: {self.stmt}")
        transaction = session.get_transaction()
        found = session.info.get(_DRIVER)
        if found is None or transaction is None or found[0] is not transaction:
            found = (session.get_transaction(), session.connection())
            session.info[_DRIVER] = found
        connection: Connection = found[1]
        dialect = connection.dialect
        rows: list[Mapping[str, Any]] = params if isinstance(params, list) else [params]
        compiled = self._for(dialect, rows[0])
        driver: Any = connection.connection.driver_connection
        cursor = driver.cursor()
        try:
            if isinstance(params, list):
                cursor.executemany(compiled.sql, [compiled.args(p) for p in rows])
                return []
            cursor.execute(compiled.sql, compiled.args(params))
            if fetch == 0:
                return []
            processors = compiled.processors(cursor)
            if fetch == 1:
                raw = cursor.fetchone()
                return [] if raw is None else [compiled.row(processors, raw)]
            return [compiled.row(processors, raw) for raw in cursor.fetchall()]
        except dialect.loaded_dbapi.Error as exc:
            lost = is_lost_connection(exc) or dialect.is_disconnect(
                exc, connection.connection.dbapi_connection, cursor
            )
            if lost:
                invalidate_all(connection, exc)
            raise DBAPIError.instance(
                compiled.sql,
                params,
                exc,
                dialect.loaded_dbapi.Error,
                connection_invalidated=lost,
                dialect=dialect,
            ) from exc
        finally:
            cursor.close()

    def first(self, session: Session, params: Mapping[str, Any]) -> list[Any] | None:
        rows = self._execute(session, params, 1)
        return rows[0] if rows else None

    def all(self, session: Session, params: Mapping[str, Any]) -> list[list[Any]]:
        return self._execute(session, params, 2)

    def run(self, session: Session, params: Mapping[str, Any]) -> None:
        self._execute(session, params, 0)

    def run_many(self, session: Session, rows: Iterable[Mapping[str, Any]]) -> None:
        many = list(rows)
        if many:
            self._execute(session, many, 0)
