"""The migration to fleets with ids of their own, on a database filled by the release before it.

The previous release (the commit before the one that added this migration) is taken from git
and served as it was: `attune serve` of that code, on a fresh database, filled through its HTTP
API with what a deployment holds (two fleets' keys, users with history, explicit feedback, a
reset in the middle of a history, an imported model, admin actions in the audit log). Then this
code upgrades the database, and every row, every model version and every figure must be as it
was, every user's model must rebuild identically (its past decisions redrawn from the same
seeds), the service must go on serving them, and the downgrade must work while user ids are
still unique across fleets (and say which ids are not, when they are not).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from app.db import migrate
from app.main import create_app
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

MIGRATION = "migrations/versions/2026-11-30-1200_fleets_are_tenants.py"
BEFORE = "5b7e1c2d9a40"  # the revision the previous release ends at
USER_TABLES = ("learner_models", "episodes", "samples")
USERS = {"north": ["lin", "chen", "room-12"], "south": ["ana", "bo"], "default": ["dts-user"]}


@pytest.fixture(scope="module")
def old_code(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The previous release's ``app`` and ``migrations``, as git has them."""
    assert migrate.head_revision() != BEFORE
    return release_code(previous_release(MIGRATION), tmp_path_factory.mktemp("previous-release"))


def _fill(old: OldService) -> dict[str, Any]:
    """What a deployment holds, made through the previous release's API; the names used."""
    keys = {
        "robot_a": ("robot", "north"),
        "robot_b": ("robot", "south"),
        "admin": ("admin", "default"),
    }
    with release.clients(old, keys) as (secrets, clients):
        n = 0
        for fleet in ("north", "south"):
            api = clients["robot_a" if fleet == "north" else "robot_b"]
            for uid in USERS[fleet]:
                made = api.put(f"/v1/users/{uid}", json={"display_name": uid.title()})
                assert made.status_code == 201, made.text
                n = release.history(api, uid, 9, n)
        admin = clients["admin"]
        assert admin.delete("/v1/users/chen/model").status_code == 204  # a reset mid-history
        for i in range(3):
            run_episode(clients["robot_a"], "chen", f"chen-after-{i}", n + i)
        doc = admin.get("/v1/users/lin/model/export")
        assert doc.status_code == 200
        assert admin.put("/v1/users/bo/model", json=doc.json()).status_code == 200  # imported
        run_episode(clients["robot_b"], "bo", "bo-after-import", 99)
        assert (
            admin.put("/v1/users/dts-user", json={"learner": {"algorithm": "dts"}}).status_code
            == 201
        )
        for i in range(4):
            run_episode(admin, "dts-user", f"dts-{i}", i)
        old.attune(
            "keys", "revoke", old.attune("keys", "list", "--json").split('"id": "')[1].split('"')[0]
        )
    return {"keys": secrets, "users": USERS}


def _api_view(api: Any, users: dict[str, list[str]], *, fleet_param: bool) -> dict[str, Any]:
    """Every figure the API shows of every user: the user, its model, stats, episodes and their
    traces, and the audit log."""
    view: dict[str, Any] = {}
    for fleet, ids in users.items():
        for uid in ids:
            q = {"fleet": fleet} if fleet_param else {}
            user = api.get(f"/v1/users/{uid}", params=q).json()
            user.pop("fleet_prior", None)
            model = comparable_model(api.get(f"/v1/users/{uid}/model", params=q).json())
            model.pop("started_from", None)
            stats = release.stats(api, uid, q)
            episodes = api.get(f"/v1/users/{uid}/episodes", params={**q, "limit": 500}).json()
            traces = []
            # Later releases add fields: the fleet (traces, episodes), the mission version
            # (episodes, models), where a model started and whether a user takes part in the
            # fleet's prior.
            model.pop("mission_version", None)
            for ep in episodes["items"]:
                trace = api.get(f"/v1/episodes/{ep['episode_id']}").json()
                trace.pop("fleet", None)
                trace.pop("mission_version", None)
                traces.append(trace)
            for ep in episodes["items"]:
                ep.pop("fleet", None)
                ep.pop("mission_version", None)
            view[f"{fleet}/{uid}"] = {
                "user": user,
                "model": model,
                "stats": stats,
                "episodes": episodes["items"],
                "traces": traces,
            }
    view["audit"] = api.get("/v1/admin/audit", params={"limit": 500}).json()["items"]
    return view


