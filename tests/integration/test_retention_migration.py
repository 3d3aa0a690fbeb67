"""The migration that brings retention in (``fleet_settings.history_days``, ``history_folds``),
on a database filled by the release before it: every row stays, every fleet keeps everything
until its staff set a window, a run then folds and removes the old history with the models
rebuilding identical, and the downgrade drops the column and the table, nothing else."""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient

from app.db import migrate
from app.main import create_app
from app.services import retention
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

MIGRATION = "migrations/versions/2026-12-02-2000_retention_windows_and_history_folds.py"
BEFORE = "7a2c5e8d1f36"
USERS = ("lin", "chen")


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "app/services/retention.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        n = 0
        for uid in USERS:
            assert api["robot"].put(f"/v1/users/{uid}", json={}).status_code == 201
            n = release.history(api["robot"], uid, 4, n)
        assert (
            api["staff"].put("/v1/admin/fleets/default/prior", json={"enabled": False}).status_code
            == 200
        )
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


def test_the_upgrade_keeps_everything_and_a_run_then_folds_exactly(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()
    assert "history_folds" in set(table_names(url)) - set(tables)
    after = table_rows(url, tables)
    after["fleet_settings"] = [
        tuple(c for c in row if c[0] != "history_days") for row in after["fleet_settings"]
    ]
    assert after == rows_before
    assert scalars(url, "SELECT history_days FROM fleet_settings") == [None]
    app = create_app(Settings(database_url=url, seed=0, _env_file=None))  # type: ignore[call-arg]
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}
        ) as staff:
            assert _view(staff) == before
            r = staff.put("/v1/admin/fleets/default/history", json={"history_days": 1})
            assert r.status_code == 200, r.text
            later = dt.datetime.now(dt.UTC) + dt.timedelta(days=2)
            report = retention.run(app.state.db, app.state.ctx, now=later)
            assert report.episodes_removed == 8  # every closed one; chen's open one stays
            assert _view(staff) == before
    finally:
        app.state.db.dispose()
    for uid in USERS:
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, summary


def test_the_downgrade_drops_the_window_and_the_folds_and_nothing_else(filled: Filled) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url)
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    assert table_rows(url, tables) == rows_before
