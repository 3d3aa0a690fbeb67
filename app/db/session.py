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

An encrypted SQLite file (``ATTUNE_DB_KEY`` or ``ATTUNE_DB_KEY_FILE``) is opened with SQLCipher's
driver instead of ``sqlite3``, each connection given the key first (``app.db.encryption``).
"""

from __future__ import annotations

import asyncio
import logging
import statistics
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import orjson
from pydantic import SecretStr
from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import Connection, ExceptionContext, make_url
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from app.errors import ServiceUnavailable
from app.settings import Settings

from . import encryption
from .pool import MeteredQueuePool, is_lost_connection
from .types import json_dumps

__all__ = ["NOWAIT", "PROBE_EVERY_S", "Database", "LockBusy", "WriteGroup"]

log = logging.getLogger("attune.db")

_WRITE = "attune_write"
NOWAIT = "attune_nowait"  # session.info: take the user's lock only if it is free at once

PROBE_EVERY_S = 2.0
"""PostgreSQL, ``ATTUNE_PG_INLINE_WRITES=auto``: how often each worker measures the round trip."""
_PROBES_KEPT = 5  # the round trip in force is the median of the last probes
_SAMPLES = 5  # statements per probe; a probe's figure is their median
_SLOW = 4  # on the loop, a probe stops at a statement this many times the threshold


class LockBusy(Exception):
    """The user's lock was held by another transaction, in a session that does not wait for it
    (:data:`NOWAIT`): the write is run again where it may wait (the thread pool)."""


class WriteGroup:
    """Writes that share one SQLite transaction (see :meth:`Database.join_group`); each
    member runs in a savepoint, and waits for the group's COMMIT before it answers."""

    def __init__(self, session: Session, done: asyncio.Future[None]) -> None:
        self.session, self.done = session, done
        self.members = 0

    @contextmanager
    def member(self) -> Iterator[Session]:
        """One write's part: released into the group if it succeeds, rolled back (with the
        after-commit callbacks it registered) if it raises."""
        driver: Any = self.session.connection().connection.driver_connection
        callbacks: list[Any] = self.session.info.setdefault("after_commit", [])
        mark = len(callbacks)
        self.members += 1
        driver.execute("SAVEPOINT attune_write")
        try:
            yield self.session
        except BaseException:
            driver.execute("ROLLBACK TO attune_write")
            driver.execute("RELEASE attune_write")
            del callbacks[mark:]
            raise
        driver.execute("RELEASE attune_write")

    async def committed(self) -> None:
        """Until the group's COMMIT (``ServiceUnavailable`` if it failed). A member whose
        request is cancelled stops waiting; the others, and the commit, go on."""
        await asyncio.shield(self.done)


CONNECT_TIMEOUT_S = 10
"""PostgreSQL: how long a new connection may take (libpq's ``connect_timeout``), unless the
database URL sets it."""


