"""The report kit of the experiment commands: what every report is made of, once.

A report is a folder of files (``--out``): a markdown page, a CSV, a PNG and ``summary.json``
(:func:`write_report`, :func:`write_csv`, :func:`write_json`), and a table on the terminal,
printed whole whatever the terminal's width, with plain lines after it (:func:`terminal_table`,
:func:`print_whole`). The suites that measure shares of an oracle's reward (robustness,
newcomers) share their numbers and their words: a seed's share (:func:`share`), a window's
mean and 95 % interval over seeds (:func:`interval_cell`), and the same in text
(:func:`interval_text`, :func:`percent`, :func:`window_heading`). Markdown tables
(:func:`markdown_table`), the canvas of a figure (:func:`figure`) and the numbers written in a
heatmap's cells (:func:`label_cells`) serve every report, the paper's too.

rich is imported here and matplotlib only inside the functions that draw, so that a worker
process, which imports none of this, and ``--help`` stay fast.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .statistics import mean_ci95

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure
    from rich.console import Console
    from rich.table import Table

    from app.learning.types import FloatArray

__all__ = [
    "MIN_ORACLE_REWARD",
    "family_lines",
    "figure",
    "interval_cell",
    "interval_text",
    "label_cells",
    "markdown_table",
    "mission_sentence",
    "oracle_per_event",
    "percent",
    "print_whole",
    "rounded",
    "share",
    "terminal_table",
    "verdict_section",
    "window_heading",
    "write_csv",
    "write_json",
    "write_report",
]

MIN_ORACLE_REWARD = 1.0
"""Below this, the oracle earned (about) nothing in a window: a seed has no share there."""


# -- files --------------------------------------------------------------------------------------


def write_json(data: Mapping[str, Any], path: Path) -> None:
    """``data`` as strict, indented UTF-8 JSON (no NaN: JSON has none)."""
    path.write_text(
        json.dumps(data, indent=2, ensure_ascii=False, allow_nan=False) + "\n", encoding="utf-8"
    )


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[Sequence[object]]) -> int:
    """A CSV file (``\\n`` line ends): the header, then ``rows``; returns the rows written."""
    written = 0
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for row in rows:
            writer.writerow(row)
            written += 1
    return written


Summary = Mapping[str, Any]


def write_report(
    summary: Summary,
    out: Path,
    stem: str,
    *,
    markdown: Callable[[Summary], str],
    table: Callable[[Summary, Path], int],
    plot: Callable[[Summary, Path], None],
) -> list[Path]:
    """Write ``STEM.md``, ``STEM.csv``, ``STEM.png`` and ``summary.json`` into ``out``
    (created if needed); returns them, in that order."""
    out.mkdir(parents=True, exist_ok=True)
    files = [out / f"{stem}.md", out / f"{stem}.csv", out / f"{stem}.png", out / "summary.json"]
    files[0].write_text(markdown(summary), encoding="utf-8")
    table(summary, files[1])
    plot(summary, files[2])
    write_json(summary, files[3])
    return files


# -- numbers ------------------------------------------------------------------------------------


def rounded(x: float | None, digits: int = 4) -> float | None:
    """``x`` rounded for the summary; None for None, NaN and infinities."""
    return None if x is None or not math.isfinite(x) else round(x, digits)


def share(learner: float, oracle: float) -> float:
    """A learner's reward as a share of the oracle's; NaN (no share) when the oracle earned
    less than :data:`MIN_ORACLE_REWARD`."""
    return learner / oracle if oracle >= MIN_ORACLE_REWARD else float("nan")


def interval_cell(values: Sequence[float], events: tuple[int, int]) -> dict[str, Any]:
    """One window's per-seed ``values`` (NaN: undefined) as the summary holds them: its events
    (1-based, inclusive), the mean over the defined seeds, the 95 % interval (Student's t),
    how many seeds it stands on and how many had none, and every seed's value."""
    stats = mean_ci95(values)
    undefined = sum(1 for v in values if not math.isfinite(v))
    return {
        "events": [events[0] + 1, events[1]],
        "mean": None if stats is None else rounded(stats[0]),
        "ci95": None if stats is None else [rounded(stats[1]), rounded(stats[2])],
        "seeds": len(values) - undefined,
        "undefined_seeds": undefined,
        "per_seed": [rounded(v) for v in values],
    }


def oracle_per_event(oracles: Sequence[FloatArray]) -> float | None:
    """The oracle's mean reward per event over runs (their reward arrays), rounded."""
    return rounded(float(np.mean([o.mean() for o in oracles])) if oracles else float("nan"))


# -- words --------------------------------------------------------------------------------------


def percent(x: float) -> str:
    """A share as a whole percentage, without the sign of a negative zero."""
    text = f"{100 * x:.0f}"
    return "0" if text == "-0" else text


def interval_text(cell: Mapping[str, Any], *, signed: bool = False) -> str:
    """``62% [55, 69]``; a difference in points, ``+12 [5, 19]`` (``signed``); ``—`` when no
    seed defines it."""
    if cell["mean"] is None:
        return "—"
    low, high = cell["ci95"]
    if signed:
        sign = "+" if percent(cell["mean"]) != "0" and cell["mean"] > 0 else ""
        return f"{sign}{percent(cell['mean'])} [{percent(low)}, {percent(high)}]"
    return f"{percent(cell['mean'])}% [{percent(low)}, {percent(high)}]"


def window_heading(summary: Summary, key: str) -> str:
    """A window's label with its events: ``first 20 (1–20)``."""
    window = summary["windows"][key]
    events = window["events"]
    return window["label"] if events is None else f"{window['label']} ({events[0]}–{events[1]})"


def mission_sentence(run: Mapping[str, Any]) -> str:
    """The sentence that says the people lived in another mission than the paper's office
    mission (``--mission FILE``); empty for the office mission."""
    mission = run.get("mission") or {}
    if not mission.get("file"):
        return ""
    return (
        f" The people lived in the mission {mission['name']!r} of {mission['file']}, "
        "not in the paper's office mission."
    )


def family_lines(summary: Summary) -> list[str]:
    """The families of a suite's summary, each with its oracle's reward per event, as a
    markdown list under its heading."""
    lines = ["", "Families (oracle's mean reward per event):", ""]
    for name, family in summary["families"].items():
        reward = family["oracle_reward_per_event"]
        shown = "—" if reward is None else f"{reward:.2f}"
        lines.append(f"- **{name}** ({shown}): {family['description']}.")
    return lines


def verdict_section(title: str, verdict: Sequence[str]) -> list[str]:
    """A markdown section of verdict lines: the first a paragraph, the rest a list."""
    return ["", f"## {title}", "", verdict[0], "", *(f"- {line.strip()}" for line in verdict[1:])]


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[str]], *, left: int = 1) -> str:
    """A markdown table: its first ``left`` columns aligned left, the others right."""
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "|".join([":---"] * left + ["---:"] * (len(header) - left)) + "|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


