"""``attune experiment paper|ablation --mission FILE``: the simulated users live in the mission
of FILE instead of the office mission, and the output and the reports say so; a FILE that is
not a mission is one line on stderr and exit code 2."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from app.cli import app
from app.experiments.runner import _mission, jobs_for, run_job
from app.experiments.text import mission_note
from app.learning import load_mission, office_mission
from app.learning.evaluation import ABLATION_METHODS, E3, Protocol

CARE_HOME = Path(__file__).parents[2] / "docs" / "examples" / "care-home-mission.json"
NOTE = "not the paper's office mission"


def run(command: str, out: Path, *extra: str) -> Result:
    return CliRunner(env={"COLUMNS": "40"}).invoke(
        app,
        [
            "experiment",
            command,
            "--seeds",
            "1",
            "--users",
            "1",
            "--jobs",
            "1",
            "--out",
            str(out),
            "--no-progress",
            *extra,
        ],
    )


def test_ablation_in_the_care_home(tmp_path: Path) -> None:
    done = run("ablation", tmp_path, "--mission", str(CARE_HOME))
    assert done.exit_code == 0, done.output
    assert (
        f"Mission 'care-home' from {CARE_HOME} (5 situations, 6 time slots, 3 services), {NOTE}."
    ) in done.stderr
    summary = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    mission = load_mission(CARE_HOME)
    assert summary["run"]["mission"] == {
        "name": "care-home",
        "file": str(CARE_HOME),
        "fingerprint": mission.fingerprint,
        "situations": 5,
        "time_slots": 6,
        "services": 3,
    }
    report = (tmp_path / "ablation.md").read_text(encoding="utf-8")
    assert f"The simulated users lived in the mission 'care-home' of {CARE_HOME}" in report


def test_paper_in_the_care_home_says_so_in_every_report(tmp_path: Path) -> None:
    done = run("paper", tmp_path, "--mission", str(CARE_HOME), "--json")
    assert done.exit_code == 0, done.output
    printed = json.loads(done.stdout)
    assert printed["run"]["mission"]["name"] == "care-home"
    assert NOTE in done.stderr
    table2 = (tmp_path / "table2.md").read_text(encoding="utf-8")
    assert table2.count("lived in the mission 'care-home'") == 2  # Table II and the PA


def test_without_mission_the_office_mission_is_named() -> None:
    (job,) = jobs_for(ABLATION_METHODS[:1], [E3], 1)
    assert job.mission is None
    assert _mission(job.mission) is office_mission()
    office = {"run": {"mission": {"name": "office", "file": None}}}
    assert mission_note(office) == ""
    assert mission_note({"run": {}}) == ""


def test_a_job_carries_its_mission_to_the_worker() -> None:
    care = load_mission(CARE_HOME)
    short = Protocol("short", n_events=12, change_at=None, stream=9)
    (job,) = jobs_for(ABLATION_METHODS[:1], [short], 1, n_users=2, mission=care)
    again = pickle.loads(pickle.dumps(job))  # what the spawned workers get
    assert _mission(again.mission) == care
    result = run_job(again)
    assert result.reward.shape == (2, 12)
    # the same seed in the office mission is another run
    (office_job,) = jobs_for(ABLATION_METHODS[:1], [short], 1, n_users=2)
    assert run_job(office_job).reward.tolist() != result.reward.tolist()


BAD = {
    "missing.json": None,
    "not-json.json": "[1, 2",
    "no-services.json": json.dumps({**office_mission().to_dict(), "services": []}),
}


@pytest.mark.parametrize("command", ["paper", "ablation"])
@pytest.mark.parametrize("name", sorted(BAD))
def test_a_bad_file_is_one_line_and_exit_2(command: str, name: str, tmp_path: Path) -> None:
    path = tmp_path / name
    text = BAD[name]
    if text is not None:
        path.write_text(text, encoding="utf-8")
    out = tmp_path / "out"
    done = run(command, out, "--mission", str(path))
    assert done.exit_code == 2, done.output
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"--mission: {path}: ")
    assert not out.exists()


@pytest.mark.parametrize("command", ["paper", "ablation"])
def test_the_help_explains_mission(command: str) -> None:
    done = CliRunner().invoke(app, ["experiment", command, "--help"])
    assert done.exit_code == 0
    text = " ".join(done.output.split())  # the paragraphs, unwrapped
    assert "--mission FILE" in text
    assert "instead of the paper's office mission" in text
