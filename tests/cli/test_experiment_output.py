"""What ``attune experiment paper|ablation`` print when the output is not a terminal: whole
tables (no cell cut or wrapped at the terminal's width) or, with ``--json``, the summary as
the only thing on stdout; messages and progress go to stderr."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from app.cli import app

# The module's shared run is made once: every test of the module on one worker.
pytestmark = pytest.mark.xdist_group("experiment-output")

NARROW = {"COLUMNS": "40"}  # what a narrow terminal would cut, a pipe must not


def run(command: str, out: Path, *extra: str) -> Result:
    done = CliRunner(env=NARROW).invoke(
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
            *extra,
        ],
    )
    assert done.exit_code == 0, done.output
    return done


@pytest.fixture(scope="module")
def paper(tmp_path_factory: pytest.TempPathFactory) -> tuple[Result, dict[str, Any]]:
    out = tmp_path_factory.mktemp("paper")
    done = run("paper", out)
    return done, json.loads((out / "summary.json").read_text(encoding="utf-8"))


def test_paper_table_is_whole(paper: tuple[Result, dict[str, Any]]) -> None:
    done, summary = paper
    lines = done.stdout.splitlines()
    assert any("Table II (E3) — reproduced vs paper" in line for line in lines)
    for method in summary["methods"]:  # one row per method, its name whole, its numbers beside
        row = next(line for line in lines if line.startswith(method + " "))
        assert row.count("±") == 5, row
    for claim in summary["claims"]:  # each claim whole on its own line
        assert any(line.endswith(claim["text"]) for line in lines), claim["text"]
    assert "Wrote 6 files" in done.stderr  # messages on stderr, not between the tables
    assert "Wrote" not in done.stdout
    assert "runs" not in done.stdout


def test_paper_json_is_the_summary_and_nothing_else(tmp_path: Path) -> None:
    done = run("paper", tmp_path, "--json")
    printed = json.loads(done.stdout)
    assert printed == json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))
    assert {"methods", "claims", "protocols"} <= set(printed)
    assert "Wrote 6 files" in done.stderr


def test_ablation_table_and_json(tmp_path: Path) -> None:
    done = run("ablation", tmp_path / "table")
    summary = json.loads((tmp_path / "table" / "summary.json").read_text(encoding="utf-8"))
    lines = done.stdout.splitlines()
    assert any("Ablations on E3" in line for line in lines)
    for method in summary["methods"]:
        row = next(line for line in lines if line.startswith(method + " "))
        assert row.count("±") == 5, row
    as_json = run("ablation", tmp_path / "json", "--json")
    assert json.loads(as_json.stdout)["methods"] == summary["methods"]
    assert "Wrote 4 files" in as_json.stderr
