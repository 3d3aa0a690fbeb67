"""``attune experiment newcomers`` on a tiny run: the files it writes, fresh and prior rows for
every learner and family, the paired differences, the targets printed met or missed, --json,
bad options, and that the fresh runs are the robustness suite's runs of the same persons."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner, Result

from app.cli import app

# The module's shared run is made once: every test of the module on one worker.
pytestmark = pytest.mark.xdist_group("experiment-newcomers")

FAMILIES = ("home", "individual")
LEARNERS = ("DTS", "DTS-adapt")
FILES = ("newcomers.md", "newcomers.csv", "newcomers.png", "summary.json")
WINDOWS = ("first20", "early", "after100", "all")


def run(out: Path, *extra: str) -> Result:
    return CliRunner(env={"COLUMNS": "40"}).invoke(
        app,
        [
            "experiment",
            "newcomers",
            "--seeds",
            "2",
            "--events",
            "110",
            "--residents",
            "4",
            "--learners",
            "dts,dts-adapt",
            "--jobs",
            "1",
            "--out",
            str(out),
            "--no-progress",
            *extra,
        ],
    )


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> tuple[Result, Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("newcomers")
    done = run(out)
    assert done.exit_code == 0, done.output
    return done, out, json.loads((out / "summary.json").read_text(encoding="utf-8"))


@pytest.mark.slow
def test_writes_the_files(study: tuple[Result, Path, dict[str, Any]]) -> None:
    done, out, summary = study
    for name in FILES:
        assert (out / name).stat().st_size > 0, name
    assert (out / "newcomers.png").read_bytes().startswith(b"\x89PNG")
    assert f"Wrote {len(FILES)} files" in done.stderr
    assert summary["learners"] == list(LEARNERS)
    assert list(summary["families"]) == list(FAMILIES)  # the default families
    assert list(summary["windows"]) == list(WINDOWS)
    assert summary["windows"]["after100"]["events"] == [101, 110]


@pytest.mark.slow
def test_every_share_is_bounded_and_the_difference_is_paired(
    study: tuple[Result, Path, dict[str, Any]],
) -> None:
    _, _, summary = study
    for fam in summary["families"].values():
        assert fam["seeds"] == 2
        for cells in fam["learners"].values():
            for window in WINDOWS:
                fresh, prior = cells["fresh"][window], cells["prior"][window]
                diff = cells["difference"][window]
                for cell in (fresh, prior, diff):
                    assert cell["ci95"][0] <= cell["mean"] <= cell["ci95"][1]
                for share in fresh["per_seed"] + prior["per_seed"]:
                    assert -1.0 <= share <= 1.2
                for f, p, d in zip(
                    fresh["per_seed"], prior["per_seed"], diff["per_seed"], strict=True
                ):
                    assert d == pytest.approx(p - f, abs=2e-4)
            for arm in ("fresh", "prior"):
                curve = cells["curves"][arm]
                assert len(curve) == summary["run"]["events"]
                assert all(v is None or math.isfinite(v) for v in curve)


@pytest.mark.slow
def test_a_home_newcomer_from_the_prior_starts_better(
    study: tuple[Result, Path, dict[str, Any]],
) -> None:
    """An ordering, not a number: in a home, DTS from the other residents' prior earns a larger
    share of the oracle's reward in the first 20 events than a fresh DTS, in every seed."""
    _, _, summary = study
    cells = summary["families"]["home"]["learners"]["DTS"]
    for fresh, prior in zip(
        cells["fresh"]["first20"]["per_seed"], cells["prior"]["first20"]["per_seed"], strict=True
    ):
        assert prior > fresh


@pytest.mark.slow
def test_the_table_has_fresh_and_prior_rows(study: tuple[Result, Path, dict[str, Any]]) -> None:
    done, out, _ = study
    for text in (done.stdout, (out / "newcomers.md").read_text(encoding="utf-8")):
        lines = text.splitlines()
        for family in FAMILIES:
            assert any(family in line for line in lines), family
        for start in ("fresh", "prior", "prior − fresh"):  # one row per family and learner
            rows = [line for line in lines if f" {start} " in line and "[" in line]
            assert len(rows) >= len(FAMILIES) * len(LEARNERS), start
    with (out / "newcomers.csv").open(encoding="utf-8") as handle:
        records = list(csv.DictReader(handle))
    keys = {(r["family"], r["learner"], r["start"], r["window"]) for r in records}
    assert len(keys) == len(records) == len(FAMILIES) * len(LEARNERS) * 3 * len(WINDOWS)
    assert {r["start"] for r in records} == {"fresh", "prior", "difference"}


