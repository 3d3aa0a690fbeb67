"""The migration that adds the record of who looked (``data_views``), on a database filled by
the release before it: every row stays, staff reads are recorded from then on and go with the
person, and the downgrade drops the table and what it recorded, nothing else."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient

from app.db import migrate
from app.main import create_app
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

MIGRATION = "migrations/versions/2026-12-02-1800_who_looked_at_a_person.py"
BEFORE = "3e9d41c7a5b2"
USERS = ("lin", "chen")


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "app/services/views.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        n = 0
        for uid in USERS:
            assert api["robot"].put(f"/v1/users/{uid}", json={}).status_code == 201
            n = release.history(api["robot"], uid, 3, n)
        assert api["staff"].get("/v1/users/lin/profile").status_code == 200  # not recorded then
        release.leave_open(api["robot"], "chen")
    return {"keys": secrets}


def _view(api: Any) -> dict[str, Any]:
    return {uid: api.get(f"/v1/users/{uid}/episodes").json() for uid in USERS}


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_view, rows=table_rows, at=BEFORE
    ) as database:
        yield database


def test_the_upgrade_keeps_everything_and_records_reads_from_then_on(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()  # this code runs on the newest schema
    assert "data_views" in set(table_names(url)) - set(tables)
    assert table_rows(url, tables) == rows_before
    assert scalars(url, "SELECT COUNT(*) FROM data_views") == [0]
    app = create_app(Settings(database_url=url, seed=0, _env_file=None))  # type: ignore[call-arg]
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}
        ) as staff:
            assert _view(staff) == before
            views = staff.get("/v1/users/lin/views").json()["items"]
            assert [(v["what"], v["actor"]["role"]) for v in views] == [("episodes", "staff")]
            assert staff.delete("/v1/users/lin").status_code == 204
    finally:
        app.state.db.dispose()
    assert scalars(url, "SELECT COUNT(*) FROM data_views") == [1]  # chen's
    summary = rebuild(url, "chen").summary
    assert summary["identical"] is True, summary


def test_the_downgrade_drops_the_record_and_nothing_else(filled: Filled) -> None:
    url, names, _, tables, rows_before = filled
    migrate.upgrade(url)
    app = create_app(Settings(database_url=url, seed=0, _env_file=None))  # type: ignore[call-arg]
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}
        ) as staff:
            assert staff.get("/v1/users/chen/model").status_code == 200
    finally:
        app.state.db.dispose()
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    assert table_rows(url, tables) == rows_before
