"""The migration to missions per fleet, on a database filled by the release before it.

The previous release (the commit before the one that added this migration) is served as it was,
on a fresh database, and filled through its HTTP API: two fleets with users and history,
explicit feedback, a reset, an imported model, a DTS user and an episode left open. Then this
code upgrades the database: every row and every figure the API shows stay as they were, every
row is marked as belonging to its fleet's mission version 1 (the deployment's mission, stored
for every fleet with users), every model rebuilds identically, and the service goes on: the
open episode finishes, and a fleet changes its mission. The upgrade refuses a deployment whose
models were learned for another mission than the one it is told, and the downgrade works while
no fleet has changed its mission (and names those that have).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from app.db import migrate
from app.learning import office_mission
from app.main import create_app
from app.services import audit
from app.services.context import ServiceContext
from app.services.models import rebuild_model
from app.settings import Settings
from tests.support import release
from tests.support.release import (
    Filled,
    OldService,
    comparable_model,
    previous_release,
    release_code,
    run_episode,
    table_rows,
)

pytestmark = [pytest.mark.slow]

MIGRATION = "migrations/versions/2026-11-30-1500_missions_per_fleet.py"
BEFORE = "9c1f4e7a2b65"  # the revision the previous release ends at
TABLES = (
    "users",
    "learner_models",
    "episodes",
    "samples",
    "decisions",
    "feedback",
    "api_keys",
    "audit_log",
)
NEW_COLUMNS = (
    "mission_version",
    "base_mission_version",
    "utc_offset",  # this and later releases
    "fleet_prior",
    "base_origin",
    "base_contributors",
)
USERS = {"north": ["lin", "chen", "room-12"], "south": ["lin", "bo"]}


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    assert migrate.head_revision() != BEFORE
    # The change began with the learning core's remapping, before its migration was committed.
    return release_code(
        previous_release(MIGRATION, "app/learning/remap.py"),
        tmp_path_factory.mktemp("previous-release"),
    )


def _fill(old: OldService) -> dict[str, Any]:
    """What a deployment holds, made through the previous release's API."""
    keys = {
        "north": ("robot", "north"),
        "south": ("robot", "south"),
        "admin": ("admin", "default"),
    }
    with release.clients(old, keys) as (secrets, clients):
        n = 0
        for fleet, ids in USERS.items():
            for uid in ids:
                n = release.history(clients[fleet], uid, 6, n)
        admin = clients["admin"]
        assert admin.delete("/v1/users/chen/model", params={"fleet": "north"}).status_code == 204
        run_episode(clients["north"], "chen", "chen-after", n)
        doc = admin.get("/v1/users/lin/model/export", params={"fleet": "north"})
        assert doc.status_code == 200
        assert (
            admin.put("/v1/users/bo/model", params={"fleet": "south"}, json=doc.json()).status_code
            == 200
        )
        run_episode(clients["south"], "bo", "bo-after-import", 99)
        assert (
            clients["south"]
            .put("/v1/users/dts", json={"learner": {"algorithm": "dts"}})
            .status_code
            == 201
        )
        for i in range(4):
            run_episode(clients["south"], "dts", f"dts-{i}", i)
        opened = release.leave_open(clients["north"], "room-12")
    return {"keys": secrets, "open": opened}


def _rows(url: str) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of the tables the previous release had, without the new columns."""
    return table_rows(url, TABLES, leave_out=NEW_COLUMNS)


def _api_view(api: Any) -> dict[str, Any]:
    """Every figure the API shows of every user (the fields this release adds left out)."""
    view: dict[str, Any] = {}
    for fleet, ids in {**USERS, "south": [*USERS["south"], "dts"]}.items():
        for uid in ids:
            q = {"fleet": fleet}
            model = comparable_model(api.get(f"/v1/users/{uid}/model", params=q).json())
            model.pop("mission_version", None)
            model.pop("started_from", None)  # a later release's
            user = api.get(f"/v1/users/{uid}", params=q).json()
            user.pop("fleet_prior", None)  # a later release's
            episodes = api.get(f"/v1/users/{uid}/episodes", params={**q, "limit": 500}).json()
            traces = [
                api.get(f"/v1/episodes/{ep['episode_id']}").json() for ep in episodes["items"]
            ]
            for item in [*episodes["items"], *traces]:
                item.pop("mission_version", None)
            view[f"{fleet}/{uid}"] = {
                "user": user,
                "model": model,
                "stats": release.stats(api, uid, q),
                "episodes": episodes["items"],
                "traces": traces,
            }
    return view


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    """A database at the previous release's head, filled through its API."""
    with release.filled(
        request.param,
        old_code,
        tmp_path,
        fill=_fill,
        view=_api_view,
        rows=lambda url, _: _rows(url),
        at=BEFORE,
    ) as database:
        yield database


