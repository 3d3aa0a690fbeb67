"""The newcomers study's numbers: windows, shares fresh and from the prior, the paired
difference, the targets at their bounds, and the table and CSV made of them, on hand-made runs."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.experiments.newcomers import (
    CSV_COLUMNS,
    WINDOWS,
    NewcomerRun,
    build_summary,
    markdown,
    span_range,
    write_csv,
)
from app.experiments.statistics import mean_ci95

W = {w.key: w for w in WINDOWS}
EVENTS = 160
LABEL = "L"


def info(seeds: int = 3) -> dict[str, Any]:
    return {
        "seeds": seeds,
        "residents": 2,
        "events": EVENTS,
        "strength": 4.0,
        "min_support": 3,
        "seconds": 1.0,
        "workers": 1,
    }


def run(
    family: str,
    seed: int,
    fresh: float,
    prior: float,
    *,
    oracle: float = 1.0,
    prior_after100: float | None = None,
) -> NewcomerRun:
    """Two residents; every event the oracle earns ``oracle``, the learner ``fresh`` or
    ``prior`` times as much (``prior_after100`` from event 101 on, when given)."""
    o = np.full((2, EVENTS), oracle)
    p = prior * o
    if prior_after100 is not None:
        p[:, 100:] = prior_after100 * oracle
    return NewcomerRun(family, seed, o, {LABEL: fresh * o}, {LABEL: p})


def targets(summary: dict[str, Any]) -> dict[tuple[str, str, str], bool]:
    return {(t["id"], t["family"], t["window"]): t["met"] for t in summary["targets"]}


class TestWindows:
    def test_the_windows(self) -> None:
        assert span_range(W["first20"], 160) == (0, 20)
        assert span_range(W["early"], 160) == (20, 100)
        assert span_range(W["after100"], 160) == (100, 160)
        assert span_range(W["all"], 160) == (0, 160)

    def test_a_short_run_has_no_window_after_100(self) -> None:
        assert span_range(W["early"], 60) == (20, 60)
        assert span_range(W["after100"], 100) is None
        assert span_range(W["first20"], 10) == (0, 10)


class TestShares:
    def test_shares_differences_and_intervals(self) -> None:
        runs = [run("home", s, fresh=0.2 + 0.1 * s, prior=0.7 + 0.05 * s) for s in range(3)]
        summary = build_summary(runs, ["home"], [LABEL], EVENTS, info())
        cells = summary["families"]["home"]["learners"][LABEL]
        fresh = cells["fresh"]["first20"]
        assert fresh["per_seed"] == pytest.approx([0.2, 0.3, 0.4])
        assert cells["prior"]["all"]["per_seed"] == pytest.approx([0.7, 0.75, 0.8])
        diff = cells["difference"]["first20"]
        assert diff["per_seed"] == pytest.approx([0.5, 0.45, 0.4])
        stats = mean_ci95([0.5, 0.45, 0.4])
        assert stats is not None
        assert diff["mean"] == pytest.approx(stats[0])
        assert diff["ci95"] == pytest.approx([stats[1], stats[2]], abs=1e-4)
        assert cells["curves"]["prior"][50] == pytest.approx(0.75)
        assert len(cells["curves"]["fresh"]) == EVENTS

    def test_a_seed_whose_oracle_earned_nothing_has_no_share(self) -> None:
        # below MIN_ORACLE_REWARD (robustness suite): that seed is left out of the cell
        runs = [run("home", 0, 0.5, 0.9), run("home", 1, 0.5, 0.9, oracle=0.0)]
        summary = build_summary(runs, ["home"], [LABEL], EVENTS, info(2))
        cell = summary["families"]["home"]["learners"][LABEL]["prior"]["first20"]
        assert cell["seeds"] == 1
        assert cell["undefined_seeds"] == 1
        assert cell["per_seed"][1] is None


class TestTargets:
    @pytest.mark.parametrize(("share", "met"), [(0.80, True), (0.7951, True), (0.79, False)])
    def test_home_first_20_is_decided_in_whole_percentages(self, share: float, met: bool) -> None:
        runs = [run("home", s, 0.2, share) for s in range(3)]
        summary = build_summary(runs, ["home"], [LABEL], EVENTS, info())
        assert targets(summary)[("a", "home", "first20")] is met

    def test_not_below_fresh_is_the_paired_intervals_upper_bound(self) -> None:
        # A loss of 5 points in every seed: the interval excludes 0 -> missed.
        lost = [run("individual", s, 0.6 + 0.1 * s, 0.55 + 0.1 * s) for s in range(3)]
        # Losses that vary in sign across seeds: the interval reaches 0 -> met.
        mixed = [run("individual", s, 0.6, p) for s, p in enumerate((0.5, 0.65, 0.62))]
        for runs, met in ((lost, False), (mixed, True)):
            summary = build_summary(runs, ["individual"], [LABEL], EVENTS, info())
            decided = targets(summary)
            assert decided[("b", "individual", "first20")] is met
            assert decided[("b", "individual", "all")] is met
            assert decided[("c", "individual", "after100")] is met
            assert ("a", "home", "first20") not in decided

    def test_a_loss_after_100_misses_c_only(self) -> None:
        runs = [run("home", s, 0.5, 0.9, prior_after100=0.4 + 0.01 * s) for s in range(3)]
        summary = build_summary(runs, ["home"], [LABEL], EVENTS, info())
        assert targets(summary) == {
            ("a", "home", "first20"): True,
            ("c", "home", "after100"): False,
        }
        text = markdown(summary)
        assert "1 of 2 met" in text
        assert text.count("MISSED") == 1


def test_the_csv_has_a_row_per_family_learner_start_and_window(tmp_path: Path) -> None:
    runs = [run(f, s, 0.3, 0.6) for f in ("home", "individual") for s in range(2)]
    summary = build_summary(runs, ["home", "individual"], [LABEL], EVENTS, info(2))
    rows = write_csv(summary, tmp_path / "n.csv")
    with (tmp_path / "n.csv").open(encoding="utf-8") as handle:
        records = list(csv.DictReader(handle))
    assert tuple(records[0]) == CSV_COLUMNS
    assert rows == len(records) == 2 * 1 * 3 * len(WINDOWS)
    diff = next(r for r in records if r["start"] == "difference" and r["window"] == "all")
    assert float(diff["mean"]) == pytest.approx(0.3)
