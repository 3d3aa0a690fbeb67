"""The evaluation benchmark (bench/evaluation.py) runs end to end with tiny numbers on each engine
(the PostgreSQL path has its own database, VACUUM and size), so that it cannot rot unnoticed: its
JSON has the figures the docs quote, and its counts agree with one another. No timing is
checked."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"
STEPS = 500

pytestmark = pytest.mark.live


@pytest.mark.parametrize("engine", ["sqlite", "postgresql"])
def test_the_benchmark_runs(engine: str) -> None:
    done = subprocess.run(
        [
            sys.executable,
            str(BENCH / "evaluation.py"),
            "--engine",
            engine,
            "--steps",
            str(STEPS),
            "--template-people",
            "4",
            "--template-episodes",
            "60",
            "--template-robots",
            "2",
            "--tracemalloc",
            "--max-minutes",
            "8",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    doc = json.loads(done.stdout)
    assert doc["steps_requested"] == STEPS
    assert doc["candidates"] == ["dts", "hri:tau=0.005"]  # the default two
    found = doc["engines"][engine]
    assert found["stopped"] == ""
    assert found["check"]["ok"], found["check"]
    fill, read, full = found["fill"], found["read"], found["evaluate"]

    # The steps: at least those asked for, as the fill planned them, read as the evaluation
    # reads them; the evaluation counted the same people and episodes, and left no one out.
    assert read["steps"] >= STEPS
    assert read["steps"] == fill["steps_planned"]
    assert 0 < read["episodes"] <= read["steps"]
    assert read["episodes"] <= fill["episodes"]  # the open ones (none here) are not counted
    assert 0 < full["people"] == read["people"] == fill["people"]
    assert full["people_counted"] == read["people_counted"] > 0
    assert full["episodes"] == read["episodes"]
    assert full["people_skipped"] == read["people_skipped"] == 0
    # Cloned people: more than the template's, with the two whose corrections a clone cannot
    # keep left uncloned (bench/retention.py says why).
    assert fill["people"] > fill["template_people"] == 4
    assert set(fill["not_cloned"]) <= {"tpl-000", "tpl-001"}
    assert [c["key"] for c in full["candidates"]] == doc["candidates"]

    # The figures of each process, and the table made of them.
    for run in (read, full, found["traced"]):
        assert run["seconds"] > 0
        assert run["cpu_seconds"] > 0
        assert 0 < run["baseline_rss_bytes"] <= run["peak_rss_bytes"]
    assert 0 <= full["estimators_seconds"] <= full["seconds"]
    assert 0 < full["read_replay_seconds"] <= full["seconds"]
    assert found["traced"]["tracemalloc_peak_bytes"] > 0
    assert found["size"]["bytes"] > 0
    table = found["table"]
    assert [r["run"] for r in table] == ["read only (reference)", "full evaluation"]
    assert [r["candidates"] for r in table] == [0, 2]
    for row in table:
        assert row["steps"] == read["steps"]
        assert row["steps_per_second"] > 0
        assert row["peak_rss_mib"] >= row["baseline_rss_mib"] > 0
