"""``attune experiment what-if`` on a tiny run: the files it writes, a cell per setting, arm,
estimator and interval whose numbers hang together, the logger's own value covered by its logs,
the targets printed met or missed, --json, and bad options refused with a usage error."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from app.cli import app
from app.experiments.whatif import CSV_COLUMNS, INTERVALS
from app.learning.offpolicy import ESTIMATORS

# The module's shared run is made once: every test of the module on one worker.
pytestmark = pytest.mark.xdist_group("experiment-whatif")

FILES = ("whatif.md", "whatif.csv", "whatif.png", "summary.json")
SIZES = (20, 60)
CANDIDATES = ("HRI τ=0.02", "DTS")


def run(out: Path, *extra: str) -> Result:
    return CliRunner(env={"COLUMNS": "60"}).invoke(
        app,
        [
            "experiment",
            "what-if",
            "--trials",
            "3",
            "--persons",
            "4",
            "--sizes",
            ",".join(str(k) for k in SIZES),
            "--candidates",
            "hri-0.02,dts",
            "--truth-runs",
            "1",
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
    out = tmp_path_factory.mktemp("what-if")
    done = run(out)
    assert done.exit_code == 0, done.output
    return done, out, json.loads((out / "summary.json").read_text(encoding="utf-8"))


@pytest.mark.slow
def test_writes_the_files_and_a_cell_for_everything(
    study: tuple[Result, Path, dict[str, Any]],
) -> None:
    done, out, summary = study
    for name in FILES:
        assert (out / name).stat().st_size > 0, name
    assert (out / "whatif.png").read_bytes().startswith(b"\x89PNG")
    assert f"Wrote {len(FILES)} files" in done.stderr
    assert summary["logger"] == "HRI τ=0.01"
    assert summary["candidates"] == list(CANDIDATES)
    assert summary["sizes"] == list(SIZES)
    keys = {(c["episodes"], c["arm"], c["estimator"], c["interval"]) for c in summary["cells"]}
    expected = {
        (k, arm, estimator, interval)
        for k in SIZES
        for arm, estimators in (("HRI τ=0.01", ("logged",)), *((c, ESTIMATORS) for c in CANDIDATES))
        for estimator in estimators
        for interval in INTERVALS
    }
    assert keys == expected
    with (out / "whatif.csv").open(encoding="utf-8") as handle:
        records = list(csv.DictReader(handle))
    assert len(records) == len(expected)
    assert tuple(records[0]) == CSV_COLUMNS


@pytest.mark.slow
def test_the_numbers_hang_together(study: tuple[Result, Path, dict[str, Any]]) -> None:
    _, _, summary = study
    for c in summary["cells"]:
        assert c["trials"] == 3
        assert 0 <= c["answered"] <= c["trials"]
        if c["answered"]:
            assert 0.0 <= c["coverage"] <= c["coverage_or_silent"] <= 1.0
            assert c["rmse"] >= abs(c["bias"]) - 1e-4
            assert c["width"] > 0
        if c["logger"]:
            # the logger's own value read from its logs: every weight 1
            assert c["ess"] == c["episodes"]
            assert c["unsupported"] == 0
    # a bigger fleet, narrower bootstrap intervals for the logger's own value
    widths = {
        c["episodes"]: c["width"]
        for c in summary["cells"]
        if c["logger"] and c["interval"] == "bootstrap"
    }
    assert widths[SIZES[1]] < widths[SIZES[0]]


@pytest.mark.slow
def test_prints_the_targets_met_or_missed(study: tuple[Result, Path, dict[str, Any]]) -> None:
    done, out, summary = study
    targets = summary["targets"]
    # coverage per setting, and a ranking per pair of arms apart in expectation
    assert len(targets) == len(SIZES) + len(summary["ranking"]["pairs"])
    for t in targets:
        verdict = "met" if t["met"] else "MISSED"
        assert f"{verdict}: {t['target']}" in done.stdout
        assert f"{verdict}: {t['target']}" in (out / "whatif.md").read_text(encoding="utf-8")
    assert "Elapsed:" in done.stdout
    assert "not the default run" in done.stdout
    assert summary["ranking"]["episodes"] == max(SIZES)
    # one trial of each of 3 families: a pair is ranked in the families whose truths put
    # its arms 0.1 apart, each family once
    assert summary["ranking"]["families"] == ["individual", "home", "abrupt"]
    for pair in summary["ranking"]["pairs"]:
        assert pair["gap"] >= 0.1
        families = pair["families"]
        assert families
        assert len({f["family"] for f in families}) == len(families)
        n = sum(f["truth"]["trials"] for f in families)
        assert n == len(families)
        for f in families:
            assert f["gap"] >= 0.1
            assert f["truth"]["ordered"] == 1.0  # its own truths put it so, with one trial
        for estimator in ESTIMATORS:
            assert pair[estimator]["trials"] + pair[estimator]["silent"] == n
            assert sum(f[estimator]["trials"] for f in families) == pair[estimator]["trials"]
        assert pair["truth"] == {"trials": n, "ordered": 1.0}
        assert f"the fleets' own truths 100% of {n}" in done.stdout
    # per family, in the report
    if summary["ranking"]["pairs"]:
        assert "## Ranking by family" in (out / "whatif.md").read_text(encoding="utf-8")


@pytest.mark.slow
def test_json_prints_the_summary(tmp_path: Path) -> None:
    done = run(tmp_path, "--json", "--trials", "1")
    assert done.exit_code == 0, done.output
    summary = json.loads(done.stdout)
    assert summary["study"] == "what-if"
    assert summary["run"]["trials"] == 1


@pytest.mark.parametrize(
    ("option", "value", "words"),
    [
        ("--sizes", "10,x", "numbers separated by commas"),
        ("--sizes", "30", "multiple of --persons"),
        ("--logger", "nobody", "one of"),
        ("--candidates", "hri,nobody", "'nobody'"),
        ("--families", "nowhere", "'nowhere'"),
    ],
)
def test_refuses_bad_options(tmp_path: Path, option: str, value: str, words: str) -> None:
    done = run(tmp_path, option, value)
    assert done.exit_code == 2, done.output
    assert words in " ".join(done.output.split())


def test_a_run_where_every_candidate_is_refused_still_reports(tmp_path: Path) -> None:
    """Logged under dts-routine, which leaves little to chance, R-MAX (which never draws) is
    refused in every fleet: the table says so, the plot is drawn without its lines, and nothing
    fails."""
    done = run(tmp_path, "--logger", "dts-routine", "--candidates", "hri,rmax", "--sizes", "40")
    assert done.exit_code == 0, done.output
    summary = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    cells = [c for c in summary["cells"] if not c["logger"] and c["interval"] == "bootstrap"]
    refused = [c for c in cells if c["answered"] == 0]
    assert {c["arm"] for c in refused} >= {"R-MAX"}
    assert all(c["coverage"] is None and c["bias"] is None for c in refused)
    assert (tmp_path / "whatif.png").read_bytes().startswith(b"\x89PNG")
    assert "no answer" in done.stdout


@pytest.mark.slow
def test_replay_value_splits_the_bias_into_the_approximation_and_the_estimators_own(
    tmp_path: Path, study: tuple[Result, Path, dict[str, Any]]
) -> None:
    """With --replay-value a row per setting and candidate: the truth is the plain run's
    (the same seeds), the approximation is the replay's value less the truth, and the
    estimator's error is against the replay's value; printed and in whatif.md. Without it,
    nothing of the kind."""
    _, _, plain = study
    assert plain["approximation"] == []
    assert plain["run"]["replay_value"] is False
    done = run(tmp_path, "--replay-value")
    assert done.exit_code == 0, done.output
    summary = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    assert summary["run"]["replay_value"] is True
    rows = summary["approximation"]
    assert {(r["episodes"], r["arm"]) for r in rows} == {(k, c) for k in SIZES for c in CANDIDATES}
    truths = {
        (c["episodes"], c["arm"]): c["truth"]
        for c in plain["cells"]
        if c["estimator"] == "wpdis" and c["interval"] == "bootstrap"
    }
    for r in rows:
        assert r["trials"] == 3
        assert r["truth"] == pytest.approx(truths[(r["episodes"], r["arm"])], abs=1e-3)
        assert r["approximation"] == pytest.approx(r["replay_value"] - r["truth"], abs=2e-3)
        assert 0 <= r["answered"] <= 3
        if r["answered"]:
            assert r["estimator_error"] is not None
            assert 0.0 <= r["covers_replay_value"] <= 1.0
            assert r["answered_truth"] is not None
            assert r["answered_replay_value"] is not None
            if r["answered"] == r["trials"]:  # the same trials: the same means
                assert r["answered_truth"] == pytest.approx(r["truth"], abs=1e-3)
                assert r["answered_replay_value"] == pytest.approx(r["replay_value"], abs=1e-3)
        else:
            assert r["estimator_error"] is None
            assert r["answered_truth"] is None
    text = (tmp_path / "whatif.md").read_text(encoding="utf-8")
    assert "## The replay's approximation" in text
    assert "replay value" in done.stdout
    assert "not the default run" in done.stdout
