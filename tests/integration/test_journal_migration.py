"""The migration that types the model's journal (``samples`` becomes ``journal``), on a
database filled through the previous release's API with every kind of entry it wrote
(transitions, feedback, staff corrections made and lifted, a move to a new mission version;
and models that were reset and imported): every row is carried over field for field, nothing
else changes, every model rebuilds identically and the service goes on; the downgrade gives
back ``samples`` exactly as it was."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient

from app.db import migrate
from app.db.repositories import journal
from app.learning import office_mission
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
    table_names,
    table_rows,
)
from tests.support.rows import user_pk

pytestmark = [pytest.mark.slow]

MIGRATION = "migrations/versions/2026-12-04-2300_typed_model_journal.py"
BEFORE = "9c4e7a2b6d15"
USERS = ("lin", "chen", "ana")


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "app/services/person_model.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _correction(cid: str, kind: str = "tea") -> dict[str, Any]:
    """A staff correction: the person prefers tea (``kind`` "tea"), or quiet ("quiet")."""
    body: dict[str, Any] = {
        "correction_id": cid,
        "time_slot": "afternoon",
        "situation": "stretching",
        "kind": "quiet" if kind == "quiet" else "prefers",
    }
    if kind == "tea":
        body.update(service="ProvideDrink", detail="tea")
    return body


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        robot, staff = api["robot"], api["staff"]
        n = 0
        for uid in USERS:
            assert robot.put(f"/v1/users/{uid}", json={}).status_code == 201
            n = release.history(robot, uid, 4, n)
        # lin: a correction in force and one lifted
        for cid in ("tea", "quiet"):
            r = staff.post("/v1/users/lin/corrections", json=_correction(cid, kind=cid))
            assert r.status_code == 201, r.text
        assert staff.delete("/v1/users/lin/corrections/quiet").status_code in (200, 204)
        n = release.history(robot, "lin", 3, n)
        # chen: a reset that keeps a correction, then more episodes
        r = staff.post("/v1/users/chen/corrections", json=_correction("tea"))
        assert r.status_code == 201, r.text
        assert staff.delete("/v1/users/chen/model").status_code == 204
        n = release.history(robot, "chen", 3, n)
        # ana: her model imported from lin's export
        doc = staff.get("/v1/users/lin/model/export").json()
        assert staff.put("/v1/users/ana/model", json=doc).status_code == 200
        n = release.history(robot, "ana", 2, n)
        # everyone moves to a new version of the fleet's mission, and goes on
        mission = copy.deepcopy(office_mission().to_dict())
        mission["services"][0]["details"].append("cocoa")
        r = staff.put(
            "/v1/admin/fleets/default/mission", json={"change_id": "cocoa", "mission": mission}
        )
        assert r.status_code == 200, r.text
        for uid in USERS:
            n = release.history(robot, uid, 2, n)
        release.leave_open(robot, "chen")
    return {"keys": secrets}


def _view(api: Any) -> dict[str, Any]:
    return {
        uid: [
            release.later_fields_out(what, api.get(f"/v1/users/{uid}/{what}").json())
            for what in ("model", "profile", "corrections", "stats")
        ]
        for uid in USERS
    }


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_view, rows=table_rows, at=BEFORE
    ) as database:
        yield database


def test_the_upgrade_types_every_entry_and_changes_nothing_else(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    assert "samples" in tables
    kinds = {dict(r)["kind"] for r in rows_before["samples"]}
    assert kinds == {"transition", "feedback", "correction", "lift", "mission"}
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()
    kept = [t for t in tables if t != "samples"]
    assert set(table_names(url, as_stored=True)) >= {*kept, "journal"}  # and later ones
    assert "samples" not in table_names(url, as_stored=True)
    assert table_rows(url, kept) == {t: rows_before[t] for t in kept}
    assert table_rows(url, ["samples"]) == {"samples": rows_before["samples"]}, (
        "an entry lost or changed a field"
    )
    app = create_app(Settings(database_url=url, seed=0, _env_file=None))  # type: ignore[call-arg]
    try:
        with (
            TestClient(app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}) as staff,
            TestClient(app, headers={"Authorization": f"Bearer {names['keys']['robot']}"}) as robot,
        ):
            assert _view(staff) == before
            with app.state.db.transaction(write=False) as session:
                lin = journal.entries_since(session, user_pk(session, "lin"), 0)
                corrections = [e for e in lin if isinstance(e, journal.Correction)]
                assert [c.since for c in corrections] == [4, 4]
                assert all(isinstance(c.correction_pk, int) for c in corrections)
                assert any(isinstance(e, journal.MissionMove) for e in lin)
            # The service goes on, and a reset is now journalled as one.
            release.history(robot, "lin", 2, 100)
            assert staff.delete("/v1/users/lin/model").status_code == 204
            with app.state.db.transaction(write=False) as session:
                last = journal.entries_since(session, user_pk(session, "lin"), 0)[-1]
            assert isinstance(last, journal.Reset)
            release.history(robot, "lin", 2, 200)
    finally:
        app.state.db.dispose()
    for uid in USERS:
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, (uid, summary)


def test_the_downgrade_gives_back_the_samples_as_they_were(filled: Filled) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url)
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url, as_stored=True) == tables
    assert table_rows(url, tables) == rows_before
    # And up again: the same journal.
    migrate.upgrade(url)
    assert table_rows(url, ["samples"]) == {"samples": rows_before["samples"]}
