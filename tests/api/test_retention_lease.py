"""The retention lease (``leases``), on SQLite, PostgreSQL and through PgBouncer in transaction
pooling: one holder at a time, a holder that dies lets it run out, a renewal keeps it, takers at
once find one winner; a run under the lease stops when it is lost or its worker stops; the
service's run at a set time runs once however many workers wake for it, and not while another
run holds the lease; the app's lifespan starts and stops the schedule.

Times are given to the lease (no test waits for one to pass)."""

from __future__ import annotations

import datetime as dt
import logging
import threading
import time
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.daily import DailyTime
from app.db.models import AuditEntry
from app.db.repositories import leases as repo
from app.db.session import Database
from app.main import create_app
from app.services import leases
from app.services.leases import LeaseHeld, LeaseLost
from app.services.retention_runs import LEASE, DailyRetention, RunStopped, run_held
from app.settings import Settings
from tests.support.episodes import start

T0 = dt.datetime(2026, 12, 3, 3, 30, tzinfo=dt.UTC)
TTL = dt.timedelta(seconds=60)


def s(seconds: float) -> dt.datetime:
    return T0 + dt.timedelta(seconds=seconds)


def _row(db: Database, name: str = LEASE) -> repo.LeaseRow:
    with db.transaction(write=False) as session:
        row = repo.get(session, name)
    assert row is not None
    return row


