"""The robustness suite's numbers: windows, shares of the oracle's reward, intervals over seeds,
and the table, CSV and plot made of them, on hand-made runs."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from app.experiments.robustness import (
    CSV_COLUMNS,
    MIN_ORACLE_REWARD,
    WINDOWS,
    build_summary,
    markdown,
    run_robust_task,
    tasks_for,
    window_range,
    write_report,
)
from app.experiments.runner import run_tasks
from app.experiments.statistics import mean_ci95, t95
from app.learning.population import FamilyRun, change_event

W = {w.key: w for w in WINDOWS}
INFO = {
    "seeds": 3,
    "persons": 2,
    "events": 160,
    "change_at_event": 101,
    "seconds": 1.0,
    "workers": 1,
}


class TestWindows:
    def test_the_windows_around_the_change(self) -> None:
        at = change_event(160)
        assert window_range(W["first20"], 160, at) == (0, 20)
        assert window_range(W["before30"], 160, at) == (70, 100)
        assert window_range(W["after15"], 160, at) == (100, 115)
        assert window_range(W["last30"], 160, at) == (130, 160)
        assert window_range(W["all"], 160, at) == (0, 160)

    def test_no_change_no_window_about_it(self) -> None:
        assert window_range(W["before30"], 160, None) is None
        assert window_range(W["after15"], 160, None) is None
        assert window_range(W["last30"], 160, None) == (130, 160)

    def test_short_runs_clip_the_windows(self) -> None:
        for w in WINDOWS:
            rng = window_range(w, 24, change_event(24))
            assert rng is not None
            assert 0 <= rng[0] < rng[1] <= 24


class TestIntervals:
    def test_t_quantiles_fall_towards_the_normal(self) -> None:
        values = [t95(df) for df in (1, 2, 5, 10, 30, 40, 100, 5000)]
        assert values == sorted(values, reverse=True)
        assert values[-1] == pytest.approx(1.96)

    def test_mean_and_interval(self) -> None:
        stats = mean_ci95([0.5, 0.6, 0.7, float("nan")])
        assert stats is not None
        mean, low, high = stats
        assert mean == pytest.approx(0.6)
        assert low < mean < high
        assert high - mean == pytest.approx(mean - low)
        assert mean_ci95([float("nan")]) is None
        assert mean_ci95([0.4]) == (0.4, 0.4, 0.4)


def fake_run(
    family: str, seed: int, oracle: float, shares: dict[str, float], change: bool
) -> FamilyRun:
    """Two persons, 160 events: the oracle earns ``oracle`` per event, a learner ``share`` of
    it."""
    o = np.full((2, 160), oracle)
    return FamilyRun(
        family,
        seed,
        o,
        {k: o * v for k, v in shares.items()},
        change_event(160) if change else None,
    )


class TestSummary:
    def runs(self) -> list[FamilyRun]:
        out = []
        for seed, (a, b) in enumerate([(0.4, 0.8), (0.5, 0.9), (0.6, 1.0)]):
            out.append(fake_run("paper", seed, 4.0, {"A": a, "B": b}, change=True))
            out.append(fake_run("shy", seed, 4.0, {"A": a, "B": b}, change=False))
        return out

    def test_shares_means_and_blank_windows(self) -> None:
        summary = build_summary(self.runs(), ["paper", "shy"], ["A", "B"], 160, INFO)
        paper, shy = summary["families"]["paper"], summary["families"]["shy"]
        for w in WINDOWS:
            a, b = paper["learners"]["A"][w.key], paper["learners"]["B"][w.key]
            assert a["applicable"]
            assert a["mean"] < b["mean"]
            assert a["ci95"][0] <= a["mean"] <= a["ci95"][1]
            assert a["seeds"] == 3
            assert a["per_seed"] == pytest.approx([0.4, 0.5, 0.6])
            blank = shy["learners"]["A"][w.key]
            assert blank["applicable"] is not w.needs_change
            if w.needs_change:
                assert blank["mean"] is None
                assert blank["ci95"] is None
        assert paper["change_at_event"] == 101
        assert shy["change_at_event"] is None

    def test_a_seed_whose_oracle_earns_nothing_has_no_share(self) -> None:
        runs = self.runs()
        runs.append(
            fake_run("paper", 3, MIN_ORACLE_REWARD / 1000, {"A": 50.0, "B": 1.0}, change=True)
        )
        summary = build_summary(runs, ["paper"], ["A", "B"], 160, {**INFO, "seeds": 4})
        cell = summary["families"]["paper"]["learners"]["A"]["all"]
        assert cell["undefined_seeds"] == 1
        assert cell["seeds"] == 3
        assert cell["per_seed"][3] is None
        assert cell["mean"] < 1.0  # the 50x of the empty seed is left out
        assert "without a share" in markdown(summary)

    def test_the_files(self, tmp_path: Path) -> None:
        summary = build_summary(self.runs(), ["paper", "shy"], ["A", "B"], 160, INFO)
        files = write_report(summary, tmp_path)
        assert [f.name for f in files] == [
            "robustness.md",
            "robustness.csv",
            "robustness.png",
            "summary.json",
        ]
        assert all(f.stat().st_size > 0 for f in files)
        assert files[2].read_bytes().startswith(b"\x89PNG")
        with files[1].open(encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
        assert tuple(rows[0]) == CSV_COLUMNS
        assert len(rows) == 2 * 2 * len(WINDOWS)
        for row in rows:
            blank = row["family"] == "shy" and W[row["window"]].needs_change
            assert (row["share_mean"] == "") is blank
        table = files[0].read_text(encoding="utf-8")
        for family in ("paper", "shy"):
            assert f"**{family}**" in table
        shy_row = next(line for line in table.splitlines() if line.startswith("| **shy** |"))
        assert "|  |  |" in shy_row  # the two windows about the change, blank


def test_tasks_run_the_same_in_workers_and_here() -> None:
    from app.experiments.robustness import LEARNERS

    tasks = tasks_for(["shy", "abrupt"], [LEARNERS["qlearning"], LEARNERS["hri"]], 2, 1, 30)
    pooled = run_tasks(run_robust_task, tasks, 2, progress=False)
    local = run_tasks(run_robust_task, tasks, 1, progress=False)
    assert [(r.family, r.seed) for r in pooled] == [(t.family, t.seed) for t in tasks]
    for a, b in zip(pooled, local, strict=True):
        assert np.array_equal(a.oracle, b.oracle)
        for label in a.learners:
            assert np.array_equal(a.learners[label], b.learners[label])
    assert math.isfinite(float(pooled[0].oracle.sum()))
