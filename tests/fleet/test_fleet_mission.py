"""``attune fleet simulate --mission FILE``: the fleet's mission is set from FILE through the
client before the people are drawn from it; a bad FILE is one line and exit code 2.

The service is the real application under uvicorn in this process (``serving``), on SQLite and
PostgreSQL; the command runs in its own process, as an operator runs it.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from typer.testing import CliRunner

from app.cli import app as cli
from app.learning import load_mission
from tests.support.fixtures import MakeKey
from tests.support.live import ATTUNE, serving

CARE_HOME = Path(__file__).parents[2] / "docs" / "examples" / "care-home-mission.json"
MISSION = load_mission(CARE_HOME)


def simulate(url: str, key: str, *extra: str) -> subprocess.CompletedProcess[str]:
    args = [
        ATTUNE,
        "fleet",
        "simulate",
        "--url",
        url,
        "--key",
        key,
        "--robots",
        "2",
        "--users",
        "2",
        "--events",
        "6",
        "--seed",
        "3",
        "--prefix",
        "care",
        "--json",
        "--no-progress",
        "--deadline",
        "120",
        *extra,
    ]
    env = {**os.environ, "ATTUNE_KEY": ""}
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=180, check=False)


def get(url: str, key: str, path: str, **params: Any) -> Any:
    r = httpx.get(
        f"{url}{path}", params=params, headers={"Authorization": f"Bearer {key}"}, timeout=30
    )
    assert r.status_code == 200, r.text
    return r.json()


def test_the_people_are_drawn_from_the_mission_in_the_file(app: FastAPI, make_key: MakeKey) -> None:
    staff, robot = make_key("staff"), make_key("robot")
    with serving(app) as url:
        done = simulate(url, staff, "--mission", str(CARE_HOME))
        assert done.returncode == 0, done.stderr
        assert f"Fleet 'default' now has the mission in {CARE_HOME}: version 2" in done.stderr
        assert "Mission 'care-home': 5 situations, 6 time slots, 3 services." in done.stderr
        printed = json.loads(done.stdout)
        assert printed["overall"]["episodes"] == 2 * 6

        mission = get(url, robot, "/v1/mission")
        # Version 1 was the deployment's default, which the fleet had until then.
        assert (mission["name"], mission["version"]) == ("care-home", 2)
        assert mission["fingerprint"] == MISSION.fingerprint
        slots = {s.name for s in MISSION.time_slots}
        for user_id in ("care-u1", "care-u2"):
            items = get(url, robot, f"/v1/users/{user_id}/episodes", limit=100)["items"]
            assert len(items) == 6
            for item in items:
                assert item["context"]["situation"] in MISSION.situations
                assert item["context"]["time_slot"] in slots
                assert item["mission_version"] == 2

        # The same file again is the same change: nothing changes, the run goes on.
        again = simulate(url, staff, "--mission", str(CARE_HOME), "--prefix", "care2")
        assert again.returncode == 0, again.stderr
        assert "was set before (version 2 of fleet 'default'); nothing changed" in again.stderr
        versions = get(url, staff, "/v1/admin/fleets/default/missions")
        assert versions["current_version"] == 2


def test_a_changed_mission_moves_the_fleet_to_a_new_version(
    app: FastAPI, make_key: MakeKey, tmp_path: Path
) -> None:
    admin = make_key("admin")
    with serving(app) as url:
        first = simulate(url, admin, "--events", "2")  # the office mission: version 1
        assert first.returncode == 0, first.stderr
        assert "Mission 'office'" in first.stderr
        done = simulate(url, admin, "--mission", str(CARE_HOME), "--prefix", "later")
        assert done.returncode == 0, done.stderr
        assert "version 2, 2 models carried to it, 0 open episodes interrupted" in done.stderr
        # a mission of another content is another change: version 3
        other = json.loads(CARE_HOME.read_text())
        other["services"][0]["details"].append("juice")
        path = tmp_path / "with-juice.json"
        path.write_text(json.dumps(other))
        done = simulate(url, admin, "--mission", str(path), "--prefix", "juice")
        assert done.returncode == 0, done.stderr
        assert get(url, admin, "/v1/mission")["version"] == 3


def test_a_robot_key_cannot_set_the_mission(app: FastAPI, make_key: MakeKey) -> None:
    with serving(app) as url:
        done = simulate(url, make_key("robot"), "--mission", str(CARE_HOME))
    assert done.returncode == 2
    assert "403" in done.stderr
    assert done.stdout == ""


BAD_FILES = {
    "missing.json": None,
    "not-json.json": '{"name": "care-home",',
    "unknown-field.json": json.dumps({**MISSION.to_dict(), "menu": []}),
    "bad-slot.json": json.dumps(
        {**MISSION.to_dict(), "time_slots": [{"name": "day", "start": "07:00", "end": "21:00"}]}
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_a_bad_file_is_one_line_and_exit_2(name: str, tmp_path: Path) -> None:
    path = tmp_path / name
    if BAD_FILES[name] is not None:
        path.write_text(BAD_FILES[name] or "", encoding="utf-8")
    # nothing answers at this URL: the file is checked before the service is asked
    done = CliRunner().invoke(
        cli,
        [
            "fleet",
            "simulate",
            "--url",
            "http://127.0.0.1:9",
            "--key",
            "att_x",
            "--mission",
            str(path),
            "--no-progress",
        ],
    )
    assert done.exit_code == 2, done.output
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"--mission: {path}: ")
    assert "No service answers" not in done.stderr


def test_the_help_explains_mission() -> None:
    done = CliRunner().invoke(cli, ["fleet", "simulate", "--help"])
    assert done.exit_code == 0
    text = " ".join(done.output.split())  # the paragraphs, unwrapped
    assert "--mission FILE" in text
    assert "change_id derived from its content" in text
    assert "Needs a staff or admin key" in text
