"""PostgreSQL: the robots' short writes run on the event loop when the user's lock is free at
once, and in the thread pool when they would have to wait for it: a write whose user is locked
by another transaction waits without holding up the worker's other requests, and is stored once
when the lock comes free. (SQLite's counterpart, the write group, waits for no lock either: it
forms only when the database's write lock is free.)

With ``ATTUNE_PG_INLINE_WRITES=auto`` (the default) a worker measures the round trip to the
database before its first request and every few seconds after, and writes inline only while it
is below ``ATTUNE_PG_INLINE_MAX_RTT_MS``; ``attune_robot_writes_total`` says where each went."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import httpx
import psycopg
import pytest
from fastapi import FastAPI
from sqlalchemy import func, select

from app.db.models import Decision
from app.db.session import Database
from app.main import create_app
from app.services.auth import create_key
from app.settings import Settings
from tests.support.episodes import event, report, start
from tests.support.fixtures import MakeKey
from tests.support.live import free_port, serving


@contextmanager
def user_held(database_url: str, user_id: str) -> Iterator[None]:
    """Another transaction that holds the user's row lock until the block ends."""
    other = psycopg.connect(database_url.replace("postgresql+psycopg://", "postgresql://"))
    other.execute("SELECT id FROM users WHERE user_id = %s FOR UPDATE", (user_id,))
    try:
        yield
    finally:
        other.rollback()
        other.close()


def test_a_write_on_a_locked_user_waits_aside_and_is_stored_once(
    app: FastAPI, db: Database, make_key: MakeKey, database_url: str
) -> None:
    if db.is_sqlite:
        pytest.skip("PostgreSQL's inline writes and row locks")
    key = make_key("robot")
    headers = {"Authorization": f"Bearer {key}"}
    with serving(app) as base, httpx.Client(base_url=base, headers=headers, timeout=30) as http:
        first = http.post("/v1/users/held/episodes", json=event("held-1"))
        assert first.status_code == 201, first.text
        episode = first.json()
        before = (db.inlined, db.deferred)
        outcome = {"decision_id": episode["decision"]["decision_id"], "response": "accepted"}
        answered: dict[str, Any] = {}
        with user_held(database_url, "held"):
            writer = threading.Thread(
                target=lambda: answered.update(
                    r=http.post(f"/v1/episodes/{episode['episode_id']}/outcomes", json=outcome)
                )
            )
            writer.start()
            # While the write waits for the lock, the worker still answers other requests.
            for _ in range(3):
                assert http.get("/healthz").status_code == 200
            assert writer.is_alive(), "the write did not wait for the user's lock"
        writer.join(timeout=30)
        assert not writer.is_alive()
        assert answered["r"].status_code == 200, answered["r"].text
        again = http.post(f"/v1/episodes/{episode['episode_id']}/outcomes", json=outcome)
        assert again.status_code == 200
        assert again.json() == answered["r"].json()
    with db.transaction(write=False) as session:
        stored = session.execute(
            select(func.count())
            .select_from(Decision)
            .where(Decision.outcome_hash.is_not(None), Decision.episode_id == episode["episode_id"])
        ).scalar_one()
    assert stored == 1
    # The held write went to the pool; the replay, with the lock free, ran inline.
    assert db.deferred == before[1] + 1
    assert db.inlined > before[0]


def _auto(settings: Settings, **kw: Any) -> Settings:
    """The test's settings (its database, through PgBouncer or not) with the choice left to
    the measured round trip."""
    return settings.model_copy(update={"pg_inline_writes": "auto", **kw})


def test_auto_writes_inline_only_below_the_round_trip_it_measured(settings: Settings) -> None:
    db = Database(_auto(settings))
    try:
        if db.is_sqlite:
            assert not db.probes_round_trip
            assert not db.writes_inline
            return
        assert db.probes_round_trip
        assert not db.writes_inline, "nothing measured yet: the thread pool"
        measured = db.probe_round_trip()
        assert measured is not None
        assert measured >= 0
        assert db.round_trip_s == measured
        assert db.probe_round_trip(on_loop=True) is not None  # on the inline connection
        db.inline_max_rtt_s = db.round_trip_s * 2 + 1.0
        assert db.writes_inline
        db.inline_max_rtt_s = db.round_trip_s / 2 if db.round_trip_s else 0.0
        assert not db.writes_inline
    finally:
        db.dispose()


def test_auto_sends_the_writes_to_the_pool_when_the_round_trip_is_long(
    settings: Settings, empty_tables: None
) -> None:
    if settings.database_url.startswith("sqlite"):
        pytest.skip("PostgreSQL's inline writes")
    # Any real round trip is longer than a nanosecond: every write goes to the thread pool.
    application = create_app(_auto(settings, pg_inline_max_rtt_ms=1e-6))
    db: Database = application.state.db
    with db.transaction() as session:
        _, key = create_key(session, role="robot", name="far")
    headers = {"Authorization": f"Bearer {key}"}
    with (
        serving(application) as base,
        httpx.Client(base_url=base, headers=headers, timeout=30) as http,
    ):
        episode = start(http, "far", "far-1")
        report(http, episode["episode_id"], episode["decision"]["decision_id"], "accepted")
        metrics = http.get("/metrics").text
    assert db.round_trip_s is not None
    assert db.round_trip_s > 0
    assert not db.writes_inline
    assert (db.inlined, db.pooled) == (0, 2)
    assert 'attune_robot_writes_total{path="pool"} 2.0' in metrics
    assert 'attune_robot_writes_total{path="inline"} 0.0' in metrics


def test_false_makes_no_inline_connection(database_url: str) -> None:
    db = Database(
        Settings(database_url=database_url, pg_inline_writes="false", _env_file=None)  # type: ignore[call-arg]
    )
    try:
        assert not db.writes_inline
        assert not db.probes_round_trip
    finally:
        db.dispose()


def test_a_probe_that_fails_sends_the_writes_to_the_pool() -> None:
    """A database that stops answering: what was measured before no longer holds, so the
    writes (and the reconnects they would make) leave the event loop until a probe succeeds."""
    port = free_port()  # nothing listens there: the connect is refused at once
    db = Database(
        Settings(  # type: ignore[call-arg]
            database_url=f"postgresql+psycopg://postgres@127.0.0.1:{port}/none",
            pg_inline_writes="auto",
            _env_file=None,
        )
    )
    try:
        db._probes.append(0.0001)  # as if a short round trip had been measured
        db.round_trip_s = 0.0001
        assert db.writes_inline
        assert db.probe_round_trip(on_loop=True) is None
        assert db.round_trip_s is None
        assert not db.writes_inline
    finally:
        db.dispose()
