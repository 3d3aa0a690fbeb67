"""The migration that brings in rollouts (``rollouts``, ``rollout_arms``), on a database filled
through the previous release's API (people with histories, and a finished evaluation of the
fleet): every row stays, nobody has an arm, a rollout started after the upgrade gives arms and
moves people keeping what was learned, every model rebuilds identically; the downgrade drops
the two tables and nothing else."""

from __future__ import annotations

import time
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

MIGRATION = "migrations/versions/2026-12-07-0400_shadows_rollouts_and_stored_arms.py"
BEFORE = "8b4f2e6a1c90"
USERS = tuple(f"p{i}" for i in range(8))
WAIT_S = 120.0


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "app/services/rollouts.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        n = 0
        for uid in USERS:
            body = {"learner": {"algorithm": "hri"}}
            assert api["robot"].put(f"/v1/users/{uid}", json=body).status_code == 201
            n = release.history(api["robot"], uid, 3, n)
        release.leave_open(api["robot"], "p1")
        job: dict[str, Any] = {"request_id": "before", "candidates": [{"algorithm": "dts"}]}
        r = api["staff"].post("/v1/admin/fleets/default/evaluations", json=job)
        assert r.status_code == 202, r.text
        deadline = time.monotonic() + WAIT_S
        while api["staff"].get(r.headers["Location"]).json()["status"] != "done":
            assert time.monotonic() < deadline
            time.sleep(0.05)
    return {"keys": secrets}


def _view(api: Any) -> dict[str, Any]:
    return {uid: api.get(f"/v1/users/{uid}/model").json() for uid in USERS}


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_view, rows=table_rows, at=BEFORE
    ) as database:
        yield database


def test_the_upgrade_keeps_everything_and_a_rollout_then_runs(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()
    assert set(table_names(url)) - set(tables) == {
        "rollouts",
        "rollout_arms",
        "shadows",
        "shadow_decisions",
    }
    assert table_rows(url, tables) == rows_before
    assert scalars(url, "SELECT count(*) FROM rollout_arms") == [0]
    app = create_app(Settings(database_url=url, seed=0, _env_file=None))  # type: ignore[call-arg]
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}
        ) as staff:
            assert _view(staff) == before
            assert staff.get(f"/v1/users/{USERS[0]}/profile").json()["rollout"] is None
            body = {"candidate": {"algorithm": "hri", "params": {"tau": 0.005}}, "share": 0.5}
            r = staff.put("/v1/admin/fleets/default/rollout", json=body)
            assert r.status_code == 201, r.text
            app.state.rollout_mover.join(60)  # the moves, done after the answer
            people = r.json()["people"]
            assert people["candidate"] + people["control"] == len(USERS)
            for uid in USERS:
                arm = staff.get(f"/v1/users/{uid}/profile").json()["rollout"]["arm"]
                tau = staff.get(f"/v1/users/{uid}").json()["learner"]["params"]["tau"]
                assert (tau == 0.005) == (arm == "candidate")
                # What was learned stays: the model still holds every episode it was taught.
                after = staff.get(f"/v1/users/{uid}/model").json()
                assert after["episodes"] == before[uid]["episodes"]
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