# -- the terminal -------------------------------------------------------------------------------


def terminal_table(title: str) -> Table:
    """A table for the terminal: its title on the left, a rule under the heading."""
    from rich import box
    from rich.table import Table

    return Table(title=title, box=box.SIMPLE_HEAD, title_justify="left")


def print_whole(console: Console, table: Table, lines: Iterable[str] = ()) -> None:
    """Print ``table`` whole (no cell cut or wrapped at the terminal's width), then ``lines``
    as they are (no markup, each on one line)."""
    console.print(table, soft_wrap=True, crop=False, overflow="ignore")
    for line in lines:
        console.print(
            line, soft_wrap=True, crop=False, overflow="ignore", markup=False, highlight=False
        )


# -- figures ------------------------------------------------------------------------------------


def figure(width: float, height: float) -> Figure:
    """A matplotlib figure of ``width`` x ``height`` inches at 100 dpi, laid out by
    matplotlib, on the Agg canvas (no pyplot, no display)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def label_cells(
    ax: Axes, grid: FloatArray, text: Callable[[float], str], *, fontsize: float
) -> None:
    """Write each finite cell's value into a heatmap of ``grid`` (rows x columns), white on the
    dark part of the colour scale (below 0.6), black on the light."""
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            if np.isfinite(grid[i, j]):
                ax.text(
                    j,
                    i,
                    text(float(grid[i, j])),
                    ha="center",
                    va="center",
                    fontsize=fontsize,
                    color="white" if grid[i, j] < 0.6 else "black",
                )