@pytest.mark.slow
def test_prints_the_targets_met_or_missed(study: tuple[Result, Path, dict[str, Any]]) -> None:
    done, out, summary = study
    targets = summary["targets"]
    ids = [(t["id"], t["family"], t["window"]) for t in targets]
    assert ids.count(("a", "home", "first20")) == len(LEARNERS)
    for window in ("first20", "all"):
        assert ids.count(("b", "individual", window)) == len(LEARNERS)
    for family in FAMILIES:
        assert ids.count(("c", family, "after100")) == len(LEARNERS)
    for t in targets:
        if t["id"] == "a":
            assert t["met"] == (round(t["share"], 2) >= 0.80)
        else:
            assert t["met"] == (t["ci95"][1] >= 0.0)
    met = sum(t["met"] for t in targets)
    for text in (done.stdout, (out / "newcomers.md").read_text(encoding="utf-8")):
        assert f"{met} of {len(targets)} met" in text
        assert text.count("MISSED") == len(targets) - met
        for line in ("(a) home", "(b) individual", "(c) home", "(c) individual"):
            assert line in text
    assert "Finished 4 runs in" in done.stderr
    assert "not the default run" in done.stderr
    assert "Elapsed:" in done.stdout


@pytest.mark.slow
def test_json_is_the_summary(tmp_path: Path) -> None:
    done = run(tmp_path, "--json", "--families", "home", "--learners", "hri", "--events", "40")
    assert done.exit_code == 0, done.output
    printed = json.loads(done.stdout)
    assert printed == json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    assert printed["learners"] == ["HRI τ=0.01"]
    assert list(printed["families"]) == ["home"]
    assert [t["id"] for t in printed["targets"]] == ["a"]  # no event after 100: no (c)


def test_a_support_above_the_contributors_gives_fresh_learners(tmp_path: Path) -> None:
    done = run(
        tmp_path, "--families", "home", "--learners", "dts", "--events", "30", "--min-support", "4"
    )
    assert done.exit_code == 0, done.output
    assert "every prior is a fresh learner" in done.stderr
    summary = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    cells = summary["families"]["home"]["learners"]["DTS"]
    assert cells["fresh"] == cells["prior"]  # the same generators: the same runs
    assert cells["difference"]["all"]["mean"] == 0.0


@pytest.mark.parametrize(
    ("option", "value"), [("--families", "nobody"), ("--learners", "nobody"), ("--strength", "0")]
)
def test_bad_options_are_refused(tmp_path: Path, option: str, value: str) -> None:
    done = CliRunner().invoke(
        app, ["experiment", "newcomers", option, value, "--out", str(tmp_path)]
    )
    assert done.exit_code == 2
    assert value in done.output
    assert not (tmp_path / "summary.json").exists()


def test_the_defaults_of_the_command_are_the_studys() -> None:
    from app.experiments import newcomers

    command = next(c for c in app.registered_groups if c.name == "experiment").typer_instance
    assert command is not None
    info = next(c for c in command.registered_commands if c.name == "newcomers")
    assert info.callback is not None
    defaults = info.callback.__defaults__ or ()
    assert defaults[:7] == (
        newcomers.DEFAULT_SEEDS,
        newcomers.DEFAULT_RESIDENTS,
        newcomers.DEFAULT_EVENTS,
        None,
        None,
        newcomers.DEFAULT_STRENGTH,
        newcomers.MIN_SUPPORT,
    )


def test_the_fresh_runs_are_the_robustness_suites() -> None:
    from app.experiments.newcomers import newcomer_rewards
    from app.experiments.robustness import LEARNERS as SUITE
    from app.learning import office_mission
    from app.learning.population import FAMILIES as ALL
    from app.learning.population import run_family

    method = SUITE["dts"]
    mine = newcomer_rewards(ALL["home"], 3, [method], office_mission(), n_residents=3, n_events=30)
    suites = run_family(
        ALL["home"],
        3,
        [(method.label, method.algorithm, dict(method.params))],
        office_mission(),
        n_persons=3,
        n_events=30,
    )
    np.testing.assert_array_equal(mine.oracle, suites.oracle)
    np.testing.assert_array_equal(mine.fresh[method.label], suites.learners[method.label])


def test_without_matplotlib_it_says_which_extra(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    done = CliRunner().invoke(
        app,
        ["experiment", "newcomers", "--seeds", "2", "--jobs", "1", "--out", str(tmp_path / "out")],
    )
    assert done.exit_code == 2
    assert "'experiments' extra" in done.stderr
    assert done.stdout == ""
    assert not (tmp_path / "out").exists()
