"""The migration to staff corrections and local times, on a database filled by the release
before it.

The previous release (the commit before the change's first files) is served as it was, on a
fresh database, and filled through its HTTP API: users with finished episodes, explicit
feedback, and an episode left open. Then this code upgrades the database: every row and every
figure the API shows stay as they were, the existing episodes keep ``utc_offset`` NULL, the
service starts, the profile of an existing user shows its episodes, corrections can be made,
and every model rebuilds identically (``attune models rebuild``). The downgrade gives back the
previous schema while no correction exists, and refuses, saying why, once one does.
"""

from __future__ import annotations

import datetime as dt
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

MIGRATION = "migrations/versions/2026-11-30-1800_staff_corrections_and_local_times.py"
BEFORE = "3e8a6d0c4f17"  # the revision the previous release ends at
AFTER = "5b7d2e9a1c08"
NEW_COLUMNS = (
    "utc_offset",  # this revision's, and the later ones'
    "fleet_prior",
    "base_origin",
    "base_contributors",
)
USERS = ("lin", "chen", "room-12")
OPEN_USER = "room-12"
SLOT, SITUATION = "afternoon", "stretching"  # run_episode(): n % 4 == 2 is 15:10, n % 3 == 2


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    # The change began with the learning core's guidance rules, in the migration's commit.
    return release_code(
        previous_release(MIGRATION, "app/learning/guidance.py", "app/learning/beliefs.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    """What a deployment holds, made through the previous release's API."""
    with release.clients(old, {"robot": ("robot", None), "admin": ("admin", None)}) as (keys, api):
        n = 0
        for uid in USERS:
            n = release.history(api["robot"], uid, 6, n)
        opened = release.leave_open(api["robot"], OPEN_USER, SITUATION)
    return {"keys": keys, "open": opened, "episodes": n + 1}


def _rows(url: str, tables: list[str]) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of the tables the previous release had, without the new columns."""
    return table_rows(url, tables, leave_out=NEW_COLUMNS)


def _api_view(api: Any) -> dict[str, Any]:
    """Every figure the API shows of every user (without the fields later releases add: where a
    model started, whether a user takes part in the fleet's prior)."""
    view: dict[str, Any] = {}
    for uid in USERS:
        episodes = api.get(f"/v1/users/{uid}/episodes", params={"limit": 500}).json()
        traces = [api.get(f"/v1/episodes/{ep['episode_id']}").json() for ep in episodes["items"]]
        view[uid] = {
            "user": without(api.get(f"/v1/users/{uid}").json(), "fleet_prior"),
            "model": comparable_model(
                without(api.get(f"/v1/users/{uid}/model").json(), "started_from")
            ),
            "stats": release.stats(api, uid),
            "episodes": episodes["items"],
            "traces": traces,
        }
    return view


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    """A database at the previous release's head, filled through its API."""
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_api_view, rows=_rows, at=BEFORE
    ) as database:
        assert "corrections" not in database.tables
        yield database


def _cell(profile: dict[str, Any]) -> dict[str, Any]:
    cells: list[dict[str, Any]] = [
        c for c in profile["contexts"] if (c["time_slot"], c["situation"]) == (SLOT, SITUATION)
    ]
    [cell] = cells
    return cell


def test_the_upgrade_keeps_everything_and_corrections_can_be_made(
    filled: Filled,
) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()  # this code runs on the newest schema
    assert _rows(url, tables) == rows_before
    assert scalars(url, "SELECT COUNT(*) FROM episodes") == [names["episodes"]]
    assert scalars(url, "SELECT DISTINCT utc_offset FROM episodes") == [None]
    assert scalars(url, "SELECT COUNT(*) FROM corrections") == [0]

    settings = Settings(database_url=url, seed=0, _env_file=None)  # type: ignore[call-arg]
    app = create_app(settings)
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['admin']}"}
        ) as admin:
            assert admin.get("/readyz").status_code == 200
            assert _api_view(admin) == before

            # The profile of a user whose history predates local times.
            r = admin.get(f"/v1/users/{OPEN_USER}/profile")
            assert r.status_code == 200, r.text
            profile = r.json()
            listed = admin.get(f"/v1/users/{OPEN_USER}/episodes", params={"limit": 500}).json()[
                "items"
            ]
            assert profile["episodes"] == len(listed) == 7
            assert profile["open_episodes"] == 1
            assert profile["utc_offset"] is None  # shown in UTC
            assert sum(c["episodes"] for c in profile["contexts"]) == 7
            assert sum(c["open_episodes"] for c in profile["contexts"]) == 1
            assert _cell(profile)["episodes"] >= 1
            assert profile["corrections"] == []
            for cell in profile["contexts"]:
                seen = cell["evidence"]["last_seen"]
                if seen is not None:
                    assert dt.datetime.fromisoformat(seen).utcoffset() == dt.timedelta(0)

            # Corrections are made, listed and shown in the profile.
            made = admin.post(
                f"/v1/users/{OPEN_USER}/corrections",
                json={
                    "correction_id": "tea-afternoons",
                    "time_slot": SLOT,
                    "situation": SITUATION,
                    "kind": "prefers",
                    "service": "ProvideDrink",
                    "detail": "tea",
                    "note": "Made after the upgrade.",
                },
            )
            assert made.status_code == 201, made.text
            assert made.json()["status"] == "in_force"
            quiet = admin.post(
                "/v1/users/lin/corrections",
                json={
                    "correction_id": "hush",
                    "time_slot": "morning",
                    "situation": "working",
                    "kind": "quiet",
                },
            )
            assert quiet.status_code == 201, quiet.text
            assert [
                c["correction_id"]
                for c in admin.get(f"/v1/users/{OPEN_USER}/corrections").json()["items"]
            ] == ["tea-afternoons"]
            profile = admin.get(f"/v1/users/{OPEN_USER}/profile").json()
            assert [c["correction_id"] for c in profile["corrections"]] == ["tea-afternoons"]
            assert _cell(profile)["source"] == "staff"

            # The episode left open before the upgrade finishes; a new one carries its offset.
            robot = TestClient(app, headers={"Authorization": f"Bearer {names['keys']['robot']}"})
            opened = names["open"]
            decision = opened["decision"]
            while decision is not None:
                body: dict[str, Any] = {"decision_id": decision["decision_id"]}
                kind = decision["action"]["kind"]
                if kind in ("initiate", "perform"):
                    body["response"] = "accepted"
                elif kind == "query_type":
                    body.update(response="answered", service="ProvideDrink")
                elif kind == "query_detail":
                    body.update(response="answered", detail="tea")
                else:
                    body["response"] = "none"
                r = robot.post(f"/v1/episodes/{opened['episode_id']}/outcomes", json=body)
                assert r.status_code == 200, r.text
                decision = r.json()["decision"]
            run_episode(robot, OPEN_USER, "after-upgrade", 2)
            profile = admin.get(f"/v1/users/{OPEN_USER}/profile").json()
            assert profile["episodes"] == 8
            assert profile["open_episodes"] == 0
            assert profile["utc_offset"] == 8 * 60
    finally:
        app.state.db.dispose()

    assert scalars(url, "SELECT COUNT(*) FROM episodes WHERE utc_offset IS NULL") == [
        names["episodes"]
    ]
    for uid in USERS:
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, (uid, summary)

    # Down again: refused while corrections exist, saying so; nothing changed.
    command.downgrade(migrate.alembic_config(url), AFTER)
    with pytest.raises(RuntimeError, match=r"2 staff corrections are stored"):
        command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == AFTER
    assert scalars(url, "SELECT COUNT(*) FROM corrections") == [2]


def test_the_downgrade_gives_back_the_previous_schema(
    filled: Filled,
) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url)
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    assert _rows(url, tables) == rows_before
    engine = create_engine(url)
    try:
        assert "utc_offset" not in {c["name"] for c in inspect(engine).get_columns("episodes")}
    finally:
        engine.dispose()
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()
    assert _rows(url, tables) == rows_before