def _rows(url: str, user_key: str) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of every table; a user's rows name it by (fleet, user id) instead of the key
    of the schema in force (``user_key``: ``user_id`` before, ``id`` after), and the users' own
    key and seed key (new) and later releases' columns are left out."""
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            owner = {
                r[0]: (r[1], r[2])
                for r in conn.execute(text(f"SELECT {user_key}, fleet, user_id FROM users"))
            }
    finally:
        engine.dispose()

    def by_owner(table: str, row: dict[str, Any]) -> None:
        if table == "users":
            row.pop("id", None)
            row.pop("seed_key", None)
        elif table in USER_TABLES:
            row["user"] = owner[row.pop("user_pk" if "user_pk" in row else "user_id")]

    return table_rows(
        url,
        ("users", *USER_TABLES, "decisions", "feedback", "api_keys", "audit_log"),
        leave_out=(
            "mission_version",
            "base_mission_version",
            "utc_offset",
            "fleet_prior",
            "base_origin",
            "base_contributors",
        ),
        rewrite=by_owner,
    )


@pytest.fixture(params=["sqlite", "postgresql"])
def filled(request: pytest.FixtureRequest, old_code: Path, tmp_path: Path) -> Iterator[Filled]:
    """A database at the previous release's head, filled through its API (its users' rows by
    their ``user_id``, the key of the previous schema)."""
    with release.filled(
        request.param,
        old_code,
        tmp_path,
        fill=_fill,
        view=lambda admin: _api_view(admin, USERS, fleet_param=False),
        rows=lambda url, _: _rows(url, "user_id"),
        at=BEFORE,
    ) as database:
        yield database


def test_the_upgrade_keeps_every_row_figure_and_decision(
    filled: Filled,
) -> None:
    url, names, before, _, rows_before = filled
    migrate.upgrade(url)
    assert _rows(url, "id") == rows_before

    settings = Settings(database_url=url, seed=0, _env_file=None)  # type: ignore[call-arg]
    app = create_app(settings)
    try:
        admin_key = names["keys"]["admin"]
        with TestClient(app, headers={"Authorization": f"Bearer {admin_key}"}) as admin:
            after = _api_view(admin, names["users"], fleet_param=True)
            assert after == before
            # The existing users keep their seeds: every past decision redraws identically.
            ctx = ServiceContext.from_settings(settings)
            from app.services import audit as audit_service

            for fleet, ids in names["users"].items():
                for uid in ids:
                    with app.state.db.transaction() as session:
                        report = rebuild_model(session, ctx, audit_service.CLI, uid, fleet=fleet)
                    assert report.identical, (fleet, uid, report.mismatched_decisions)
                    assert report.decisions > 0
            # The service goes on: the same robots serve their users; a second fleet may now
            # have a user of an id the first has.
            robot_b = {"Authorization": f"Bearer {names['keys']['robot_b']}"}
            assert admin.put("/v1/users/lin", json={}, headers=robot_b).status_code == 201
            assert admin.get("/v1/users/lin", headers=robot_b).json()["fleet"] == "south"
            assert (
                admin.get("/v1/users/lin", params={"fleet": "north"}).json()["episodes"]
                == before["north/lin"]["user"]["episodes"]
            )
    finally:
        app.state.db.dispose()

    # Down again, while ids are unique across fleets: refused at first, then done.
    cfg = migrate.alembic_config(url)
    with pytest.raises(RuntimeError, match=r"lin"):
        command.downgrade(cfg, BEFORE)
    # SQLite's migrations are not one transaction: the later revisions' downgrades before the
    # refusal stay done. Up again, as an operator would, before the service runs.
    migrate.upgrade(url)
    app = create_app(settings)
    try:
        with TestClient(app, headers={"Authorization": f"Bearer {admin_key}"}) as admin:
            r = admin.delete("/v1/users/lin", params={"fleet": "south"})
            assert r.status_code == 204, r.text
    finally:
        app.state.db.dispose()
    command.downgrade(cfg, BEFORE)
    assert _rows(url, "user_id")["episodes"] == rows_before["episodes"]
    migrate.upgrade(url)
    assert _rows(url, "id")["samples"] == rows_before["samples"]
