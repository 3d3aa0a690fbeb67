"""The migration to fleets' priors for newcomers, on a database filled by the release before it.

The previous release (the commit before the change's first files) is served as it was, on a
fresh database, and filled through its HTTP API: users with finished episodes and feedback, one
with an imported model, and an episode left open. Then this code upgrades the database: every
row and every figure the API showed stay as they were (the new fields aside), existing users
take part in their fleet's prior, the imported model says it was imported and the others that
they started fresh, every model rebuilds identically, and a newcomer starts from the prior the
upgraded users make. The downgrade gives back the previous schema while no model grew from a
prior, and refuses, saying why, once one does.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, inspect

from app.db import migrate
from app.main import create_app
from app.settings import Settings
from tests.support import release
from tests.support.commands import rebuild
from tests.support.release import (
    Filled,
    OldService,
    comparable_model,
    previous_release,
    release_code,
    revision,
    run_episode,
    scalars,
    table_names,
    table_rows,
    without,
)

pytestmark = [pytest.mark.slow]

MIGRATION = "migrations/versions/2026-11-30-2100_fleet_priors_for_newcomers.py"
BEFORE = "5b7d2e9a1c08"  # the revision the previous release ends at
AFTER = "8c4f1a7e2b93"
NEW_COLUMNS = ("fleet_prior", "base_origin", "base_contributors")
USERS = ("lin", "chen", "wu", "room-12")
IMPORTED = "wu"
OPEN_USER = "room-12"
EPISODES = 5  # per user


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    # The change began with the learning core's prior, before the migration's commit.
    return release_code(
        previous_release(MIGRATION, "app/learning/prior.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    """What a deployment holds, made through the previous release's API."""
    with release.clients(old, {"robot": ("robot", None), "admin": ("admin", None)}) as (keys, api):
        robot, admin = api["robot"], api["admin"]
        n = 0
        for uid in USERS:
            # DTS: the previous release's default, HRI, is a learner whose newcomers start fresh
            made = robot.put(f"/v1/users/{uid}", json={"learner": {"algorithm": "dts"}})
            assert made.status_code == 201, made.text
            n = release.history(robot, uid, EPISODES, n)
        exported = admin.get("/v1/users/lin/model/export")
        assert exported.status_code == 200, exported.text
        imported = admin.put(f"/v1/users/{IMPORTED}/model", json=exported.json())
        assert imported.status_code == 200, imported.text
        release.leave_open(robot, OPEN_USER)
    return {"keys": keys, "episodes": n + 1}


def _rows(url: str, tables: list[str]) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of the tables the previous release had, without the new columns."""
    return table_rows(url, tables, leave_out=NEW_COLUMNS)


def _api_view(api: Any) -> dict[str, Any]:
    """Every figure the API shows of every user (without the fields this change adds)."""
    view: dict[str, Any] = {}
    for uid in USERS:
        episodes = api.get(f"/v1/users/{uid}/episodes", params={"limit": 500}).json()
        view[uid] = {
            "user": without(api.get(f"/v1/users/{uid}").json(), "fleet_prior"),
            "model": comparable_model(
                without(api.get(f"/v1/users/{uid}/model").json(), "started_from")
            ),
            "stats": release.stats(api, uid),
            "episodes": episodes["items"],
        }
    return view


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    """A database at the previous release's head, filled through its API."""
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_api_view, rows=_rows, at=BEFORE
    ) as database:
        yield database


def test_the_upgrade_keeps_everything_and_newcomers_start_from_the_prior(
    filled: Filled,
) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()  # this code runs on the newest schema
    assert table_rows(url, tables, leave_out=NEW_COLUMNS) == rows_before
    assert scalars(url, "SELECT DISTINCT fleet_prior FROM users") == [True]
    assert scalars(url, "SELECT COUNT(*) FROM fleet_settings") == [0]

    settings = Settings(
        database_url=url,
        seed=0,
        prior_min_contributors=3,  # type: ignore[call-arg]
        prior_min_episodes=EPISODES,
        _env_file=None,
    )
    app = create_app(settings)
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['admin']}"}
        ) as admin:
            assert admin.get("/readyz").status_code == 200
            assert _api_view(admin) == before
            for uid in USERS:
                assert admin.get(f"/v1/users/{uid}").json()["fleet_prior"] is True
                started = admin.get(f"/v1/users/{uid}/model").json()["started_from"]
                kind = "imported" if uid == IMPORTED else "fresh"
                assert started == {"kind": kind, "contributors": None}, uid
            view = admin.get("/v1/admin/fleets/default/prior").json()
            assert view["enabled"] is True
            assert view["contributors"]["dts"] == len(USERS)
            made = admin.put("/v1/users/newcomer", json={"learner": {"algorithm": "dts"}})
            assert made.status_code == 201, made.text
            assert admin.get("/v1/users/newcomer/model").json()["started_from"] == {
                "kind": "fleet_prior",
                "contributors": len(USERS),
            }
            run_episode(admin, "newcomer", "newcomer-1", 1)
    finally:
        app.state.db.dispose()

    for uid in (*USERS, "newcomer"):
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, (uid, summary)

    # Down again: refused while a model grew from a prior, saying so; nothing changed.
    with pytest.raises(RuntimeError, match=r"1 models started from their fleet's prior"):
        command.downgrade(migrate.alembic_config(url), BEFORE)
    # PostgreSQL runs the whole downgrade in one transaction; SQLite's driver commits each DDL
    # statement, so the later revisions' downgrades stay done and this one's refusal stops it.
    stopped_at = migrate.head_revision() if url.startswith("postgresql") else AFTER
    assert revision(url) == stopped_at


def test_the_downgrade_gives_back_the_previous_schema(
    filled: Filled,
) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url, AFTER)  # this revision's own downgrade
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    engine = create_engine(url)
    try:
        assert "fleet_settings" not in inspect(engine).get_table_names()
        assert "fleet_prior" not in {c["name"] for c in inspect(engine).get_columns("users")}
        assert not {"base_origin", "base_contributors"} & {
            c["name"] for c in inspect(engine).get_columns("learner_models")
        }
    finally:
        engine.dispose()
    assert table_rows(url, tables) == rows_before
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()  # this code runs on the newest schema
    assert table_rows(url, tables, leave_out=NEW_COLUMNS) == rows_before