class TestLease:
    def test_one_holder_at_a_time_until_it_lets_go(self, db: Database) -> None:
        a = leases.take(db, LEASE, now=s(0), ttl=TTL, holder="web-1:11:aaaaaa")
        with pytest.raises(LeaseHeld) as held:
            leases.take(db, LEASE, now=s(30), ttl=TTL, holder="web-2:22:bbbbbb")
        assert held.value.current is not None
        assert held.value.current.holder == "web-1:11:aaaaaa"
        assert not held.value.already_ran
        assert held.value.sentence() == (
            "another process holds the lease: web-1:11:aaaaaa, since 2026-12-03 03:30:00 UTC, "
            "until 2026-12-03 03:31:00 UTC unless it renews it"
        )
        a.release(s(40))
        assert _row(db).expires_at == s(40)
        b = leases.take(db, LEASE, now=s(41), ttl=TTL, holder="web-2:22:bbbbbb")
        assert (_row(db).holder, _row(db).acquired_at) == ("web-2:22:bbbbbb", s(41))
        # The first holder's late release changes nothing of the second's.
        a.release(s(42))
        assert _row(db).expires_at == b.expires_at == s(101)

    def test_a_holder_that_dies_lets_it_run_out(self, db: Database) -> None:
        dead = leases.take(db, LEASE, now=s(0), ttl=TTL)  # never renewed, never let go
        with pytest.raises(LeaseHeld):
            leases.take(db, LEASE, now=s(59.999), ttl=TTL)
        alive = leases.take(db, LEASE, now=s(60), ttl=TTL)
        assert _row(db).holder == alive.holder != dead.holder
        # Were the first holder only slow, its next renewal finds the lease gone: it stops.
        assert dead.renew(s(61)) is False
        with pytest.raises(LeaseLost, match="another process took it"):
            dead.check()
        assert _row(db).holder == alive.holder
        alive.check()

    def test_a_renewal_keeps_it(self, db: Database) -> None:
        a = leases.take(db, LEASE, now=s(0), ttl=TTL)
        assert a.renew(s(50)) is True
        assert a.expires_at == _row(db).expires_at == s(110)
        with pytest.raises(LeaseHeld):
            leases.take(db, LEASE, now=s(100), ttl=TTL)  # free by now without the renewal
        leases.take(db, LEASE, now=s(110), ttl=TTL)

    def test_leases_of_other_names_are_apart(self, db: Database) -> None:
        leases.take(db, LEASE, now=s(0), ttl=TTL)
        leases.take(db, "another-job", now=s(0), ttl=TTL)
        with pytest.raises(LeaseHeld):
            leases.take(db, "another-job", now=s(1), ttl=TTL)

    def test_a_set_time_is_run_once(self, db: Database) -> None:
        """``since``: the first process to wake for a set time runs it; one that wakes after it
        finished finds it done; the command, and the next day's time, are not held back."""
        due = s(0)
        first = leases.take(db, LEASE, now=s(1), ttl=TTL, since=due)
        first.release(s(2))
        with pytest.raises(LeaseHeld) as held:
            leases.take(db, LEASE, now=s(3), ttl=TTL, since=due)
        assert held.value.already_ran
        assert held.value.sentence().startswith("it already ran: ")
        leases.take(db, LEASE, now=s(4), ttl=TTL).release(s(5))  # by hand, at once
        leases.take(db, LEASE, now=s(86_401), ttl=TTL, since=s(86_400))

    def test_takers_at_once_find_one_winner(self, db: Database) -> None:
        takers, won, lost = 8, [], []
        ready = threading.Barrier(takers)

        def try_it(n: int) -> None:
            ready.wait()
            try:
                won.append(leases.take(db, LEASE, now=s(0), ttl=TTL, holder=f"taker-{n}"))
            except LeaseHeld as held:
                lost.append(held)

        threads = [threading.Thread(target=try_it, args=(n,)) for n in range(takers)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(won) == 1
        assert len(lost) == takers - 1
        assert _row(db).holder == won[0].holder
        assert {h.current.holder for h in lost if h.current is not None} <= {won[0].holder}

    def test_held_renews_from_its_thread_and_lets_go_at_the_end(self, db: Database) -> None:
        now = [s(0)]
        with leases.held(
            db, LEASE, ttl=TTL, renew_every=dt.timedelta(milliseconds=5), clock=lambda: now[0]
        ) as lease:
            assert _row(db).expires_at == s(60)
            now[0] = s(45)
            deadline = time.monotonic() + 30
            # The renewer's next turn moves the row, then (after its commit) the lease it holds:
            # wait for both, or a read between the two sees the row moved and the lease not yet.
            while _row(db).expires_at != s(105) or lease.expires_at != s(105):
                assert time.monotonic() < deadline, "the lease was never renewed"
                time.sleep(0.01)
            now[0] = s(50)
        assert _row(db).expires_at == s(50)  # let go: free from then on
        leases.take(db, LEASE, now=s(50), ttl=TTL)


def _fleet_with_a_window(app: FastAPI, make_key: Any, people: int = 3) -> None:
    """``people`` people of fleet ``default`` with an episode each, and a window of 30 days."""
    with TestClient(app, headers={"Authorization": f"Bearer {make_key('staff')}"}) as staff:
        for n in range(people):
            assert staff.put(f"/v1/users/p{n}", json={}).status_code == 201
            start(staff, f"p{n}", f"e{n}")
        r = staff.put("/v1/admin/fleets/default/history", json={"history_days": 30})
        assert r.status_code == 200, r.text


def _retention_entries(db: Database) -> int:
    with db.transaction(write=False) as session:
        return len(
            session.scalars(
                select(AuditEntry.id).where(AuditEntry.action == "fleet.retention")
            ).all()
        )


class TestRunHeld:
    def test_a_run_holds_the_lease_and_lets_it_go(
        self, app: FastAPI, db: Database, make_key: Any
    ) -> None:
        _fleet_with_a_window(app, make_key)
        seen: list[str] = []

        def progress(fleet: str, user_id: str) -> None:
            with pytest.raises(LeaseHeld):  # a second run, meanwhile
                run_held(db, app.state.ctx)
            seen.append(user_id)

        report = run_held(db, app.state.ctx, progress=progress)
        assert seen == ["p0", "p1", "p2"]
        assert [f.fleet for f in report.fleets] == ["default"]
        assert _row(db).expires_at <= dt.datetime.now(dt.UTC)
        run_held(db, app.state.ctx)  # free again
        assert _retention_entries(db) == 2

    def test_a_run_stops_after_the_person_in_hand_when_its_worker_stops(
        self, app: FastAPI, db: Database, make_key: Any
    ) -> None:
        _fleet_with_a_window(app, make_key)
        seen: list[str] = []
        with pytest.raises(RunStopped):
            run_held(
                db,
                app.state.ctx,
                progress=lambda _fleet, user_id: seen.append(user_id),
                stopping=lambda: len(seen) >= 2,
            )
        assert seen == ["p0", "p1"]
        assert _row(db).expires_at <= dt.datetime.now(dt.UTC)  # let go
        assert _retention_entries(db) == 0  # the fleet was not finished: no entry

    def test_a_run_whose_lease_was_lost_stops_after_the_person_in_hand(
        self, app: FastAPI, db: Database, make_key: Any
    ) -> None:
        _fleet_with_a_window(app, make_key)
        held: list[leases.Lease] = []
        seen: list[str] = []

        def taken_meanwhile(_fleet: str, user_id: str) -> None:
            seen.append(user_id)
            # The lease ran out while this holder could not reach the database, and another
            # process took it: this holder's next renewal finds it gone.
            later = dt.datetime.now(dt.UTC) + dt.timedelta(hours=1)
            other = leases.take(db, LEASE, now=later, ttl=TTL, holder="web-2:22:bbbbbb")
            assert other.holder == "web-2:22:bbbbbb"
            assert held[0].renew(later) is False

        with pytest.raises(LeaseLost):
            run_held(db, app.state.ctx, progress=taken_meanwhile, started=held.append)
        assert seen == ["p0"]
        assert _row(db).holder == "web-2:22:bbbbbb"  # the loser let nothing go


class TestSchedule:
    def test_the_set_time_runs_once_however_many_workers_wake_for_it(
        self,
        app: FastAPI,
        db: Database,
        make_key: Any,
        caplog: pytest.LogCaptureFixture,
    ) -> None:
        _fleet_with_a_window(app, make_key, people=1)
        workers = [DailyRetention(db, app.state.ctx, DailyTime(dt.time(3, 30))) for _ in range(3)]
        due = dt.datetime.now(dt.UTC).replace(microsecond=0) - dt.timedelta(seconds=1)
        with caplog.at_level(logging.INFO, logger="attune.retention"):
            reports = [w.run_due(due) for w in workers]
        assert reports[0] is not None
        assert reports[1:] == [None, None]
        assert _retention_entries(db) == 1
        said = [r.getMessage() for r in caplog.records if r.name == "attune.retention"]
        when = f"{due:%Y-%m-%d %H:%M} UTC"
        assert any(
            m.startswith(f"Retention run of {when} started (lease held by ") for m in said
        ), said
        assert any(
            m.startswith(f"Retention run of {when} finished in ")
            and m.endswith(": 1 fleet, 0 episodes and 0 journal entries removed.")
            for m in said
        ), said
        skipped = [m for m in said if m.startswith(f"Retention run of {when} skipped: ")]
        assert len(skipped) == 2, said
        assert all("it already ran: " in m for m in skipped), said

    def test_the_set_time_is_skipped_while_another_run_holds_the_lease(
        self,
        app: FastAPI,
        db: Database,
        make_key: Any,
        caplog: pytest.LogCaptureFixture,
    ) -> None:
        _fleet_with_a_window(app, make_key, people=1)
        now = dt.datetime.now(dt.UTC)
        cron = leases.take(db, LEASE, now=now, holder="cron-host:4242:cccccc")
        worker = DailyRetention(db, app.state.ctx, DailyTime(dt.time(3, 30)))
        with caplog.at_level(logging.INFO, logger="attune.retention"):
            assert worker.run_due(now) is None
        assert _retention_entries(db) == 0
        said = [r.getMessage() for r in caplog.records if r.name == "attune.retention"]
        assert any(
            "skipped: another process holds the lease: cron-host:4242:cccccc, since " in m
            for m in said
        ), said
        cron.release(dt.datetime.now(dt.UTC))

    def test_the_lifespan_starts_the_schedule_and_stops_it(
        self, settings: Settings, empty_tables: None, caplog: pytest.LogCaptureFixture
    ) -> None:
        def threads() -> list[threading.Thread]:
            return [t for t in threading.enumerate() if t.name == "attune-retention"]

        assert threads() == []
        plain = create_app(settings)
        with TestClient(plain):
            assert threads() == []  # unset: no schedule
        daily = settings.model_copy(update={"retention_at": DailyTime(dt.time(3, 30))})
        app = create_app(daily)
        with caplog.at_level(logging.INFO, logger="attune.retention"), TestClient(app) as client:
            assert client.get("/livez").status_code == 200
            assert len(threads()) == 1
            assert threads()[0].is_alive()
        assert threads() == []
        said = [r.getMessage() for r in caplog.records if r.name == "attune.retention"]
        assert any(
            m.startswith("Retention runs every day at 03:30 UTC; the next run is at ") for m in said
        ), said
