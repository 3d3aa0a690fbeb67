"""Engines and sessions for SQLite (embedded, WAL) and PostgreSQL (psycopg 3).

Writes are serialized per user: PostgreSQL through a row lock on the user (``FOR UPDATE``),
SQLite, which has one writer per file, through ``BEGIN IMMEDIATE`` so that a write transaction
takes the write lock up front instead of failing on upgrade. Reads use a plain ``BEGIN`` (WAL lets
them run beside a writer).

On SQLite the write transactions of one process also take turns on a lock of their own before
``BEGIN IMMEDIATE``: a writer that finds the file locked waits in SQLite's busy handler, which
polls with sleeps of up to 100 ms, so under contention writers slept long after the lock was
free (p99 over a second at 8 concurrent robots). Waiting on an in-process lock wakes the next
writer the moment the previous one commits; the busy handler is left to arbitrate between
processes only.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Any

import orjson
from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import Connection
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from app.errors import ServiceUnavailable
from app.settings import Settings

from .types import json_dumps

__all__ = ["Database"]

_WRITE = "attune_write"


class Database:
    """One engine per process, and sessions that know whether they will write."""

    def __init__(self, settings: Settings) -> None:
        self.url = settings.database_url
        self.is_sqlite = settings.is_sqlite
        kwargs: dict[str, Any] = {"pool_pre_ping": settings.db_pre_ping,
                                  "json_serializer": json_dumps,
                                  "json_deserializer": orjson.loads}
        if self.is_sqlite:
            kwargs["connect_args"] = {
                "timeout": settings.sqlite_busy_timeout_s,
                "check_same_thread": False,
            }
        else:
            kwargs["pool_size"] = settings.db_pool_size
            kwargs["max_overflow"] = settings.db_pool_size
        self.engine: Engine = create_engine(self.url, **kwargs)
        if self.is_sqlite:
            _configure_sqlite(self.engine, settings.sqlite_busy_timeout_s)
        self._write_engine = self.engine.execution_options(**{_WRITE: True})
        # Single-statement reads (the caller's key): no BEGIN/COMMIT around them.
        self._autocommit_engine = self.engine.execution_options(isolation_level="AUTOCOMMIT")
        self._writer = threading.Lock() if self.is_sqlite else None
        self._writer_timeout_s = settings.sqlite_busy_timeout_s
        self._inline_engine: Engine | None = None
        if self.is_sqlite and settings.sqlite_inline_writes:
            inline = create_engine(self.url, pool_size=1, max_overflow=0, **kwargs)
            _configure_sqlite(inline, 0.0)
            self._inline_engine = inline.execution_options(**{_WRITE: True})

    def session(self, *, write: bool) -> Session:
        return Session(bind=self._write_engine if write else self.engine, expire_on_commit=False)

    @contextmanager
    def single_read(self) -> Iterator[Session]:
        """A session for one read statement, run without a transaction (autocommit): a single
        statement sees one consistent snapshot anyway, and skipping BEGIN and COMMIT saves two
        round trips on PostgreSQL."""
        with Session(bind=self._autocommit_engine, expire_on_commit=False) as session:
            yield session

    @contextmanager
    def transaction(self, *, write: bool = True) -> Iterator[Session]:
        """A session whose transaction commits at the end of the block, or rolls back; then the
        callbacks registered for after the commit run (``app.services.context.after_commit``)."""
        with self.session(write=write) as session, self.within(session, write=write):
            yield session

    @contextmanager
    def within(self, session: Session, *, write: bool) -> Iterator[None]:
        """Run a block as ``session``'s whole transaction: take the write turn (SQLite), commit
        at the end or roll back, then run the after-commit callbacks, still in the turn (the
        next writer finds the cache filled). The block's first statement begins it."""
        with self._write_turn(write):
            try:
                yield
                session.commit()
            except BaseException:
                session.rollback()
                raise
            for callback in session.info.pop("after_commit", []):
                callback()

    @contextmanager
    def _write_turn(self, write: bool) -> Iterator[None]:
        """SQLite writers of this process, one at a time (see the module's docstring).

        A ``threading.Lock`` (not an RLock): the request's session may be opened and closed on
        different threads of the pool.
        """
        if self._writer is None or not write:
            yield
            return
        if not self._writer.acquire(timeout=self._writer_timeout_s):
            raise ServiceUnavailable("The database is busy; retry.")
        try:
            yield
        finally:
            self._writer.release()

    def try_inline(self) -> AbstractContextManager[Session] | None:
        """A write transaction to run right here, if one can start without waiting: SQLite only,
        when no writer of this process has the turn and no other process holds the database's
        write lock (its connections do not wait: busy timeout 0). ``None`` otherwise: the caller
        goes the usual way (a pool thread that may wait its turn).

        Used on the event loop by the short robot writes: with one writer at a time anyway,
        running them in place saves the hand-off to a thread and back.
        """
        if self._inline_engine is None or self._writer is None:
            return None
        if not self._writer.acquire(blocking=False):
            return None
        session = Session(bind=self._inline_engine, expire_on_commit=False)
        try:
            session.connection()  # BEGIN IMMEDIATE, or "database is locked" at once
        except OperationalError:
            session.close()
            self._writer.release()
            return None
        return self._inline(session)

    @contextmanager
    def _inline(self, session: Session) -> Iterator[Session]:
        assert self._writer is not None
        try:
            with session:
                try:
                    yield session
                    session.commit()
                except BaseException:
                    session.rollback()
                    raise
                for callback in session.info.pop("after_commit", []):
                    callback()
        finally:
            self._writer.release()

    def dispose(self) -> None:
        self.engine.dispose()
        if self._inline_engine is not None:
            self._inline_engine.dispose()


def _configure_sqlite(engine: Engine, busy_timeout_s: float) -> None:
    @event.listens_for(engine, "connect")
    def _connect(dbapi_connection: Any, _record: Any) -> None:
        # Let SQLAlchemy's begin event, not the driver, decide how each transaction starts.
        dbapi_connection.isolation_level = None
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute(f"PRAGMA busy_timeout={int(busy_timeout_s * 1000)}")
        cursor.close()

    @event.listens_for(engine, "begin")
    def _begin(conn: Connection) -> None:
        options = conn.get_execution_options()
        if options.get("isolation_level") == "AUTOCOMMIT":
            return
        # On the driver's connection: a statement through SQLAlchemy costs more than this one.
        driver: Any = conn.connection.driver_connection
        driver.execute("BEGIN IMMEDIATE" if options.get(_WRITE, False) else "BEGIN")
