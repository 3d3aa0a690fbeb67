"""``attune experiment robustness`` on a tiny suite: the files it writes, a table with every
learner and family, blank windows for a family without a change, --json, and bad names."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from app.cli import app

# The module's shared run is made once: every test of the module on one worker.
pytestmark = pytest.mark.xdist_group("experiment-robustness")

FAMILIES = ("abrupt", "shy")
LEARNERS = ("R-MAX", "Q-learning", "HRI τ=0.01", "DTS", "DTS-adapt", "DTS-routine")
FILES = ("robustness.md", "robustness.csv", "robustness.png", "summary.json")


def run(out: Path, *extra: str) -> Result:
    return CliRunner(env={"COLUMNS": "40"}).invoke(
        app,
        [
            "experiment",
            "robustness",
            "--seeds",
            "2",
            "--events",
            "40",
            "--persons",
            "1",
            "--families",
            ",".join(FAMILIES),
            "--jobs",
            "1",
            "--out",
            str(out),
            *extra,
        ],
    )


@pytest.fixture(scope="module")
def suite(tmp_path_factory: pytest.TempPathFactory) -> tuple[Result, Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("robustness")
    done = run(out)
    assert done.exit_code == 0, done.output
    return done, out, json.loads((out / "summary.json").read_text(encoding="utf-8"))


def test_writes_the_files(suite: tuple[Result, Path, dict[str, Any]]) -> None:
    done, out, summary = suite
    for name in FILES:
        assert (out / name).stat().st_size > 0, name
    assert (out / "robustness.png").read_bytes().startswith(b"\x89PNG")
    assert f"Wrote {len(FILES)} files" in done.stderr
    assert summary["learners"] == list(LEARNERS)
    assert list(summary["families"]) == list(FAMILIES)


def test_the_table_has_every_learner_and_family(suite: tuple[Result, Path, dict[str, Any]]) -> None:
    done, out, _ = suite
    for text in (done.stdout, (out / "robustness.md").read_text(encoding="utf-8")):
        lines = text.splitlines()
        for family in FAMILIES:
            assert any(family in line for line in lines), family
        for learner in LEARNERS:  # one row per family in the shares (with intervals)...
            rows = [line for line in lines if f" {learner} " in line and "[" in line]
            assert len(rows) == len(FAMILIES), (learner, rows)
            # ...and one in the changes detected (decided by the learner or by the profile)
            rows = [
                line
                for line in lines
                if f" {learner} " in line and (" learner " in line or " profile " in line)
            ]
            assert len(rows) == len(FAMILIES), (learner, rows)
    with (out / "robustness.csv").open(encoding="utf-8") as handle:
        records = list(csv.DictReader(handle))
    cells = {(r["family"], r["learner"], r["window"]): r for r in records}
    windows = {r["window"] for r in records}
    assert windows == {
        "first20",
        "before30",
        "after15",
        "after30",
        "last30",
        "all",
        "after15_bound",
        "after30_bound",
    }
    assert len(cells) == len(records) == len(FAMILIES) * len(LEARNERS) * len(windows)
    for learner in LEARNERS:
        assert cells[("shy", learner, "after15")]["share_mean"] == ""  # no change: blank
        assert cells[("abrupt", learner, "after15")]["share_mean"] != ""
        assert cells[("shy", learner, "all")]["share_mean"] != ""


def test_prints_the_time_and_the_target(suite: tuple[Result, Path, dict[str, Any]]) -> None:
    done, _, summary = suite
    assert "Finished 4 runs in" in done.stderr
    assert "not the default suite" in done.stderr
    assert "Elapsed:" in done.stdout
    assert summary["run"]["default_suite"] is False
    assert summary["run"]["seconds"] >= 0


def test_json_is_the_summary(tmp_path: Path) -> None:
    done = run(tmp_path, "--json", "--learners", "qlearning,dts")
    assert done.exit_code == 0, done.output
    printed = json.loads(done.stdout)
    assert printed == json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    assert printed["learners"] == ["Q-learning", "DTS"]


@pytest.mark.parametrize("option", ["--families", "--learners"])
def test_unknown_names_are_refused(tmp_path: Path, option: str) -> None:
    done = CliRunner().invoke(
        app, ["experiment", "robustness", option, "nobody", "--out", str(tmp_path)]
    )
    assert done.exit_code == 2
    assert "nobody" in done.output
    assert not (tmp_path / "summary.json").exists()


def test_the_defaults_of_the_command_are_the_suites() -> None:
    from app.experiments import robustness

    command = next(c for c in app.registered_groups if c.name == "experiment").typer_instance
    assert command is not None
    info = next(c for c in command.registered_commands if c.name == "robustness")
    assert info.callback is not None
    defaults = info.callback.__defaults__ or ()
    assert (
        robustness.DEFAULT_SEEDS,
        robustness.DEFAULT_EVENTS,
        robustness.DEFAULT_PERSONS,
    ) == defaults[:3]


def test_another_mission_is_named(tmp_path: Path) -> None:
    care_home = Path(__file__).resolve().parents[2] / "docs/examples/care-home-mission.json"
    done = run(tmp_path, "--mission", str(care_home), "--learners", "dts")
    assert done.exit_code == 0, done.output
    assert "not the paper's office mission" in done.stderr
    assert "care-home" in (tmp_path / "robustness.md").read_text(encoding="utf-8")
    summary = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    assert summary["run"]["mission"]["file"] == str(care_home)


def test_prints_the_rules_pick_and_the_targets_of_the_default(
    suite: tuple[Result, Path, dict[str, Any]],
) -> None:
    from app.experiments.robustness import LEARNERS as SUITE
    from app.experiments.robustness import SERVICE_DEFAULT
    from app.schemas.users import LearnerSpec

    done, out, summary = suite
    # The suite's default is the service's: its algorithm with that algorithm's defaults.
    assert (SUITE[SERVICE_DEFAULT].algorithm, dict(SUITE[SERVICE_DEFAULT].params)) == (
        LearnerSpec().algorithm,
        LearnerSpec().params,
    )
    assert summary["rule"]["chosen"] in LEARNERS
    assert [r["learner"] for r in summary["rule"]["ranking"]][0] == summary["rule"]["chosen"]
    windows = [(t["family"], t["window"]) for t in summary["targets"]]
    assert windows == [
        ("abrupt", "after15_bound"),
        ("abrupt", "before30"),
        ("abrupt", "all"),
        ("abrupt", "all"),  # no worse than the previous default
        ("abrupt", "detection"),
        ("shy", "all"),
        ("shy", "all"),
        ("shy", "false_alarms"),
    ]
    for text in (done.stdout, (out / "robustness.md").read_text(encoding="utf-8")):
        assert f"The rule picks {summary['rule']['chosen']}" in text
        assert "15 after, of the one-miss oracle" in text
        assert "Changes detected" in text
        assert "met" in text or "MISSED" in text
        assert text.count("MISSED") == sum(not t["met"] for t in summary["targets"])
