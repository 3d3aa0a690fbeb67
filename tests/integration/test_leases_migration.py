"""The migration that adds the leases (``leases``), on a database filled by the release before it
(a fleet with a retention window, people with history, an episode left open): every row stays,
``attune retention run`` then takes the lease, runs and lets it go, a run at a set time of the
service runs once, and the downgrade drops the table, nothing else."""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from app import cli
from app.daily import DailyTime
from app.db import migrate
from app.db.session import Database
from app.main import create_app
from app.services import leases
from app.services.retention_runs import LEASE, DailyRetention
from app.settings import Settings
from tests.support import release
from tests.support.commands import rebuild
from tests.support.release import (
    Filled,
    OldService,
    previous_release,
    release_code,
    revision,
    scalars,
    table_names,
    table_rows,
)

pytestmark = [pytest.mark.slow]

MIGRATION = "migrations/versions/2026-12-03-0900_leases_for_runs_one_at_a_time.py"
BEFORE = "5b8e2f4a9c17"
USERS = ("lin", "chen")


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "app/services/leases.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        n = 0
        for uid in USERS:
            assert api["robot"].put(f"/v1/users/{uid}", json={}).status_code == 201
            n = release.history(api["robot"], uid, 3, n)
        r = api["staff"].put("/v1/admin/fleets/default/history", json={"history_days": 1})
        assert r.status_code == 200, r.text
        release.leave_open(api["robot"], "chen")
    return {"keys": secrets}


def _view(api: Any) -> dict[str, Any]:
    return {
        uid: [
            release.later_fields_out(what, api.get(f"/v1/users/{uid}/{what}").json())
            for what in ("model", "profile")
        ]
        for uid in USERS
    }


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_view, rows=table_rows, at=BEFORE
    ) as database:
        yield database


def _retention_run(url: str) -> tuple[int, str, str]:
    """``attune retention run --json`` on the database at ``url``: exit code, stdout, stderr."""
    done = CliRunner().invoke(
        cli.app,
        ["retention", "run", "--json"],
        env={"ATTUNE_DATABASE_URL": url, "ATTUNE_SEED": "0"},
    )
    return done.exit_code, done.stdout, done.stderr


def test_the_upgrade_keeps_everything_and_runs_take_the_lease(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()
    assert "leases" in set(table_names(url)) - set(tables)
    assert table_rows(url, tables) == rows_before
    assert scalars(url, "SELECT COUNT(*) FROM leases") == [0]
    settings = Settings(database_url=url, seed=0, _env_file=None)  # type: ignore[call-arg]
    db = Database(settings)
    try:
        # The command, while the service holds the lease: nothing done, exit 3.
        service = leases.take(db, LEASE, now=dt.datetime.now(dt.UTC), holder="web-1:1:aaaaaa")
        code, out, err = _retention_run(url)
        assert (code, out) == (3, ""), err
        assert "Another retention run holds the lease (web-1:1:aaaaaa, since " in err
        service.release(dt.datetime.now(dt.UTC))
        # Then, with the window of a day and every episode received today: a run that keeps
        # everything, holds the lease and lets it go.
        code, out, err = _retention_run(url)
        assert code == 0, err
        report = json.loads(out)
        assert [(f["fleet"], f["days"], f["people"]) for f in report["fleets"]] == [
            ("default", 1, 2)
        ]
        assert report["episodes_removed"] == 0
        # The service's own run at its set time: once, however many workers wake for it.
        app = create_app(settings)
        try:
            workers = [
                DailyRetention(app.state.db, app.state.ctx, DailyTime(dt.time(3, 30)))
                for _ in range(2)
            ]
            due = dt.datetime.now(dt.UTC)
            reports = [w.run_due(due) for w in workers]
            assert reports[0] is not None
            assert reports[1] is None
            assert [f.fleet for f in reports[0].fleets] == ["default"]
            with TestClient(
                app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}
            ) as staff:
                assert _view(staff) == before
        finally:
            app.state.db.dispose()
        assert scalars(url, "SELECT COUNT(*) FROM leases") == [1]
        assert scalars(url, "SELECT holder FROM leases") != ["web-1:1:aaaaaa"]
    finally:
        db.dispose()
    for uid in USERS:
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, summary


def test_the_downgrade_drops_the_leases_and_nothing_else(filled: Filled) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url)
    db = Database(Settings(database_url=url, _env_file=None))  # type: ignore[call-arg]
    try:
        leases.take(db, LEASE, now=dt.datetime.now(dt.UTC)).release(dt.datetime.now(dt.UTC))
    finally:
        db.dispose()
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    assert table_rows(url, tables) == rows_before
