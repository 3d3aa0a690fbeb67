"""The service's own retention run, live: two instances of ``attune serve`` on one PostgreSQL
(one with two workers), all set to run retention at the same minute (``ATTUNE_RETENTION_AT``).
At that minute each worker wakes; one takes the lease and runs, the others say in their log that
it is held or already ran; the audit log has one run; SIGTERM then stops every worker cleanly.

The test waits for the set minute (up to two minutes) and for the log lines, not for any time
to pass between them."""

from __future__ import annotations

import datetime as dt
import re
import time
from pathlib import Path

import httpx
import pytest

from tests.support.episodes import start
from tests.support.live import LiveService, fresh_database

pytestmark = pytest.mark.live

LEAD = dt.timedelta(seconds=45)  # for both instances to start before the set minute


def _set_minute() -> dt.datetime:
    """The first whole minute at least ``LEAD`` from now (UTC)."""
    at = dt.datetime.now(dt.UTC) + LEAD
    return at.replace(second=0, microsecond=0) + dt.timedelta(minutes=1)


def _lines(services: list[LiveService], pattern: str) -> list[str]:
    found = []
    for service in services:
        text = service.log_path.read_text(errors="replace")
        found += [line for line in text.splitlines() if re.search(pattern, line)]
    return found


def test_one_process_of_the_deployment_runs_the_set_time(tmp_path: Path) -> None:
    minute = _set_minute()
    env = {"ATTUNE_RETENTION_AT": f"{minute:%H:%M}", "ATTUNE_LOG_LEVEL": "info"}
    with fresh_database("postgresql", tmp_path) as url:
        first = LiveService(url, workers=2, log_path=tmp_path / "first.log", env=env)
        second = LiveService(url, workers=1, log_path=tmp_path / "second.log", env=env)
        services = [first, second]
        with first, second:
            staff = first.create_key("staff", "north", "day-shift")
            with httpx.Client(
                base_url=second.url, timeout=30, headers={"Authorization": f"Bearer {staff}"}
            ) as api:
                assert api.put("/v1/users/ada", json={}).status_code == 201
                start(api, "ada", "e1")
                r = api.put("/v1/admin/fleets/north/history", json={"history_days": 30})
                assert r.status_code == 200, r.text
                assert dt.datetime.now(dt.UTC) < minute, "the services started too late"
                when = f"Retention run of {minute:%Y-%m-%d %H:%M} UTC"
                deadline = (
                    time.monotonic() + (minute - dt.datetime.now(dt.UTC)).total_seconds() + 90
                )
                while len(_lines(services, f"{when} (finished|skipped)")) < 3:
                    assert time.monotonic() < deadline, first.log() + second.log()
                    time.sleep(0.5)
                audit = api.get("/v1/admin/audit").json()["items"]
        for service in services:  # stopped by SIGTERM: every worker left cleanly
            assert service.process is not None
            assert service.process.returncode == 0, service.log()
    assert len(_lines(services, "Retention runs every day at ")) == 3  # one per worker
    assert len(_lines(services, f"{when} started \\(lease held by ")) == 1
    assert len(_lines(services, f"{when} finished in .*: 1 fleet, ")) == 1
    skipped = _lines(services, f"{when} skipped: ")
    assert len(skipped) == 2, skipped
    assert all("holds the lease" in s or "already ran" in s for s in skipped), skipped
    assert [e["target"] for e in audit if e["action"] == "fleet.retention"] == ["north"]
    assert not _lines(services, "Traceback|failed")
