"""The migration that brings in evaluations as background jobs (``evaluations``), on a database
filled through the previous release's API: every row stays, there is no evaluation yet, an
evaluation of the logs the previous release stored runs to its result (the same as the
evaluation run directly on them), every model rebuilds identically; the downgrade drops the
table and nothing else."""

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
from app.services.evaluation import evaluate_fleet, parse_candidate
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

MIGRATION = "migrations/versions/2026-12-07-0300_evaluations_of_candidate_learners.py"
BEFORE = "6e1a9d3c5b72"
USERS = ("lin", "chen", "ada")
WAIT_S = 120.0


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "app/services/evaluation_jobs.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        n = 0
        for uid in USERS:
            body = {"learner": {"algorithm": "hri"}}
            assert api["robot"].put(f"/v1/users/{uid}", json=body).status_code == 201
            n = release.history(api["robot"], uid, 5, n)
        release.leave_open(api["robot"], "chen")
    return {"keys": secrets}


def _view(api: Any) -> dict[str, Any]:
    return {uid: api.get(f"/v1/users/{uid}/model").json() for uid in USERS}


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_view, rows=table_rows, at=BEFORE
    ) as database:
        yield database


def test_the_upgrade_keeps_everything_and_the_old_logs_can_be_evaluated(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()
    assert set(table_names(url)) - set(tables) >= {"evaluations"}  # and later releases' tables
    assert table_rows(url, tables) == rows_before
    assert scalars(url, "SELECT count(*) FROM evaluations") == [0]
    app = create_app(Settings(database_url=url, seed=0, _env_file=None))  # type: ignore[call-arg]
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}
        ) as staff:
            assert _view(staff) == before
            body = {"request_id": "first", "candidates": [{"algorithm": "dts"}]}
            r = staff.post("/v1/admin/fleets/default/evaluations", json=body)
            assert r.status_code == 202, r.text
            deadline = time.monotonic() + WAIT_S
            while (job := staff.get(r.headers["Location"]).json())["status"] in (
                "queued",
                "running",
            ):
                assert time.monotonic() < deadline
                time.sleep(0.05)
            assert job["status"] == "done", job
            result = job["result"]
            assert result["episodes"] == 5 * len(USERS)
            assert sorted(p["user_id"] for p in result["persons"]) == sorted(USERS)
            direct = evaluate_fleet(
                app.state.db, app.state.ctx, "default", [parse_candidate("dts")]
            )
            assert direct.to_dict() == result
    finally:
        app.state.db.dispose()
    for uid in USERS:
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, summary


def test_the_downgrade_drops_the_table_and_nothing_else(filled: Filled) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url)
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    assert table_rows(url, tables) == rows_before
