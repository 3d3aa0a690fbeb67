"""The report kit the experiment reports share: files, tables, shares and their words."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import pytest

from app.experiments import report


def test_a_csv_has_its_header_and_every_row(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    assert report.write_csv(path, ("a", "b"), iter([(1, "x"), (2, "")])) == 2
    assert path.read_bytes() == b"a,b\n1,x\n2,\n"  # \n line ends, an empty cell stays empty
    with path.open(encoding="utf-8") as handle:
        assert list(csv.DictReader(handle)) == [{"a": "1", "b": "x"}, {"a": "2", "b": ""}]


def test_json_is_strict(tmp_path: Path) -> None:
    report.write_json({"share": 0.5, "name": "Lín"}, tmp_path / "s.json")
    text = (tmp_path / "s.json").read_text(encoding="utf-8")
    assert json.loads(text) == {"share": 0.5, "name": "Lín"}
    assert "Lín" in text
    assert text.endswith("\n")
    with pytest.raises(ValueError, match="not JSON compliant"):
        report.write_json({"share": math.nan}, tmp_path / "nan.json")


def test_a_report_is_its_four_files_in_order(tmp_path: Path) -> None:
    summary: dict[str, Any] = {"n": 1}
    written: list[str] = []

    def table(s: Any, path: Path) -> int:
        written.append("csv")
        return report.write_csv(path, ("n",), [(s["n"],)])

    def plot(s: Any, path: Path) -> None:
        written.append("png")
        path.write_bytes(b"\x89PNG")

    files = report.write_report(
        summary, tmp_path / "out", "kit", markdown=lambda s: f"# {s['n']}\n", table=table, plot=plot
    )
    assert [f.name for f in files] == ["kit.md", "kit.csv", "kit.png", "summary.json"]
    assert written == ["csv", "png"]
    assert files[0].read_text(encoding="utf-8") == "# 1\n"
    assert json.loads(files[3].read_text(encoding="utf-8")) == summary


def test_markdown_tables_align_their_leading_columns_left() -> None:
    text = report.markdown_table(["A", "B", "n"], [["x", "", "1"]], left=2)
    assert text.splitlines() == ["| A | B | n |", "|:---|:---|---:|", "| x |  | 1 |"]


def test_a_share_needs_an_oracle_that_earned_something() -> None:
    assert report.share(3.0, 4.0) == 0.75
    assert report.share(1.0, report.MIN_ORACLE_REWARD) == 1.0
    assert math.isnan(report.share(0.5, report.MIN_ORACLE_REWARD - 0.01))


def test_an_interval_cell_stands_on_the_defined_seeds() -> None:
    cell = report.interval_cell([0.5, math.nan, 0.7], (0, 20))
    assert cell["events"] == [1, 20]
    assert cell["seeds"] == 2
    assert cell["undefined_seeds"] == 1
    assert cell["mean"] == pytest.approx(0.6)
    low, high = cell["ci95"]
    assert low < 0.6 < high
    assert cell["per_seed"] == [0.5, None, 0.7]
    nothing = report.interval_cell([math.nan], (0, 5))
    assert nothing["mean"] is None
    assert nothing["ci95"] is None


def test_the_words_of_a_share() -> None:
    assert report.percent(0.624) == "62"
    assert report.percent(-0.001) == "0"  # no "-0"
    cell = {"mean": 0.62, "ci95": [0.55, 0.69]}
    assert report.interval_text(cell) == "62% [55, 69]"
    assert report.interval_text({"mean": 0.12, "ci95": [0.05, 0.19]}, signed=True) == "+12 [5, 19]"
    assert report.interval_text({"mean": -0.001, "ci95": [-0.1, 0.1]}, signed=True) == "0 [-10, 10]"
    assert report.interval_text({"mean": None, "ci95": None}) == "—"
    summary = {
        "windows": {
            "w": {"label": "first 20", "events": [1, 20]},
            "x": {"label": "all", "events": None},
        }
    }
    assert report.window_heading(summary, "w") == "first 20 (1–20)"
    assert report.window_heading(summary, "x") == "all"
    assert report.mission_sentence({"mission": {"file": None}}) == ""
    assert "'care-home' of m.json" in report.mission_sentence(
        {"mission": {"name": "care-home", "file": "m.json"}}
    )
