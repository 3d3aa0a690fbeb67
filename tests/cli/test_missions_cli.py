"""``attune missions show|list|set`` on SQLite and PostgreSQL: a fleet's mission read and changed
at the machine, with what it says about bad files and repeated changes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from app.main import create_app
from app.settings import Settings

from .conftest import Attune


def _office(attune: Attune, fleet: str = "default") -> dict[str, Any]:
    done = attune("missions", "show", "--fleet", fleet, "--json")
    assert done.exit_code == 0, done.stderr
    doc: dict[str, Any] = json.loads(done.stdout)
    return doc


def test_show_prints_the_default_until_a_fleet_has_its_own(attune: Attune) -> None:
    done = attune("missions", "show", "--fleet", "north")
    assert done.exit_code == 0, done.stderr
    assert "version 1" in done.stdout
    assert "default" in done.stdout  # not stored yet: the deployment's default
    assert "busy (do not disturb)" in done.stdout
    assert _office(attune, "north")["name"] == "office"


def test_set_makes_a_version_carries_renames_and_is_idempotent(
    attune: Attune, tmp_path: Path
) -> None:
    doc = _office(attune)
    drinks = doc["services"][0]
    drinks["details"] = ["cha" if d == "tea" else d for d in drinks["details"]] + ["cocoa"]
    (tmp_path / "m.json").write_text(json.dumps(doc))
    (tmp_path / "r.json").write_text(json.dumps({"details": {"tea": "cha"}}))
    args = ("missions", "set", str(tmp_path / "m.json"), "--renames", str(tmp_path / "r.json"))
    done = attune(*args)
    assert done.exit_code == 0, done.stderr
    assert "version 2" in done.stderr
    assert "added ProvideDrink/cocoa" in done.stderr
    assert "ProvideDrink/tea -> ProvideDrink/cha" in done.stderr
    again = attune(*args, "--json")  # the same files: the same change, nothing new
    assert again.exit_code == 0, again.stderr
    out = json.loads(again.stdout)
    assert (out["version"], out["replayed"]) == (2, True)
    listed = json.loads(attune("missions", "list", "--json").stdout)
    assert [i["version"] for i in listed["items"]] == [2, 1]
    assert listed["items"][0]["renames"]["details"] == {"tea": "cha"}
    assert _office(attune)["services"][0]["details"][0] == "cha"
    old = attune("missions", "show", "--version", "1")
    assert "replaced" in old.stdout
    assert "tea" in old.stdout
    assert attune("missions", "show", "--version", "7").exit_code == 2


def test_set_moves_the_fleets_models(attune: Attune, tmp_path: Path, database_url: str) -> None:
    app = create_app(Settings(database_url=database_url, _env_file=None))  # type: ignore[call-arg]

    key = attune("keys", "create", "--role", "robot").stdout.strip()
    try:
        with TestClient(app, headers={"Authorization": f"Bearer {key}"}) as robot:
            r = robot.post(
                "/v1/users/lin/episodes",
                json={
                    "event_id": "e1",
                    "occurred_at": "2026-11-22T15:10:00+08:00",
                    "situation": "stretching",
                    "initiator": "robot",
                },
            )
            assert r.status_code == 201, r.text
            doc = _office(attune)
            doc["situations"].append("visiting")
            (tmp_path / "m.json").write_text(json.dumps(doc))
            done = attune("missions", "set", str(tmp_path / "m.json"))
            assert done.exit_code == 0, done.stderr
            assert "1 models carried over, 1 open episodes interrupted" in done.stderr
            assert robot.get("/v1/users/lin/model").json()["mission_version"] == 2
            assert (
                robot.get(f"/v1/episodes/{r.json()['episode_id']}").json()["status"]
                == "interrupted"
            )
    finally:
        app.state.db.dispose()


def test_bad_files_say_why_in_one_line(attune: Attune, tmp_path: Path) -> None:
    (tmp_path / "bad.json").write_text('{"name": "x"}')
    done = attune("missions", "set", str(tmp_path / "bad.json"))
    assert done.exit_code == 2
    assert "situations" in done.stderr
    assert "Traceback" not in done.stderr
    (tmp_path / "not.json").write_text("{")
    done = attune("missions", "set", str(tmp_path / "not.json"))
    assert done.exit_code == 2
    assert "is not JSON" in done.stderr
    done = attune("missions", "set", str(tmp_path / "missing.json"))
    assert done.exit_code == 2
    assert "Cannot read" in done.stderr
    doc = _office(attune)
    (tmp_path / "m.json").write_text(json.dumps(doc))
    (tmp_path / "r.json").write_text(json.dumps({"details": {"nectar": "tea"}}))
    done = attune(
        "missions", "set", str(tmp_path / "m.json"), "--renames", str(tmp_path / "r.json")
    )
    assert done.exit_code == 2
    assert "nectar" in done.stderr
