"""The text of experiment reports: Table II and the ablations as markdown, the paper's claims,
and the same metrics as compact tables for the terminal.

Every cell is ``mean ± std`` over users x seeds (``statistics.SPREAD_LABEL``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rich import box
from rich.console import Console
from rich.table import Table

from app.learning.evaluation import E3, PA

from .report import markdown_table
from .statistics import METRICS, PAPER_TABLE2, SPREAD_LABEL, Metric, Stats

__all__ = [
    "DEFINITIONS",
    "ablation_markdown",
    "claims_markdown",
    "mission_note",
    "print_metrics_table",
    "print_table2",
    "table2_markdown",
]


def _e3_stats(summary: Mapping[str, Any]) -> Stats:
    """The Table II numbers (E3, all events) out of a summary."""
    e3 = summary["protocols"][E3.name]
    stats: Stats = e3["blocks"][f"1-{e3['n_events']}"]
    return stats


def _fmt(stat: Mapping[str, float | None], rate: bool) -> str:
    """``mean ± std``, as percentages for rates; ``—`` when undefined."""
    mean, std = stat.get("mean"), stat.get("std")
    if mean is None or std is None:
        return "—"
    if rate:
        return f"{100 * mean:.1f} ± {100 * std:.1f}%"
    return f"{mean:.2f} ± {std:.2f}"


def _paper(method: str, metric: Metric) -> str:
    """The paper's Table II value for ``method``, or ``—``."""
    value = PAPER_TABLE2.get(method, {}).get(metric.key)
    if value is None:
        return "—"
    return f"{100 * value:.4g}%" if metric.rate else f"{value:g}"


@dataclass(frozen=True)
class Column:
    """A table column after the method: a metric's measured value, or the paper's target."""

    metric: Metric
    paper: bool = False

    @property
    def heading(self) -> str:
        """The column heading."""
        return "paper" if self.paper else self.metric.heading

    def cell(self, method: str, stats: Stats) -> str:
        """The cell text for ``method``."""
        if self.paper:
            return _paper(method, self.metric)
        return _fmt(stats[method][self.metric.key], self.metric.rate)


def _columns(with_paper: bool) -> list[Column]:
    """The metric columns, each followed by the paper's column when asked and known."""
    cols: list[Column] = []
    for metric in METRICS:
        cols.append(Column(metric))
        if with_paper and metric.paper:
            cols.append(Column(metric, paper=True))
    return cols


Row = tuple[Sequence[str], str, Stats]  # leading cells, method, the stats to read


def _markdown_table(rows: Sequence[Row], lead: Sequence[str], with_paper: bool) -> str:
    """A markdown table: ``lead`` columns, then the metric (and paper) columns."""
    cols = _columns(with_paper)
    return markdown_table(
        [*lead, *(c.heading for c in cols)],
        ([*cells, *(c.cell(method, stats) for c in cols)] for cells, method, stats in rows),
        left=len(lead),
    )


def _block_rows(summary: Mapping[str, Any], protocol: str) -> list[Row]:
    """Rows method x block (the phases, or the whole run when there is no change)."""
    blocks: dict[str, Stats] = summary["protocols"][protocol]["blocks"]
    labels = list(blocks)[1:] or list(blocks)
    return [
        ((method, f"{label}"), method, blocks[label])
        for method in summary["methods"]
        for label in labels
    ]


def _plural(n: int, word: str) -> str:
    """``"1 seed"``, ``"2 seeds"``."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def _preamble(summary: Mapping[str, Any]) -> str:
    """How many runs the numbers come from."""
    run = summary["run"]
    runs = f"{_plural(run['seeds'], 'seed')} × {_plural(run['users'], 'simulated user')}"
    return f"{runs} per method; {SPREAD_LABEL}.{mission_note(summary)}"


def mission_note(summary: Mapping[str, Any]) -> str:
    """A sentence naming the mission the simulated users lived in, when it was not the
    paper's office mission (``--mission FILE``); empty otherwise."""
    mission = summary.get("run", {}).get("mission")
    if not mission or mission.get("file") is None:
        return ""
    return (
        f" The simulated users lived in the mission {mission['name']!r} of "
        f"{mission['file']} ({mission['situations']} situations, {mission['time_slots']} "
        f"time slots, {mission['services']} services), not the paper's office mission: "
        "the paper's numbers are not targets for it."
    )


DEFINITIONS = """\
- **Interaction rate**: events where the robot chose to initiate / events.
- **Success rate**: missions (an episode of class I1, I2 or I3) with an accepted service / missions;
  **(I1+I2)**: the same over I1 and I2 missions only (without rejected initiations).
- **Queries / mission**: query actions / missions. **Total reward**: summed over the block's events.
"""


def claims_markdown(summary: Mapping[str, Any]) -> str:
    """The paper's qualitative claims (docs/method.md §13), each reproduced or not, with the
    numbers it was decided on (E1 and E2 from the e1e2 runs, Table II orderings from E3)."""
    lines = [
        "## The paper's claims, checked (docs/method.md §13)",
        "",
        "✓ reproduced by our reconstruction, ✗ not reproduced.",
        "",
    ]
    for claim in summary.get("claims", []):
        mark = "✓" if claim["reproduced"] else "✗"
        lines.append(f"- {mark} **{claim['text']}** {claim['evidence']}.")
    return "\n".join(lines) + "\n"


