"""The floor under a robot request's CPU: what the work every request must do costs on this
machine, with nothing around it.

``bench/service.py`` measures the service's CPU per robot-loop request against a bare FastAPI
POST. This module measures, in the same run, the two parts of that request no change outside
them can leave out, each alone:

- **the learner**: the decision (``select_action``, with the decision's seeded generator) and
  the update (``update``) the requests make, timed on the CPU clock around those calls only;
- **the statements**: the SQL the requests run, with their parameters exactly as the service
  sent them to the driver, replayed through the bare DB-API driver (``sqlite3``, ``psycopg``)
  on a copy of the database taken just before, as the service runs them: on SQLite in write
  groups (one ``BEGIN IMMEDIATE`` and ``COMMIT`` per turn of the robots, a savepoint per
  request), on PostgreSQL one transaction per request with the writes sent in one pipeline.
  No SQLAlchemy, no session, no service code.

Both come from robot loops run in-process through the service's use cases (start an episode,
answer each decision as the benchmark's robots do), on a fresh database, after a warm-up that
creates the users. The bare POST's CPU comes from the reference the benchmark already runs.
Their sum is what a robot request costs at the least with this design; the CPU target minus
that floor is what is left for everything else a request does (reading and checking its body,
authentication, the service's logic, SQLAlchemy, the response).
"""

from __future__ import annotations

import contextlib
import sqlite3
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["Floor", "measure", "remove_copy"]


@dataclass
class Floor:
    """Per robot request: the learner's CPU, the statements replayed, and their CPU."""

    requests: int
    learner_ms: float
    statements_per_request: float
    statements_ms: float
    copy: str | None = None  # the replayed copy's URL, when kept (``measure(keep_copy=True)``)


@dataclass
class _Op:
    sql: str
    args: Any
    many: bool
    fetch: bool
    batch: int | None  # the service's ``batch`` block it ran in (PostgreSQL: one pipeline)


