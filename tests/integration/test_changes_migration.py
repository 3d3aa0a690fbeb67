"""The migration that brings in changes told to staff (``context_beliefs``,
``change_events``), on a database filled through the previous release's API: every row stays,
nobody has a change or a walk yet, each context's walk begins with the next episode that ends
there (a wish that then changes is told), every model rebuilds identically; the downgrade drops
the two tables and nothing else."""

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
from tests.support.episodes import play
from tests.support.people import person
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

MIGRATION = "migrations/versions/2026-12-05-0100_changes_told_to_staff.py"
BEFORE = "3c9d4e7f2a18"
USERS = ("lin", "chen")
TEA, COFFEE = ("ProvideDrink", "tea"), ("ProvideDrink", "coffee")


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "app/services/changes.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        n = 0
        for uid in USERS:
            # HRI: a learner without a change mechanism of its own, whose changes the
            # profile's walk tells (a learner with one tells its own: tests/api/test_changes.py)
            body = {"learner": {"algorithm": "hri"}}
            assert api["robot"].put(f"/v1/users/{uid}", json=body).status_code == 201
            n = release.history(api["robot"], uid, 4, n)
        # Lin's wish changes under the previous release: nobody was told then.
        for i, need in enumerate([TEA] * 3 + [COFFEE] * 3):
            play(api["robot"], "lin", f"lin-w{i}", person(need=need), situation="stretching")
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


def test_the_upgrade_keeps_everything_and_changes_are_told_from_then_on(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()
    assert set(table_names(url)) - set(tables) >= {"change_events", "context_beliefs"}
    assert table_rows(url, tables) == rows_before
    assert scalars(url, "SELECT count(*) FROM change_events") == [0]
    app = create_app(Settings(database_url=url, seed=0, _env_file=None))  # type: ignore[call-arg]
    try:
        with (
            TestClient(app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}) as staff,
            TestClient(app, headers={"Authorization": f"Bearer {names['keys']['robot']}"}) as robot,
        ):
            assert _view(staff) == before
            assert staff.get("/v1/users/lin/changes").json()["items"] == []
            # Coffee holds; then tea again: the walk that began after the upgrade tells it.
            for i, need in enumerate([COFFEE] * 3 + [TEA] * 3):
                play(robot, "lin", f"lin-x{i}", person(need=need), situation="stretching")
            (change,) = staff.get("/v1/users/lin/changes").json()["items"]
            assert change["before"] == {"service": "ProvideDrink", "detail": "coffee"}
            assert staff.get("/v1/admin/fleets/default/changes").json()["items"] == [change]
    finally:
        app.state.db.dispose()
    for uid in USERS:
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, summary


def test_the_downgrade_drops_the_two_tables_and_nothing_else(filled: Filled) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url)
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    assert table_rows(url, tables) == rows_before