class Database:
    """One engine per process, and sessions that know whether they will write."""

    def __init__(self, settings: Settings) -> None:
        self.url = settings.database_url
        self.is_sqlite = settings.is_sqlite
        key = settings.database_key if self.is_sqlite else None  # None: a plain file
        kwargs: dict[str, Any] = {
            "pool_pre_ping": settings.db_pre_ping,
            "json_serializer": json_dumps,
            "json_deserializer": orjson.loads,
        }
        pool: dict[str, Any] = {}  # the main engine's: it counts the checkouts that wait
        if self.is_sqlite:
            kwargs["connect_args"] = {
                "timeout": settings.sqlite_busy_timeout_s,
                "check_same_thread": False,
            }
            if key is not None:
                kwargs["module"] = encryption.driver()  # EncryptionUnavailable without the extra
            if make_url(self.url).database not in (None, "", ":memory:"):
                pool = {"poolclass": MeteredQueuePool}  # SQLAlchemy's sizes for a file (5 + 10)
        else:
            # Behind a transaction pooler each transaction may run on another server
            # connection: a statement psycopg prepared on one (after prepare_threshold uses) is
            # unknown to the next ("prepared statement "_pg3_0" does not exist"), so none is.
            connect_args: dict[str, Any] = {}
            if settings.database_pooler == "transaction":
                connect_args["prepare_threshold"] = None
            # A database host that stops answering: a connect gives up after this (libpq waits
            # for the kernel's TCP timeout otherwise, minutes), unless the URL says otherwise.
            if "connect_timeout" not in make_url(self.url).query:
                connect_args["connect_timeout"] = CONNECT_TIMEOUT_S
            kwargs["connect_args"] = connect_args
            kwargs["pool_size"] = settings.db_pool_size
            kwargs["max_overflow"] = settings.db_pool_size
            pool = {"poolclass": MeteredQueuePool}
        self.engine: Engine = create_engine(self.url, **kwargs, **pool)
        if self.is_sqlite:
            _configure_sqlite(self.engine, settings.sqlite_busy_timeout_s, key)
        else:
            event.listen(self.engine, "handle_error", _mark_lost_connection)
        self._write_engine = self.engine.execution_options(**{_WRITE: True})
        # Single-statement reads (the caller's key): no BEGIN/COMMIT around them.
        self._autocommit_engine = self.engine.execution_options(isolation_level="AUTOCOMMIT")
        self._writer = threading.Lock() if self.is_sqlite else None
        self._writer_timeout_s = settings.sqlite_busy_timeout_s
        self._inline_engine: Engine | None = None
        self._group: WriteGroup | None = None
        self.groups = self.grouped = 0  # committed write groups, and the writes in them
        # PostgreSQL: robot writes run inline, rolled back there and sent to the pool (the
        # user's lock was taken), and sent to the pool at once (the round trip is too long).
        self.inlined = self.deferred = self.pooled = 0
        self.inline_mode = "false" if self.is_sqlite else settings.pg_inline_writes
        self.inline_max_rtt_s = settings.pg_inline_max_rtt_ms / 1000.0
        self.round_trip_s: float | None = None  # the median of the last probes (auto)
        self._probes: deque[float] = deque(maxlen=_PROBES_KEPT)
        if self.is_sqlite and settings.sqlite_inline_writes:
            inline = create_engine(self.url, pool_size=1, max_overflow=0, **kwargs)
            _configure_sqlite(inline, 0.0, key)
            self._inline_engine = inline.execution_options(**{_WRITE: True})
        elif self.inline_mode != "false":
            inline = create_engine(
                self.url,
                pool_size=1,
                max_overflow=0,
                **{k: v for k, v in kwargs.items() if k not in ("pool_size", "max_overflow")},
            )
            event.listen(inline, "handle_error", _mark_lost_connection)
            self._inline_engine = inline.execution_options(**{_WRITE: True})

    @property
    def writes_inline(self) -> bool:
        """PostgreSQL: the robots' short writes run on the event loop (:meth:`inline`): always
        with ``ATTUNE_PG_INLINE_WRITES=true``; with ``auto`` while the measured round trip is
        below ``ATTUNE_PG_INLINE_MAX_RTT_MS`` (none measured yet: not inline)."""
        if self.is_sqlite or self._inline_engine is None:
            return False
        if self.inline_mode == "true":
            return True
        rtt = self.round_trip_s
        return rtt is not None and rtt < self.inline_max_rtt_s

    @property
    def probes_round_trip(self) -> bool:
        """Whether this database decides where writes run by measuring (PostgreSQL, auto)."""
        return self.inline_mode == "auto" and self._inline_engine is not None

    def probe_round_trip(self, *, on_loop: bool = False) -> float | None:
        """Measure the round trip to the database: a few ``SELECT 1``, each timed as its wall
        time minus the CPU time of this thread (what the client itself spent on it), their
        median kept (not the fastest: a write waits for ten typical round trips, and a relay or
        a database on a saturated machine answers some fast and most slower); the round trip
        in force (:attr:`round_trip_s`) is the median of the last probes. ``None``, and
        nothing changed, if the database did not answer.

        ``on_loop``: on the event loop, on the inline connection (free between writes, and
        the thread's CPU clock then counts no other thread's work); it stops at a statement
        far over the threshold, so that a network grown slow holds the loop up once, for a
        round trip or two. Else on a connection of the pool, from any thread."""
        engine = self._inline_engine if on_loop else self._autocommit_engine
        assert engine is not None
        samples: list[float] = []
        try:
            with engine.connect() as conn:
                cursor: Any = conn.connection.driver_connection.cursor()  # type: ignore[union-attr]
                for _ in range(_SAMPLES + 1):  # the first also begins a transaction: not kept
                    wall, cpu = time.perf_counter(), time.thread_time()
                    cursor.execute("SELECT 1")
                    cursor.fetchone()
                    took = (time.perf_counter() - wall) - (time.thread_time() - cpu)
                    samples.append(max(0.0, took))
                    if on_loop and took > _SLOW * self.inline_max_rtt_s:
                        break  # far over the threshold: no need to hold the loop up longer
                cursor.close()
        except Exception as exc:  # the database is away: nothing known until it answers again
            log.warning("could not measure the round trip to the database: %s", exc)
            # The writes go to the thread pool (and the next probes run in a thread) until a
            # probe succeeds: a reconnect must not be made on the event loop.
            self._probes.clear()
            self.round_trip_s = None
            return None
        measured = statistics.median(samples[1:] or samples)
        self._probes.append(measured)
        self.round_trip_s = statistics.median(self._probes)
        return measured

    async def watch_round_trip(self, every_s: float = PROBE_EVERY_S) -> None:
        """Each worker's task, for its life (``auto``): measure the round trip every
        ``every_s`` seconds, on the loop while writes run there (the round trip is short),
        else in a thread of its own (the loop waits for nothing)."""
        while True:
            await asyncio.sleep(every_s)
            if self.writes_inline:
                self.probe_round_trip(on_loop=True)
            else:
                await asyncio.to_thread(self.probe_round_trip)

    @contextmanager
    def inline(self) -> Iterator[Session]:
        """PostgreSQL: a write transaction run on the event loop, on this process's inline
        connection (the loop runs one at a time, so it is always free), that takes the user's
        lock only if it is free at once: else :class:`LockBusy` leaves the block (rolled back,
        nothing written) and the caller runs the write in the thread pool, where it may wait.

        It spares each robot write two hand-offs between the event loop and a pool thread,
        which cost more CPU than the write's statements; while it runs, the loop waits for the
        database's answers (a few local round trips), as a SQLite write group does.
        """
        assert self._inline_engine is not None
        try:
            with Session(bind=self._inline_engine, expire_on_commit=False) as session:
                session.info[NOWAIT] = True
                with self.within(session, write=True):
                    yield session
        except LockBusy:
            self.deferred += 1
            raise
        self.inlined += 1

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

    def join_group(self, loop: asyncio.AbstractEventLoop) -> WriteGroup | None:
        """The write group of this turn of the event loop, opened if need be; ``None`` when it
        cannot start without waiting (PostgreSQL, another writer of this process has the turn,
        or another process holds SQLite's write lock: these connections never wait for it).

        SQLite group commit: the robots' short writes that the event loop runs in one turn
        share one transaction, each inside a savepoint of its own, and one COMMIT at the end of
        the turn makes them all durable; none of them answers before that. With one writer at
        a time anyway, running them in place saves two hand-offs to a thread each, and the
        shared COMMIT writes each changed page once per turn, not once per write.
        """
        if self._group is not None:
            return self._group
        if self._inline_engine is None or self._writer is None:  # PostgreSQL: see inline()
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
        self._group = WriteGroup(session, loop.create_future())
        loop.call_soon(self._commit_group)
        return self._group

    def _commit_group(self) -> None:
        group, self._group = self._group, None
        assert group is not None
        assert self._writer is not None
        try:
            group.session.commit()
        except BaseException as exc:  # the disk, most likely: every member fails, retryably
            group.session.rollback()
            log.error("a group of %d writes could not be committed: %s", group.members, exc)
            group.done.set_exception(
                ServiceUnavailable("The database could not store this write; retry.")
            )
        else:
            self.groups += 1
            self.grouped += group.members
            for callback in group.session.info.pop("after_commit", []):
                callback()
            group.done.set_result(None)
        finally:
            group.session.close()
            self._writer.release()

    def dispose(self) -> None:
        self.engine.dispose()
        if self._inline_engine is not None:
            self._inline_engine.dispose()


def _mark_lost_connection(ctx: ExceptionContext) -> None:
    """A driver error that means the connection is gone (``is_lost_connection``: the server
    closed it, ended the session, or a pooler in between lost it) is a disconnect, whatever its
    message: the pool drops the connection and every one opened before it, so the request that
    met it is the only one to fail (503, which clients retry), not every later one that would
    be handed a dead connection from the pool."""
    if not ctx.is_disconnect and is_lost_connection(ctx.original_exception):
        ctx.is_disconnect = True


def _configure_sqlite(engine: Engine, busy_timeout_s: float, key: SecretStr | None) -> None:
    if key is not None:
        encryption.apply_key(engine, key)
    locked: type[Exception] = engine.dialect.loaded_dbapi.OperationalError

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
        statement = "BEGIN IMMEDIATE" if options.get(_WRITE, False) else "BEGIN"
        try:
            driver.execute(statement)
        except locked as exc:  # "database is locked": SQLAlchemy's, as any
            raise OperationalError(statement, None, exc) from exc