class _Recorder:
    """Records every statement the service sends to its driver, per request, and times the
    learner's calls on the CPU clock."""

    def __init__(self) -> None:
        self.requests: list[list[_Op]] = []
        self.learner_s = 0.0
        self.batch: int | None = None
        self._batches = 0
        self._undo: list[Callable[[], None]] = []

    def new_request(self) -> None:
        self.requests.append([])

    def add(self, sql: str, args: Any, *, many: bool, fetch: bool) -> None:
        if self.requests:
            self.requests[-1].append(_Op(sql, args, many, fetch, self.batch))

    @contextlib.contextmanager
    def batched(self) -> Iterator[None]:
        self._batches += 1
        self.batch = self._batches
        try:
            yield
        finally:
            self.batch = None

    def patch(self, owner: Any, name: str, make: Callable[[Any], Any]) -> None:
        original = getattr(owner, name)
        setattr(owner, name, make(original))
        self._undo.append(lambda: setattr(owner, name, original))

    def timed(self, original: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            t = time.process_time()
            try:
                return original(*args, **kwargs)
            finally:
                self.learner_s += time.process_time() - t

        return call

    def restore(self) -> None:
        while self._undo:
            self._undo.pop()()


@contextlib.contextmanager
def _recording(sa_engine: Any) -> Iterator[_Recorder]:
    """While open: the statements of ``sa_engine``'s connections (through the repositories'
    prepared statements, or through SQLAlchemy) are recorded, with the ``batch`` blocks of the
    robots' writes they ran in, and the learner is timed."""
    from sqlalchemy import event

    from app.db.repositories import _rows
    from app.learning.learners import base
    from app.services.episodes import write

    rec = _Recorder()

    def prepared(original: Callable[..., Any]) -> Callable[..., Any]:
        def execute(self: Any, session: Any, params: Any, fetch: int) -> Any:
            dialect = session.connection().dialect
            rows = params if isinstance(params, list) else [params]
            compiled = self._for(dialect, rows[0])
            if isinstance(params, list):
                rec.add(compiled.sql, [compiled.args(p) for p in rows], many=True, fetch=False)
            else:
                rec.add(compiled.sql, compiled.args(params), many=False, fetch=fetch > 0)
            return original(self, session, params, fetch)

        return execute

    def batch(original: Callable[..., Any]) -> Callable[..., Any]:
        @contextlib.contextmanager
        def block(session: Any) -> Iterator[None]:
            with original(session), rec.batched():
                yield

        return block

    def core(
        _conn: Any, _cursor: Any, statement: str, parameters: Any, _context: Any, executemany: bool
    ) -> None:
        # SQLAlchemy also reports a single row sent through its many-rows path as executemany.
        many = executemany and isinstance(parameters, list)
        rec.add(statement, parameters, many=many, fetch=not many)

    try:
        rec.patch(_rows.Prepared, "_execute", prepared)
        rec.patch(write, "batch", batch)
        rec.patch(base.TabularLearner, "select_action", rec.timed)
        rec.patch(base.TabularLearner, "update", rec.timed)
        rec.patch(write, "rng_for", rec.timed)
        event.listen(sa_engine, "before_cursor_execute", core)
        try:
            yield rec
        finally:
            event.remove(sa_engine, "before_cursor_execute", core)
    finally:
        rec.restore()


def _run(cursor: Any, op: _Op) -> None:
    if op.many:
        cursor.executemany(op.sql, op.args)
        return
    cursor.execute(op.sql, op.args)
    if op.fetch and cursor.description is not None:
        cursor.fetchall()


def _replay_sqlite(path: Path, requests: list[list[_Op]], group: int) -> float:
    """CPU seconds of the requests' statements through ``sqlite3``, with the service's pragmas,
    as its write groups run them: ``group`` requests per ``BEGIN IMMEDIATE`` ... ``COMMIT``,
    each in a savepoint."""
    with contextlib.closing(sqlite3.connect(path, isolation_level=None)) as conn:
        for pragma in ("journal_mode=WAL", "synchronous=NORMAL", "foreign_keys=ON"):
            conn.execute(f"PRAGMA {pragma}")
        t = time.process_time()
        for lo in range(0, len(requests), group):
            conn.execute("BEGIN IMMEDIATE")
            for ops in requests[lo : lo + group]:
                conn.execute("SAVEPOINT attune_write")
                for op in ops:
                    cursor = conn.cursor()
                    _run(cursor, op)
                    cursor.close()
                conn.execute("RELEASE attune_write")
            conn.execute("COMMIT")
        return time.process_time() - t


def _replay_postgresql(url: str, requests: list[list[_Op]]) -> float:
    """CPU seconds of the requests' statements through ``psycopg``, one transaction each, the
    statements of one ``batch`` block in one pipeline (as the service sends its writes)."""
    import psycopg

    with psycopg.connect(url) as conn:
        t = time.process_time()
        for ops in requests:
            i = 0
            while i < len(ops):
                block = ops[i].batch
                j = i + 1
                while block is not None and j < len(ops) and ops[j].batch == block:
                    j += 1
                with contextlib.ExitStack() as stack:
                    if block is not None:
                        stack.enter_context(conn.pipeline())
                    for op in ops[i:j]:
                        with conn.cursor() as cursor:
                            _run(cursor, op)
                i = j
            conn.commit()
        return time.process_time() - t


def _pg_admin(pg_server: str, sql: str) -> None:
    import psycopg

    with psycopg.connect(f"{pg_server}/postgres", autocommit=True) as conn:
        conn.execute(sql)


def remove_copy(copy: str, pg_server: str) -> None:
    """Remove a copy :func:`measure` kept (its URL)."""
    if copy.startswith("sqlite:///"):
        path = copy.removeprefix("sqlite:///")
        for suffix in ("", "-wal", "-shm"):
            Path(path + suffix).unlink(missing_ok=True)
    else:
        _pg_admin(pg_server, f'DROP DATABASE IF EXISTS "{copy.rsplit("/", 1)[1]}" WITH (FORCE)')


def _copy(kind: str, database_url: str, pg_server: str) -> str:
    """A copy of the database, as a URL of SQLAlchemy's (plain for the drivers below)."""
    if kind == "sqlite":
        path = Path(database_url.removeprefix("sqlite:///"))
        copy = path.with_name(path.stem + "-floor.db")
        with (
            contextlib.closing(sqlite3.connect(path)) as src,
            contextlib.closing(sqlite3.connect(copy)) as dst,
        ):
            src.backup(dst)
        return f"sqlite:///{copy}"
    source = database_url.rsplit("/", 1)[1]
    name = f"{source}_floor"
    _pg_admin(pg_server, f'CREATE DATABASE "{name}" TEMPLATE "{source}"')
    return f"postgresql+psycopg://{pg_server.split('://', 1)[1]}/{name}"


def measure(
    kind: str,
    database_url: str,
    data: Any,
    users: list[str],
    requests: int,
    pg_server: str,
    progress: Callable[[str], None] = lambda _: None,
    *,
    group: int = 8,
    keep_copy: bool = False,
) -> Floor:
    """The floor on ``database_url``, a fresh database of ``kind`` (``sqlite``,
    ``postgresql``), through ``data`` (the benchmark's in-process access to it:
    ``history(user, n, tag=...)`` plays whole episodes, one transaction per request, through
    ``data.db``): a warm-up episode per user, a copy of the database, at least ``requests``
    recorded requests of ``users`` in turn, and their replay on the copy (SQLite: ``group``
    requests per write group, the robots of a turn). The copy is removed, unless
    ``keep_copy`` and the measure succeeded (:func:`remove_copy` then): the replay must leave
    it as the recorded run left the original."""
    if requests < 1 or group < 1:
        raise ValueError("requests and group must be at least 1")
    for user in users:
        data.history(user, 1, tag="floor-warm")  # creates the users, warms the caches
    data.db.dispose()
    copy = _copy(kind, database_url, pg_server)
    kept = False
    try:
        transaction = data.db.transaction

        @contextlib.contextmanager
        def counted(*args: Any, **kwargs: Any) -> Iterator[Any]:
            rec.new_request()
            with transaction(*args, **kwargs) as session:
                yield session

        progress(f"  floor: recording about {requests} requests in-process")
        with _recording(data.db.engine) as rec:
            data.db.transaction = counted
            try:
                turn = 0
                while len(rec.requests) < requests:
                    for user in users:
                        data.history(user, 1, tag=f"floor-{turn}")
                    turn += 1
            finally:
                del data.db.transaction
        replayed = [ops for ops in rec.requests if ops]
        progress(f"  floor: replaying {sum(map(len, replayed))} statements through the driver")
        if kind == "sqlite":
            replay_s = _replay_sqlite(Path(copy.removeprefix("sqlite:///")), replayed, group)
        else:
            replay_s = _replay_postgresql(copy.replace("+psycopg", "", 1), replayed)
        kept = keep_copy
    finally:
        if not kept:
            remove_copy(copy, pg_server)
    n = len(rec.requests)
    return Floor(
        requests=n,
        learner_ms=rec.learner_s * 1000 / n,
        statements_per_request=sum(map(len, rec.requests)) / n,
        statements_ms=replay_s * 1000 / n,
        copy=copy if kept else None,
    )
