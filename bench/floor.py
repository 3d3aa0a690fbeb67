"""The floor under a robot request's CPU: what the work every request must do costs on this
machine, with nothing around it.

``bench/service.py`` measures the service's CPU per robot-loop request against a bare FastAPI
POST. This module measures, in the same run, the two parts of that request no design can leave
out, each alone:

- **the learner**: the decision (``select_action``, with the decision's seeded generator) and
  the update (``update``) the requests make, timed on the CPU clock around those calls only;
- **the statements**: the SQL the requests run, with their parameters exactly as the service
  sent them to the driver, replayed through the bare DB-API driver (``sqlite3``, ``psycopg``)
  on a copy of the database taken just before, in the service's transactions (SQLite: one per
  turn of 8 writers, as its write groups commit; PostgreSQL: one per request). No SQLAlchemy,
  no session, no service code.

Both come from robot loops run in-process through the service's use cases (start an episode,
answer each decision as the benchmark's robots do), on a fresh database, after a warm-up that
creates the users. The bare POST's CPU comes from the reference the benchmark already runs.
Their sum is a lower bound on what a robot request can cost with this design; the CPU target
minus that floor is what is left for everything else a request does (reading and checking its
body, authentication, the service's logic, SQLAlchemy, the response).
"""

from __future__ import annotations

import contextlib
import sqlite3
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["Floor", "measure"]

WRITERS_PER_TURN = 8  # SQLite: the write group of 8 robots commits once per turn


@dataclass
class Floor:
    """Per robot request: the learner's CPU, the statements replayed, and their CPU."""

    requests: int
    learner_ms: float
    statements: float
    statements_ms: float
    copy: str | None = None  # the replayed copy's URL, when kept (``measure(keep_copy=True)``)


@dataclass
class _Op:
    sql: str
    args: Any
    many: bool
    fetch: bool


class _Recorder:
    """Records every statement the service sends to its driver, per request, and times the
    learner's calls on the CPU clock."""

    def __init__(self) -> None:
        self.requests: list[list[_Op]] = []
        self.learner_s = 0.0
        self._undo: list[Callable[[], None]] = []

    def new_request(self) -> None:
        self.requests.append([])

    def add(self, op: _Op) -> None:
        if self.requests:
            self.requests[-1].append(op)

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
def _recording(engine: Any) -> Iterator[_Recorder]:
    """While open: the statements of ``engine``'s connections (through the repositories'
    prepared statements or through SQLAlchemy) are recorded, and the learner is timed."""
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
                rec.add(_Op(compiled.sql, [compiled.args(p) for p in rows], True, False))
            else:
                rec.add(_Op(compiled.sql, compiled.args(params), False, fetch > 0))
            return original(self, session, params, fetch)
        return execute

    def core(_conn: Any, cursor: Any, statement: str, parameters: Any, _context: Any,
             executemany: bool) -> None:
        rec.add(_Op(statement, parameters, executemany, not executemany))

    rec.patch(_rows.Prepared, "_execute", prepared)
    rec.patch(base.TabularLearner, "select_action", rec.timed)
    rec.patch(base.TabularLearner, "update", rec.timed)
    rec.patch(write, "rng_for", rec.timed)
    event.listen(engine, "before_cursor_execute", core)
    try:
        yield rec
    finally:
        event.remove(engine, "before_cursor_execute", core)
        rec.restore()


def _run(cursor: Any, op: _Op) -> None:
    if op.many:
        cursor.executemany(op.sql, op.args)
        return
    cursor.execute(op.sql, op.args)
    if op.fetch and cursor.description is not None:
        cursor.fetchall()


def _replay_sqlite(path: Path, requests: list[list[_Op]]) -> float:
    """CPU seconds of the requests' statements through ``sqlite3``, with the service's pragmas,
    in write transactions of ``WRITERS_PER_TURN`` requests."""
    conn = sqlite3.connect(path, isolation_level=None)
    try:
        for pragma in ("journal_mode=WAL", "synchronous=NORMAL", "foreign_keys=ON"):
            conn.execute(f"PRAGMA {pragma}")
        t = time.process_time()
        for lo in range(0, len(requests), WRITERS_PER_TURN):
            conn.execute("BEGIN IMMEDIATE")
            for ops in requests[lo:lo + WRITERS_PER_TURN]:
                for op in ops:
                    cursor = conn.cursor()
                    _run(cursor, op)
                    cursor.close()
            conn.execute("COMMIT")
        return time.process_time() - t
    finally:
        conn.close()


def _replay_postgresql(url: str, requests: list[list[_Op]]) -> float:
    """CPU seconds of the requests' statements through ``psycopg``, one transaction each."""
    import psycopg

    with psycopg.connect(url) as conn:
        t = time.process_time()
        for ops in requests:
            for op in ops:
                with conn.cursor() as cursor:
                    _run(cursor, op)
            conn.commit()
        return time.process_time() - t


def _copy_postgresql(server_url: str, source: str, name: str) -> None:
    import psycopg

    with psycopg.connect(f"{server_url}/postgres", autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}" TEMPLATE "{source}"')


def _drop_postgresql(server_url: str, name: str) -> None:
    import psycopg

    with psycopg.connect(f"{server_url}/postgres", autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def measure(engine: str, database_url: str, data: Any, users: list[str], requests: int,
            pg_server: str, progress: Callable[[str], None] = lambda _: None, *,
            keep_copy: bool = False) -> Floor:
    """The floor on ``database_url`` (a fresh database), through ``data`` (the benchmark's
    in-process access to it: ``history(user, n, tag=...)`` plays whole episodes, one
    transaction per request, through ``data.db``): a warm-up episode per user, a copy of the
    database, about ``requests`` recorded requests, and their replay on the copy (removed
    after, unless ``keep_copy``: the replay must leave it as the recorded run left the
    original)."""
    for user in users:
        data.history(user, 1, tag="floor-warm")  # creates the users, warms the caches
    data.db.dispose()
    if engine == "sqlite":
        path = Path(database_url.removeprefix("sqlite:///"))
        copy = path.with_name(path.stem + "-floor.db")
        with sqlite3.connect(path) as src, sqlite3.connect(copy) as dst:
            src.backup(dst)
        target: str = str(copy)
        kept = f"sqlite:///{copy}"
    else:
        name = database_url.rsplit("/", 1)[1] + "_floor"
        _copy_postgresql(pg_server, database_url.rsplit("/", 1)[1], name)
        target = f"{pg_server}/{name}"
        kept = f"postgresql+psycopg://{pg_server.split('://', 1)[1]}/{name}"
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
                round_ = 0
                while len(rec.requests) < requests:
                    for user in users:
                        data.history(user, 1, tag=f"floor-{round_}")
                    round_ += 1
            finally:
                del data.db.transaction
        ops = [r for r in rec.requests if r]
        progress(f"  floor: replaying {sum(map(len, ops))} statements through the driver")
        if engine == "sqlite":
            replay_s = _replay_sqlite(Path(target), ops)
        else:
            replay_s = _replay_postgresql(target, ops)
    finally:
        if keep_copy:
            pass
        elif engine == "sqlite":
            Path(target).unlink(missing_ok=True)
            for suffix in ("-wal", "-shm"):
                Path(target + suffix).unlink(missing_ok=True)
        else:
            _drop_postgresql(pg_server, target.rsplit("/", 1)[1])
    n = len(rec.requests)
    return Floor(requests=n, learner_ms=rec.learner_s * 1000 / n,
                 statements=sum(map(len, rec.requests)) / n,
                 statements_ms=replay_s * 1000 / n, copy=kept if keep_copy else None)