def _rebuild_all(app: Any, settings: Settings) -> None:
    ctx = ServiceContext.from_settings(settings)
    for fleet, ids in {**USERS, "south": [*USERS["south"], "dts"]}.items():
        for uid in ids:
            with app.state.db.transaction() as session:
                report = rebuild_model(session, ctx, audit.CLI, uid, fleet=fleet)
            assert report.identical, (fleet, uid, report.mismatched_decisions)
            assert report.decisions > 0


def test_the_upgrade_keeps_everything_and_the_service_goes_on(
    filled: Filled,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    url, names, before, _, rows_before = filled

    # Told another mission than the one the models were learned for: refused, nothing changed.
    other = office_mission().to_dict()
    other["situations"] = [*other["situations"], "visiting"]
    (tmp_path / "other.json").write_text(json.dumps(other))
    monkeypatch.setenv("ATTUNE_MISSION_PATH", str(tmp_path / "other.json"))
    with pytest.raises(RuntimeError, match=r"north \(3\), south \(3\).*ATTUNE_MISSION_PATH"):
        migrate.upgrade(url)
    monkeypatch.delenv("ATTUNE_MISSION_PATH")
    engine = create_engine(url)
    try:
        assert migrate.current_revision(engine) == BEFORE
    finally:
        engine.dispose()

    migrate.upgrade(url)
    assert _rows(url) == rows_before
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            stored = conn.execute(
                text("SELECT fleet, version, fingerprint FROM fleet_missions ORDER BY fleet")
            ).all()
            assert [tuple(r) for r in stored] == [
                ("north", 1, office_mission().fingerprint),
                ("south", 1, office_mission().fingerprint),
            ]
            # the journal (samples, as this release called it) is a later release's name
            for table in ("learner_models", "episodes", "journal"):
                assert conn.execute(
                    text(f"SELECT DISTINCT mission_version FROM {table}")
                ).scalars().all() == [1]
    finally:
        engine.dispose()

    settings = Settings(database_url=url, seed=0, _env_file=None)  # type: ignore[call-arg]
    app = create_app(settings)
    try:
        with TestClient(
            app, headers={"Authorization": f"Bearer {names['keys']['admin']}"}
        ) as admin:
            assert _api_view(admin) == before
            _rebuild_all(app, settings)
            north = {"Authorization": f"Bearer {names['keys']['north']}"}
            assert admin.get("/v1/mission", headers=north).json()["version"] == 1
            # The episode left open finishes under its version.
            opened = names["open"]
            answer = {"decision_id": opened["decision"]["decision_id"], "response": "none"}
            if opened["decision"]["action"]["kind"] == "initiate":
                answer["response"] = "accepted"
            assert (
                admin.post(
                    f"/v1/episodes/{opened['episode_id']}/outcomes", json=answer, headers=north
                ).status_code
                == 200
            )
            # North changes its mission; south's users do not move.
            south_models = {
                uid: admin.get(f"/v1/users/{uid}/model", params={"fleet": "south"}).json()
                for uid in ("lin", "bo", "dts")
            }
            changed = other | {
                "services": [
                    {
                        "name": s["name"],
                        "details": [*s["details"], "cocoa"]
                        if s["name"] == "ProvideDrink"
                        else s["details"],
                    }
                    for s in office_mission().to_dict()["services"]
                ]
            }
            r = admin.put(
                "/v1/admin/fleets/north/mission",
                json={"change_id": "north-menu", "mission": changed},
            )
            assert r.status_code == 200, r.text
            assert (r.json()["version"], r.json()["users_moved"]) == (2, 3)
            assert {
                uid: admin.get(f"/v1/users/{uid}/model", params={"fleet": "south"}).json()
                for uid in ("lin", "bo", "dts")
            } == south_models
            _rebuild_all(app, settings)
    finally:
        app.state.db.dispose()

    # Down again: refused while north has a version 2, which it names.
    cfg = migrate.alembic_config(url)
    with pytest.raises(RuntimeError, match=r"north"):
        command.downgrade(cfg, BEFORE)


def test_the_downgrade_gives_back_the_previous_schema(
    filled: Filled,
) -> None:
    url, _, _, _, rows_before = filled
    migrate.upgrade(url)
    command.downgrade(migrate.alembic_config(url), BEFORE)
    assert _rows(url) == rows_before
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            columns = conn.execute(text("SELECT * FROM episodes")).keys()
            assert "mission_version" not in columns
    finally:
        engine.dispose()
    migrate.upgrade(url)
    assert _rows(url) == rows_before