def table2_markdown(summary: Mapping[str, Any]) -> str:
    """``table2.md``: Table II (E3) beside the paper's targets, the claims checked, and the
    200-event performance analysis (PA) per 100-event block."""
    e3 = summary["protocols"][E3.name]
    stats = _e3_stats(summary)
    parts = [
        "# Table II: E3, reproduced",
        "",
        f"E3: {e3['n_events']} events per user, the users' needs change after event "
        f"{e3['change_after_event']}. {_preamble(summary)} The *paper* columns are the targets "
        "of the paper's Table II (— : not in the paper). The simulator is reconstructed, so "
        "compare orderings rather than exact values.",
        "",
        _markdown_table([((m,), m, stats) for m in summary["methods"]], ["Method"], True),
        "",
        DEFINITIONS,
        claims_markdown(summary),
    ]
    if PA.name in summary["protocols"]:
        pa = summary["protocols"][PA.name]
        parts += [
            "",
            "## Performance analysis (PA): 200 events, per 100-event block",
            "",
            f"{pa['n_events']} events per user, the needs change after event "
            f"{pa['change_after_event']}. {_preamble(summary)}",
            "",
            _markdown_table(_block_rows(summary, PA.name), ["Method", "Events"], False),
        ]
    return "\n".join(parts) + "\n"


def ablation_markdown(summary: Mapping[str, Any]) -> str:
    """``ablation.md``: the metrics of every ablation on E3 and per PA block."""
    parts = [
        "# Ablations of HRI τ=0.01",
        "",
        f"{_preamble(summary)} Each row changes one thing relative to HRI τ=0.01.",
        "",
    ]
    if E3.name in summary["protocols"]:
        e3 = summary["protocols"][E3.name]
        parts += [
            f"## E3: {e3['n_events']} events, needs change after event {e3['change_after_event']}",
            "",
            _markdown_table(
                [((m,), m, _e3_stats(summary)) for m in summary["methods"]], ["Method"], False
            ),
            "",
        ]
    if PA.name in summary["protocols"]:
        parts += [
            "## Performance analysis (PA): 200 events, per 100-event block",
            "",
            _markdown_table(_block_rows(summary, PA.name), ["Method", "Events"], False),
            "",
        ]
    parts.append(DEFINITIONS)
    return "\n".join(parts)


TERMINAL_HEADINGS = {
    "interaction_rate": "Interaction\n%",
    "success_rate": "Success\n%",
    "success_rate_engaged": "Success %\n(I1+I2)",
    "queries_per_mission": "Queries\n/ mission",
    "total_reward": "Total\nreward",
}


def _terminal_cell(method: str, metric: Metric, stats: Stats, with_paper: bool) -> str:
    """A compact cell: mean ± std (rates in %, without the sign), the paper's value below."""
    stat = stats[method][metric.key]
    mean, std = stat.get("mean"), stat.get("std")
    if mean is None or std is None:
        text = "—"
    elif metric.rate:
        text = f"{100 * mean:.1f} ± {100 * std:.1f}"
    else:
        digits = 1 if metric.key == "total_reward" else 2
        text = f"{mean:.{digits}f} ± {std:.{digits}f}"
    target = PAPER_TABLE2.get(method, {}).get(metric.key)
    if with_paper and metric.paper and target is not None:
        paper = f"{100 * target:.4g}" if metric.rate else f"{target:g}"
        text += f"\n[dim]({paper})[/dim]"
    return text


def print_metrics_table(
    stats: Stats, methods: Sequence[str], title: str, console: Console, *, with_paper: bool
) -> None:
    """Print one metrics table (mean ± std per method; with ``with_paper``, the paper's value
    below in brackets) to the terminal, compact enough for 80 columns."""
    caption = SPREAD_LABEL + ("; (in brackets): the paper's Table II" if with_paper else "")
    table = Table(
        title=title,
        title_style="bold",
        caption=caption,
        box=box.SIMPLE_HEAD,
        pad_edge=False,
        show_edge=False,
        collapse_padding=True,
    )
    table.add_column("Method", style="bold", no_wrap=True)
    for metric in METRICS:
        table.add_column(TERMINAL_HEADINGS[metric.key], justify="right")
    for method in methods:
        table.add_row(method, *(_terminal_cell(method, m, stats, with_paper) for m in METRICS))
    console.print(table)


def print_table2(summary: Mapping[str, Any], console: Console) -> None:
    """Print the Table II comparison (E3 beside the paper's targets) and the claims."""
    print_metrics_table(
        _e3_stats(summary),
        summary["methods"],
        "Table II (E3) — reproduced vs paper",
        console,
        with_paper=True,
    )
    for claim in summary.get("claims", []):
        mark = "[green]✓[/green]" if claim["reproduced"] else "[red]✗[/red]"
        console.print(f"  {mark} {claim['text']}", highlight=False)
