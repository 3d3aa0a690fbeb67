"""The experiment command line, its parallel runner and its reports, on tiny runs."""

from __future__ import annotations

import csv
import json
import struct
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import app
from app.experiments.outputs import CSV_COLUMNS
from app.experiments.runner import Job, jobs_for, run_jobs
from app.experiments.statistics import cumulative_curve
from app.learning.evaluation import ABLATION_METHODS, E3, PA, PAPER_METHODS, RunResult

# The module's shared run is made once: every test of the module on one worker.
pytestmark = pytest.mark.xdist_group("experiment-report")

SEEDS, USERS = 1, 2
EVENTS = {"e1e2": 100, "e3": 100, "pa": 200}
RATES = ("interaction_rate", "success_rate", "success_rate_engaged")
PAPER_FILES = ("fig2.png", "fig3.png", "rewards.csv", "table2.md", "summary.json", "claims.md")


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """``attune experiment paper`` on one seed and two users, once for the module."""
    out = tmp_path_factory.mktemp("paper")
    result = CliRunner().invoke(
        app,
        [
            "experiment",
            "paper",
            "--seeds",
            str(SEEDS),
            "--users",
            str(USERS),
            "--jobs",
            "1",
            "--out",
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    return out, result.output


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from a PNG's header; fails if the file is not a PNG."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    return int(width), int(height)


def test_paper_writes_every_file_and_says_where(paper_run: tuple[Path, str]) -> None:
    out, output = paper_run
    for name in PAPER_FILES:
        assert (out / name).is_file(), name
        assert str(out / name) in output.replace("\n", "")
    assert "15 runs" in output
    assert "Table II" in output


def test_rewards_csv_has_one_row_per_event(paper_run: tuple[Path, str]) -> None:
    with (paper_run[0] / "rewards.csv").open(encoding="utf-8", newline="") as handle:
        rows = list(csv.DictReader(handle))
        assert tuple(rows[0]) == CSV_COLUMNS
    n_methods = len(PAPER_METHODS)
    assert len(rows) == n_methods * SEEDS * USERS * sum(EVENTS.values())
    per_protocol = Counter(row["protocol"] for row in rows)
    assert per_protocol == {p: n_methods * SEEDS * USERS * n for p, n in EVENTS.items()}
    assert {row["method"] for row in rows} == {m.label for m in PAPER_METHODS}
    assert {row["interaction"] for row in rows} <= {"none", "I1", "I2", "I3"}
    assert {row["initiated"] for row in rows} | {row["success"] for row in rows} <= {"0", "1"}
    events = sorted({int(row["event"]) for row in rows if row["protocol"] == "pa"})
    assert events == list(range(1, 201))
    assert all(np.isfinite(float(row["reward"])) for row in rows)


def test_figures_are_1000_by_600_pngs(paper_run: tuple[Path, str]) -> None:
    for name in ("fig2.png", "fig3.png"):
        assert png_size(paper_run[0] / name) == (1000, 600)
        assert (paper_run[0] / name).stat().st_size > 20_000


def test_table2_mentions_every_method_and_the_paper(paper_run: tuple[Path, str]) -> None:
    text = (paper_run[0] / "table2.md").read_text(encoding="utf-8")
    for method in PAPER_METHODS:
        assert f"| {method.label} |" in text
    for target in ("49.92%", "71.48%", "76.5%", "72.5%", "0.79", "80.5%", "72.04%", "1.095"):
        assert target in text
    assert "| 101-200 |" in text


def test_summary_json_rates_are_fractions(paper_run: tuple[Path, str]) -> None:
    summary: dict[str, Any] = json.loads((paper_run[0] / "summary.json").read_text("utf-8"))
    assert summary["methods"] == [m.label for m in PAPER_METHODS]
    assert summary["run"]["runs"] == len(PAPER_METHODS) * len(EVENTS) * SEEDS
    assert set(summary["protocols"]["pa"]["blocks"]) == {"1-200", "1-100", "101-200"}
    checked = 0
    for protocol in summary["protocols"].values():
        for block in protocol["blocks"].values():
            assert set(block) == {m.label for m in PAPER_METHODS}
            for metrics in block.values():
                for key in RATES:
                    mean, std = metrics[key]["mean"], metrics[key]["std"]
                    if mean is not None:
                        assert 0.0 <= mean <= 1.0
                        assert 0.0 <= std <= 1.0
                        checked += 1
    assert checked > 0
    assert summary["curves"]["fig3"]["events"] == list(range(51, 101))
    assert len(summary["claims"]) >= 10
    assert all(isinstance(c["reproduced"], bool) and c["evidence"] for c in summary["claims"])
    claims_md = (paper_run[0] / "claims.md").read_text(encoding="utf-8")
    assert claims_md.count("\n- ") == len(summary["claims"])


def test_ablation_writes_its_table(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        [
            "experiment",
            "ablation",
            "--seeds",
            "1",
            "--users",
            "1",
            "--jobs",
            "1",
            "--out",
            str(tmp_path),
            "--no-progress",
        ],
    )
    assert result.exit_code == 0, result.output
    text = (tmp_path / "ablation.md").read_text(encoding="utf-8")
    for method in ABLATION_METHODS:
        assert f"| {method.label} |" in text
    summary = json.loads((tmp_path / "summary.json").read_text("utf-8"))
    assert set(summary["protocols"]) == {E3.name, PA.name}
    assert png_size(tmp_path / "pa_cumulative.png") == (1000, 600)
    assert (tmp_path / "rewards.csv").is_file()


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        ([], "experiment"),
        (["experiment"], "paper"),
        (["experiment", "paper"], "table2.md"),
        (["experiment", "ablation"], "ablation.md"),
    ],
)
def test_help_at_every_level(args: list[str], expected: str) -> None:
    result = CliRunner().invoke(app, [*args, "--help"])
    assert result.exit_code == 0, result.output
    assert expected in result.output


