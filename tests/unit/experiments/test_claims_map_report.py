"""The claims map's jobs and reports: each run once, the default world run as `attune experiment
paper` runs it, and the table, CSV and plot made of a hand-made map."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from app.experiments.claims_map import (
    MAX_CONFIRMED,
    PROTOCOLS,
    build_summary,
    confirmed_settings,
    markdown,
    plan,
    write_report,
)
from app.learning.claims_map import AXES, ClaimMap, Grid, Setting

INFO = {
    "seeds": 2,
    "users": 6,
    "runs": 10,
    "worlds": 1,
    "seconds": 1.0,
    "workers": 1,
    "load_average": 0.5,
    "confirm_seeds": 3,
    "confirm_first_seed": 2,
    "confirm_runs": 4,
}
CLAIMS = [("a", "claim a"), ("b", "claim b"), ("c", "claim c")]


class TestPlan:
    def test_every_run_once_and_nothing_more(self) -> None:
        values = {a.key: (a.default,) for a in AXES}
        grid = Grid(
            {**values, "time_slots": (2, 4), "m": (1, 2), "exclusion": ("per_pair", "none")}
        )
        todo = plan(grid.settings(), range(3), users=2)
        jobs = [job for _, job in todo]
        assert len(todo) == len(grid.worlds()) * len(grid.methods()) * len(PROTOCOLS) * 3
        assert len({(key, job.protocol.name, job.seed) for key, job in todo}) == len(todo)
        assert {job.n_users for job in jobs} == {2}
        default = Setting.default().world()
        for key, job in todo:
            if key[0] == default:  # the office mission, as `attune experiment paper` runs it
                assert job.mission is None
            else:
                assert job.mission is not None
                assert len(json.loads(job.mission)["time_slots"]) == key[0].time_slots

    def test_held_out_seeds_are_the_ones_asked(self) -> None:
        todo = plan([Setting.default()], range(5, 7), users=1)
        assert {job.seed for _, job in todo} == {5, 6}
        assert len(todo) == 4 * len(PROTOCOLS) * 2  # the paper's four methods


def _map() -> ClaimMap:
    return ClaimMap(
        CLAIMS,
        {
            Setting.default(): [True, False, False],
            Setting.of(m=1): [True, True, False],
            Setting.of(m=4, noise=0.0): [True, True, True],
            Setting.of(m=4): [False, False, False],
        },
    )


class TestReport:
    def test_confirms_the_default_and_the_best(self) -> None:
        chosen = confirmed_settings(_map())
        assert chosen[0] == Setting.default()
        assert chosen[1] == Setting.of(m=4, noise=0.0)
        assert len(chosen) <= MAX_CONFIRMED + 1

    def test_summary_table_and_csv(self, tmp_path: Path) -> None:
        claim_map = _map()
        confirmed = ClaimMap(
            CLAIMS,
            {
                Setting.default(): [True, False, False],
                Setting.of(m=4, noise=0.0): [True, True, False],
            },
            {Setting.default(): ["x"] * 3, Setting.of(m=4, noise=0.0): ["y"] * 3},
        )
        summary = build_summary(claim_map, confirmed, Grid.full(), INFO)
        assert [c["share"] for c in summary["claims"]] == [0.75, 0.5, 0.25]
        assert summary["default"]["held"] == 1
        assert [b["held"] for b in summary["best"]] == [3]
        assert summary["histogram"] == [1, 1, 1, 1]
        assert summary["confirmation"]["seeds"] == [2, 4]
        text = markdown(summary)
        assert "| **claims that hold** |  | **1** | **3** | **1** | **2** |" in text
        assert "best 1, held-out seeds" in text
        assert "1. reading: noise=0, m=4" in text
        files = write_report(summary, tmp_path)
        assert [f.name for f in files] == [
            "claims-map.md",
            "claims-map.csv",
            "claims-map.png",
            "summary.json",
        ]
        with files[1].open(encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
        assert [r["label"] for r in rows] == [s.label() for s in claim_map.settings]
        assert [int(r["held"]) for r in rows] == [1, 2, 3, 0]
        assert files[2].read_bytes().startswith(b"\x89PNG")

    def test_a_missing_axis_value_is_refused(self) -> None:
        with pytest.raises(KeyError, match="gamma is not an axis"):
            Setting.default()["gamma"]
