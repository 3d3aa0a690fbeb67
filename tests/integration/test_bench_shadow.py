"""The shadow benchmark (bench/shadow.py) runs end to end with tiny numbers on SQLite, so that it
cannot rot unnoticed: its JSON has both phases, the shadow stored decisions, and its figures agree
with one another. No timing is checked (the bound is reported, met or missed, not asserted)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"
PEOPLE = 6
RATE = 30  # robot requests a second
WARMUP = 1  # seconds of load before each window
ROUNDS = 2  # the two phases twice, in turn

pytestmark = pytest.mark.live


def test_the_benchmark_runs_on_sqlite() -> None:
    done = subprocess.run(
        [
            sys.executable,
            str(BENCH / "shadow.py"),
            "--engine",
            "sqlite",
            "--people",
            str(PEOPLE),
            "--history",
            "2",
            "--rate",
            str(RATE),
            "--seconds",
            "3",
            "--warmup",
            str(WARMUP),
            "--keys",
            "2",
            "--rounds",
            str(ROUNDS),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    doc = json.loads(done.stdout)
    assert doc["reference"] == "no shadow"
    assert doc["shadow_seconds"] == 1
    assert doc["rounds"] == ROUNDS
    assert list(doc["engines"]) == ["sqlite"]
    found = doc["engines"]["sqlite"]
    assert found["workers"] == 1

    # The history went through the API: every person's episodes, each a start and its outcomes.
    fill = found["fill"]
    assert fill["people"] == PEOPLE
    assert fill["episodes"] == 2 * PEOPLE
    assert fill["requests"] >= fill["episodes"]
    assert fill["requests_per_episode"] == pytest.approx(fill["requests"] / fill["episodes"])
    # The first warm-up's requests per episode set the windows' episode rate: a start, and at
    # most eight outcomes.
    assert 1 <= found["requests_per_episode"] <= 9

    # Both phases, the reference first, each with its robots' requests answered in each round.
    phases = found["phases"]
    assert list(phases) == ["no shadow", "shadow"]
    for phase in phases.values():
        assert phase["windows"] == ROUNDS
        assert phase["requests"] > 0
        assert phase["episodes"] > 0
        assert phase["errors"] == 0
        assert phase["offered_rps"] == RATE
        assert 0 < phase["p50_ms"] <= phase["p99_ms"] <= phase["max_ms"]
        assert phase["rps"] == pytest.approx(phase["requests"] / phase["seconds"])
        assert phase["cpu_ms_per_request"] > 0
        assert phase["database_cpu_ms_per_request"] is None  # SQLite: no database server
        if phase["pass_cpu_ms_per_request"] is not None:  # py-spy found the pass's thread
            assert 0 <= phase["pass_cpu_ms_per_request"] <= phase["cpu_ms_per_request"]
            assert 0 <= phase["pass_cpu_share"] <= 1
    reference, shadowed = phases["no shadow"], phases["shadow"]
    assert reference["decisions"] is None
    assert shadowed["decisions"] > 0
    assert shadowed["decisions_per_s"] == pytest.approx(shadowed["decisions"] / shadowed["seconds"])

    # A shadow each round decided, for the fleet's people, once the pass caught up: at least
    # what it had stored in its window, and at most a decision for each request the robots made
    # after it started (the window's, and the warm-up's: about RATE * WARMUP, twice that here).
    shadow = found["shadow"]
    assert shadow["candidate"] == "dts"
    assert shadow["share"] == 1.0
    rounds = shadow["rounds"]
    assert len(rounds) == ROUNDS
    assert len({r["shadow_id"] for r in rounds}) == ROUNDS
    assert all(r["decisions"] > 0 for r in rounds)
    assert shadow["decisions"] == sum(r["decisions"] for r in rounds)
    assert shadow["decisions"] >= shadowed["decisions"] > 0
    assert shadow["decisions"] <= shadowed["requests"] + ROUNDS * 2 * RATE * WARMUP
    assert 0 < shadow["people"] <= PEOPLE
    assert 0 <= shadow["agreement"] <= 1
    if shadow["pass_cpu_ms_per_decision"] is not None:
        assert shadow["pass_cpu_ms_per_decision"] > 0

    # The ratios and the bound are those of the two phases' figures.
    ratios = found["ratios"]
    assert ratios["p50"] == pytest.approx(shadowed["p50_ms"] / reference["p50_ms"])
    assert ratios["p99"] == pytest.approx(shadowed["p99_ms"] / reference["p99_ms"])
    assert ratios["cpu_per_request"] == pytest.approx(
        shadowed["cpu_ms_per_request"] / reference["cpu_ms_per_request"]
    )
    assert found["cpu_ms_per_request_added"] == pytest.approx(
        shadowed["cpu_ms_per_request"] - reference["cpu_ms_per_request"]
    )
    bound = found["bound"]
    limit = min(1.5 * reference["p99_ms"], reference["p99_ms"] + 10.0)
    assert bound["limit_ms"] == pytest.approx(limit)
    assert bound["p99_ms"] == shadowed["p99_ms"]
    assert bound["met"] == (shadowed["p99_ms"] <= limit)
    assert not math.isnan(bound["limit_ms"])