def test_pool_returns_the_in_process_results_in_job_order() -> None:
    jobs = jobs_for(PAPER_METHODS[:2], [E3, PA], seeds=2, n_users=1)
    pooled = run_jobs(jobs, workers=2, progress=False)
    local = run_jobs(jobs, workers=1, progress=False)
    assert [(r.method, r.protocol, r.seed) for r in pooled] == [
        (j.method.label, j.protocol.name, j.seed) for j in jobs
    ]
    for a, b in zip(pooled, local, strict=True):
        np.testing.assert_array_equal(a.reward, b.reward)
        np.testing.assert_array_equal(a.interaction, b.interaction)


def test_run_jobs_rejects_no_workers() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        run_jobs([Job(PAPER_METHODS[0], E3, 0, 1)], workers=0, progress=False)


def test_cumulative_curve_re_zeroes_at_the_block_start() -> None:
    def result(rewards: list[list[float]]) -> RunResult:
        reward = np.asarray(rewards)
        zeros = np.zeros_like(reward, dtype=bool)
        return RunResult(
            "m", "e1e2", 0, reward, zeros, zeros.astype(np.int8), zeros, zeros.astype(np.int64)
        )

    results = [result([[5.0, 1.0, 2.0], [5.0, 3.0, 4.0]])]
    mean, half = cumulative_curve(results, "m", 1, 3)
    np.testing.assert_allclose(mean, [2.0, 5.0])
    np.testing.assert_allclose(half, 1.96 * np.asarray([np.sqrt(2), 2 * np.sqrt(2)]) / np.sqrt(2))


def test_user_overrides_reach_the_simulated_users(tmp_path: Path) -> None:
    base = [
        "experiment",
        "ablation",
        "--seeds",
        "1",
        "--users",
        "1",
        "--jobs",
        "1",
        "--no-progress",
    ]
    shy = CliRunner().invoke(app, [*base, "--out", str(tmp_path / "shy"), "--user", "p_self=0"])
    assert shy.exit_code == 0, shy.output
    summary = json.loads((tmp_path / "shy" / "summary.json").read_text("utf-8"))
    assert summary["run"]["user_params"] == {"p_self": 0.0}
    with (tmp_path / "shy" / "rewards.csv").open(encoding="utf-8") as f:
        classes = {row["interaction"] for row in csv.DictReader(f)}
    assert "I1" not in classes  # a person who never speaks first makes no I1 episode


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("p_self", "expected NAME=VALUE"),
        ("mood=0.5", "p_acc, p_self"),
        ("p_acc=2", "[0, 1]"),
        ("eps_fb=x", "[0, 1]"),
    ],
)
def test_bad_user_overrides_are_refused(tmp_path: Path, value: str, words: str) -> None:
    result = CliRunner().invoke(
        app,
        [
            "experiment",
            "paper",
            "--seeds",
            "1",
            "--out",
            str(tmp_path),
            "--user",
            value,
        ],
    )
    assert result.exit_code == 2
    assert words in " ".join(result.output.split())
    assert not any(tmp_path.iterdir())
