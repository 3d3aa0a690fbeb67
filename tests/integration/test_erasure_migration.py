"""The migration that lets an erasure blank its person's audit entries, on a database filled by
the release before it.

The previous release is served as it was, on a fresh database, and filled through its HTTP
API: people with finished episodes and feedback, staff corrections with notes (audit entries
that hold what the correction said), a person deleted the old way (an entry with their episode
count) and an episode left open. This code then upgrades the database: every row stays as it
was, every model rebuilds identically, SQLite's users table counts with ``AUTOINCREMENT``, and
erasing a person now leaves nothing of them while their neighbours' entries stay whole. The
downgrade gives back the strict triggers and the previous table.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text
from sqlalchemy.exc import DBAPIError

from app.db import migrate
from app.main import create_app
from app.settings import Settings
from tests.support import release
from tests.support.commands import rebuild
from tests.support.erasure import Subject, remains
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
from tests.support.rows import user_pk

pytestmark = [pytest.mark.slow]

MIGRATION = "migrations/versions/2026-12-02-1700_erasure_redacts_the_audit_log.py"
BEFORE = "8c4f1a7e2b93"
AFTER = "3e9d41c7a5b2"
USERS = ("lin", "chen", "room-12")
GONE = "wu"  # deleted by the previous release, made last (the highest number)
NOTE = "Lin: no radio before breakfast, her son asked"
EPISODES = 4


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    return release_code(
        previous_release(MIGRATION, "tests/support/erasure.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    keys = {"robot": ("robot", None), "staff": ("staff", None), "admin": ("admin", None)}
    with release.clients(old, keys) as (secrets, api):
        robot, staff, admin = api["robot"], api["staff"], api["admin"]
        n = 0
        for uid in (*USERS, GONE):
            assert robot.put(f"/v1/users/{uid}", json={}).status_code == 201
            n = release.history(robot, uid, EPISODES, n)
        for uid, note in (("lin", NOTE), ("chen", None)):
            body: dict[str, Any] = {
                "correction_id": f"{uid}-quiet",
                "time_slot": "morning",
                "situation": "arriving",
                "kind": "quiet",
            }
            if note is not None:
                body["note"] = note
            r = staff.post(f"/v1/users/{uid}/corrections", json=body)
            assert r.status_code == 201, r.text
        assert admin.delete(f"/v1/users/{GONE}").status_code == 204
        release.leave_open(robot, "room-12")
    return {"keys": secrets}


def _view(api: Any) -> dict[str, Any]:
    return {
        uid: {
            "user": api.get(f"/v1/users/{uid}").json(),
            "model": release.comparable_model(api.get(f"/v1/users/{uid}/model").json()),
            "corrections": api.get(f"/v1/users/{uid}/corrections").json(),
        }
        for uid in USERS
    }


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    with release.filled(
        request.param, old_code, tmp_path, fill=_fill, view=_view, rows=table_rows, at=BEFORE
    ) as database:
        yield database


def _blank(url: str, target: str) -> int:
    """Blank the audit entries about ``target`` straight in the database: their count."""
    engine = create_engine(url)
    try:
        with engine.begin() as conn:
            done = conn.execute(
                text("UPDATE audit_log SET detail = :d WHERE target = :t"),
                {"d": '{"erased": true}', "t": target},
            )
            return int(done.rowcount)
    finally:
        engine.dispose()


def test_the_upgrade_keeps_everything_and_erasure_then_leaves_nothing(filled: Filled) -> None:
    url, names, before, tables, rows_before = filled
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()  # this code runs on the newest schema
    assert set(tables) <= set(table_names(url))
    assert table_rows(url, tables) == rows_before
    if url.startswith("sqlite"):
        [ddl] = scalars(url, "SELECT sql FROM sqlite_master WHERE name = 'users'")
        assert "AUTOINCREMENT" in ddl
    # The person the previous release deleted: their entries may be blanked now.
    assert _blank(url, GONE) == 1

    settings = Settings(database_url=url, seed=0, _env_file=None)  # type: ignore[call-arg]
    app = create_app(settings)
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['staff']}"}
        ) as staff:
            assert staff.get("/readyz").status_code == 200
            assert _view(staff) == before
            with app.state.db.transaction() as session:
                lin_pk = user_pk(session, "lin")
            assert staff.delete("/v1/users/lin").status_code == 204
            items = staff.get("/v1/admin/audit", params={"limit": 500}).json()["items"]
            assert staff.put("/v1/users/newcomer", json={}).status_code == 201
            with app.state.db.transaction() as session:
                assert user_pk(session, "newcomer") > lin_pk
    finally:
        app.state.db.dispose()
    by_target = {(e["action"], e["target"]): e["detail"] for e in items}
    assert by_target[("user.delete", "lin")] == {"erased": True}
    assert by_target[("correction.add", "lin")] == {"erased": True}
    assert by_target[("correction.add", "chen")]["correction_id"] == "chen-quiet"
    engine = create_engine(url)
    try:
        assert remains(engine, Subject(pk=lin_pk, user_id="lin", markers=(NOTE,))) == []
    finally:
        engine.dispose()
    for uid in ("chen", "room-12"):
        summary = rebuild(url, uid).summary
        assert summary["identical"] is True, (uid, summary)


def test_the_downgrade_gives_back_the_strict_log(filled: Filled) -> None:
    url, _, _, tables, rows_before = filled
    migrate.upgrade(url, AFTER)  # this revision's own downgrade
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert revision(url) == BEFORE
    assert table_names(url) == tables
    assert table_rows(url, tables) == rows_before
    if url.startswith("sqlite"):
        [ddl] = scalars(url, "SELECT sql FROM sqlite_master WHERE name = 'users'")
        assert "AUTOINCREMENT" not in ddl
    with pytest.raises(DBAPIError, match="append only"):
        _blank(url, GONE)
    migrate.upgrade(url)
    assert revision(url) == migrate.head_revision()  # this code runs on the newest schema
    assert table_rows(url, tables) == rows_before
