"""Reports of experiment runs: per-event CSV, Fig. 2/3 style plots, Table II markdown and JSON.

Every number is a mean and a standard deviation over users x seeds: one sample per simulated user
per seed, as ``app.learning.experiments.summarize`` computes them. The plots shade a 95%
confidence interval of the mean instead (the spread of single users would hide the differences
between methods).

matplotlib is imported inside the plotting function, so that importing this module (and the
command line, and the worker processes) stays fast; it draws on the Agg canvas, without pyplot.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rich import box
from rich.console import Console
from rich.table import Table

from app.learning.claims import check_claims
from app.learning.experiments import E1E2, E3, PA, Protocol, RunResult, summarize

__all__ = [
    "CSV_COLUMNS",
    "PAPER_TABLE2",
    "SHADE_LABEL",
    "SPREAD_LABEL",
    "Block",
    "ablation_markdown",
    "build_summary",
    "cumulative_curve",
    "plot_cumulative",
    "print_metrics_table",
    "print_table2",
    "table2_markdown",
    "write_ablation_report",
    "write_paper_report",
    "write_rewards_csv",
]

CSV_COLUMNS = (
    "protocol", "method", "seed", "user", "event",
    "reward", "initiated", "interaction", "success", "queries",
)
INTERACTION_NAMES = ("none", "I1", "I2", "I3")  # RunResult.interaction codes 0..3

SPREAD_LABEL = "mean ± std over users × seeds (one sample per simulated user and seed)"
SHADE_LABEL = "shaded: 95% CI of the mean (±1.96 standard errors over users × seeds)"

# docs/method.md §13: the paper's Table II (E3); other methods are not in the paper.
PAPER_TABLE2: dict[str, dict[str, float]] = {
    "R-MAX": {"interaction_rate": 0.4992, "success_rate": 0.7148, "queries_per_mission": 1.2},
    "HRI τ=0.01": {"interaction_rate": 0.765, "success_rate": 0.725, "queries_per_mission": 0.79},
    "HRI τ=0.005": {
        "interaction_rate": 0.805, "success_rate": 0.7204, "queries_per_mission": 1.095,
    },
}

PROTOCOLS: dict[str, Protocol] = {p.name: p for p in (E1E2, E3, PA)}

Stats = dict[str, dict[str, dict[str, float | None]]]  # method -> metric -> {"mean", "std"}


@dataclass(frozen=True)
class Metric:
    """A reported metric: its key in ``episode_metrics``, its heading, whether it is a rate."""

    key: str
    heading: str
    rate: bool
    paper: bool = False


METRICS = (
    Metric("interaction_rate", "Interaction rate", rate=True, paper=True),
    Metric("success_rate", "Success rate", rate=True, paper=True),
    Metric("success_rate_engaged", "Success rate (I1+I2)", rate=True),
    Metric("queries_per_mission", "Queries / mission", rate=False, paper=True),
    Metric("total_reward", "Total reward", rate=False),
)


@dataclass(frozen=True)
class Block:
    """Events ``start+1 .. stop`` of a protocol (0-based, half-open ``start:stop``)."""

    start: int
    stop: int

    @property
    def label(self) -> str:
        """The 1-based, inclusive event range, e.g. ``"101-200"``."""
        return f"{self.start + 1}-{self.stop}"


def blocks_for(protocol: str, n_events: int) -> list[Block]:
    """The whole run, then the phases before and after the change (if the protocol has one)."""
    blocks = [Block(0, n_events)]
    known = PROTOCOLS.get(protocol)
    if known is not None and known.change_at is not None and 0 < known.change_at < n_events:
        blocks += [Block(0, known.change_at), Block(known.change_at, n_events)]
    return blocks


def group(results: Iterable[RunResult]) -> dict[str, list[RunResult]]:
    """Results by protocol name, in the order first seen."""
    out: dict[str, list[RunResult]] = {}
    for res in results:
        out.setdefault(res.protocol, []).append(res)
    return out


def method_order(results: Iterable[RunResult]) -> list[str]:
    """Method labels in the order first seen."""
    return list(dict.fromkeys(res.method for res in results))


def _finite(x: float) -> float | None:
    """``x``, or None for NaN/inf (JSON has no NaN)."""
    return x if math.isfinite(x) else None


def block_stats(results: Sequence[RunResult], block: Block) -> Stats:
    """Mean and std of every metric per method over the events of ``block``."""
    raw = summarize(results, block.start, block.stop)
    return {
        method: {key: {"mean": _finite(m), "std": _finite(s)} for key, (m, s) in metrics.items()}
        for method, metrics in raw.items()
    }


def cumulative_curve(
    results: Sequence[RunResult], method: str, start: int, stop: int
) -> tuple[np.ndarray, np.ndarray]:
    """Mean cumulative reward over events ``start:stop`` (re-zeroed at ``start``) and the
    half-width of its 95% confidence interval, over users x seeds."""
    rewards = [res.reward[:, start:stop] for res in results if res.method == method]
    if not rewards:
        raise ValueError(f"No results for method {method!r}.")
    curves = np.cumsum(np.concatenate(rewards, axis=0), axis=1)
    n = curves.shape[0]
    mean = curves.mean(axis=0)
    half = 1.96 * curves.std(axis=0, ddof=1) / math.sqrt(n) if n > 1 else np.zeros_like(mean)
    return mean, half


def plot_cumulative(
    results: Sequence[RunResult],
    start: int,
    stop: int,
    path: Path,
    *,
    title: str,
    xlabel: str,
    ylabel: str,
    change_after: int | None = None,
) -> None:
    """One line per method: mean cumulative reward per event over ``start:stop``, CI shaded;
    saved as a 1000x600 PNG. ``change_after`` draws a line after that (1-based) event."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 6), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    events = np.arange(start + 1, stop + 1)
    methods = method_order(results)
    samples = sum(res.reward.shape[0] for res in results if res.method == methods[0])
    styles = ("-", "--", "-.", ":")
    for i, method in enumerate(methods):
        mean, half = cumulative_curve(results, method, start, stop)
        color = f"C{i % 10}"
        ax.plot(events, mean, color=color, linestyle=styles[i % len(styles)], linewidth=2,
                label=method)
        ax.fill_between(events, mean - half, mean + half, color=color, alpha=0.18, linewidth=0)
    if change_after is not None:
        ax.axvline(change_after + 0.5, color="0.4", linestyle=":", linewidth=1.5)
        ax.annotate("needs change", xy=(change_after + 0.5, 1.0),
                    xycoords=("data", "axes fraction"), xytext=(4, -14),
                    textcoords="offset points", color="0.3", fontsize=10)
    ax.axhline(0.0, color="0.75", linewidth=0.8, zorder=0)
    ax.set_xlim(events[0], events[-1])
    ax.set_xlabel(xlabel, fontsize=12)
    ax.set_ylabel(ylabel, fontsize=12)
    ax.tick_params(labelsize=11)
    ax.grid(True, alpha=0.3)
    fig.suptitle(title, fontsize=14)
    ax.set_title(f"mean over {samples} user-runs per method; {SHADE_LABEL}", fontsize=10,
                 color="0.3")
    ax.legend(loc="upper left", fontsize=11, framealpha=0.9)
    fig.savefig(path, format="png")


def write_rewards_csv(results: Iterable[RunResult], path: Path) -> int:
    """Write every per-event record (event 1-based, user and seed as seeded); returns the rows.

    ``initiated`` and ``success`` are 0/1; ``interaction`` is none, I1, I2 or I3.
    """
    rows = 0
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        for res in results:
            users, events = res.reward.shape
            for user in range(users):
                reward = res.reward[user].tolist()
                initiated = res.initiated[user].astype(np.int8).tolist()
                interaction = [INTERACTION_NAMES[c] for c in res.interaction[user].tolist()]
                success = res.success[user].astype(np.int8).tolist()
                queries = res.queries[user].tolist()
                writer.writerows(
                    (res.protocol, res.method, res.seed, user, e + 1, f"{reward[e]:.10g}",
                     initiated[e], interaction[e], success[e], queries[e])
                    for e in range(events)
                )
                rows += events
    return rows


def build_summary(
    results: Sequence[RunResult], run_info: Mapping[str, Any], *, paper: bool = True
) -> dict[str, Any]:
    """All the numbers as plain JSON data: per protocol, per block, per method, per metric
    ``{"mean", "std"}``; with ``paper``, also the Fig. 2/3 curves, the paper's Table II targets
    and the paper's claims checked."""
    by_protocol = group(results)
    summary: dict[str, Any] = {
        "run": dict(run_info),
        "methods": method_order(results),
        "spread": SPREAD_LABEL,
        "metrics": {m.key: m.heading for m in METRICS},
        "protocols": {},
    }
    for name, runs in by_protocol.items():
        n_events = runs[0].reward.shape[1]
        known = PROTOCOLS.get(name)
        summary["protocols"][name] = {
            "n_events": n_events,
            "change_after_event": known.change_at if known else None,
            "blocks": {b.label: block_stats(runs, b) for b in blocks_for(name, n_events)},
        }
    if paper and E1E2.name in by_protocol:
        summary["curves"] = _curves(by_protocol[E1E2.name])
    if paper and E3.name in by_protocol:
        summary["paper_table2"] = PAPER_TABLE2
    if paper and E1E2.name in by_protocol and E3.name in by_protocol:
        summary["claims"] = [dataclasses.asdict(c) for c in check_claims(results)]
    return summary


def _curves(runs: Sequence[RunResult]) -> dict[str, Any]:
    """The Fig. 2 and Fig. 3 curves: mean cumulative reward and 95% CI half-width per event."""
    assert E1E2.change_at is not None
    out: dict[str, Any] = {"shade": SHADE_LABEL}
    for fig, (start, stop) in {
        "fig2": (0, E1E2.change_at), "fig3": (E1E2.change_at, E1E2.n_events)
    }.items():
        methods: dict[str, Any] = {}
        for method in method_order(runs):
            mean, half = cumulative_curve(runs, method, start, stop)
            methods[method] = {"mean": mean.round(6).tolist(), "ci95": half.round(6).tolist()}
        out[fig] = {"events": list(range(start + 1, stop + 1)), "methods": methods}
    return out


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


def _markdown_table(
    rows: Sequence[Row], lead: Sequence[str], with_paper: bool
) -> str:
    """A markdown table: ``lead`` columns, then the metric (and paper) columns."""
    cols = _columns(with_paper)
    header = [*lead, *(c.heading for c in cols)]
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join([":---"] * len(lead) + ["---:"] * len(cols)) + "|"]
    for cells, method, stats in rows:
        lines.append("| " + " | ".join([*cells, *(c.cell(method, stats) for c in cols)]) + " |")
    return "\n".join(lines)


def _block_rows(summary: Mapping[str, Any], protocol: str) -> list[Row]:
    """Rows method x block (the phases, or the whole run when there is no change)."""
    blocks: dict[str, Stats] = summary["protocols"][protocol]["blocks"]
    labels = list(blocks)[1:] or list(blocks)
    return [((method, f"{label}"), method, blocks[label])
            for method in summary["methods"] for label in labels]


def _plural(n: int, word: str) -> str:
    """``"1 seed"``, ``"2 seeds"``."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def _preamble(summary: Mapping[str, Any]) -> str:
    """How many runs the numbers come from."""
    run = summary["run"]
    runs = f"{_plural(run['seeds'], 'seed')} × {_plural(run['users'], 'simulated user')}"
    return f"{runs} per method; {SPREAD_LABEL}."


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
            _markdown_table([((m,), m, _e3_stats(summary)) for m in summary["methods"]],
                            ["Method"], False),
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
    table = Table(title=title, title_style="bold", caption=caption, box=box.SIMPLE_HEAD,
                  pad_edge=False, show_edge=False, collapse_padding=True)
    table.add_column("Method", style="bold", no_wrap=True)
    for metric in METRICS:
        table.add_column(TERMINAL_HEADINGS[metric.key], justify="right")
    for method in methods:
        table.add_row(method, *(_terminal_cell(method, m, stats, with_paper) for m in METRICS))
    console.print(table)


def print_table2(summary: Mapping[str, Any], console: Console) -> None:
    """Print the Table II comparison (E3 beside the paper's targets) and the claims."""
    print_metrics_table(_e3_stats(summary), summary["methods"],
                        "Table II (E3) — reproduced vs paper", console, with_paper=True)
    for claim in summary.get("claims", []):
        mark = "[green]✓[/green]" if claim["reproduced"] else "[red]✗[/red]"
        console.print(f"  {mark} {claim['text']}", highlight=False)


def _write_json(data: Mapping[str, Any], path: Path) -> None:
    """Write ``data`` as strict, indented UTF-8 JSON."""
    path.write_text(json.dumps(data, indent=2, ensure_ascii=False, allow_nan=False) + "\n",
                    encoding="utf-8")


def write_paper_report(
    results: Sequence[RunResult], out: Path, run_info: Mapping[str, Any]
) -> tuple[dict[str, Any], list[Path]]:
    """Write rewards.csv, fig2.png, fig3.png, table2.md and summary.json into ``out``.

    ``results`` must hold E1E2, E3 and PA runs. Returns the summary and the files written.
    """
    out.mkdir(parents=True, exist_ok=True)
    by_protocol = group(results)
    for needed in (E1E2, E3, PA):
        if needed.name not in by_protocol:
            raise ValueError(f"No {needed.name} results to report.")
    assert E1E2.change_at is not None
    files = [out / name for name in
             ("fig2.png", "fig3.png", "rewards.csv", "table2.md", "summary.json", "claims.md")]
    e1e2 = by_protocol[E1E2.name]
    plot_cumulative(
        e1e2, 0, E1E2.change_at, files[0],
        title=f"Fig. 2 — E1: cumulative reward, events 1–{E1E2.change_at} (learning from scratch)",
        xlabel="event", ylabel="cumulative reward",
    )
    plot_cumulative(
        e1e2, E1E2.change_at, E1E2.n_events, files[1],
        title=f"Fig. 3 — E2: cumulative reward after the needs change, events "
              f"{E1E2.change_at + 1}–{E1E2.n_events} (re-zeroed)",
        xlabel=f"event (the users' needs changed after event {E1E2.change_at})",
        ylabel="cumulative reward since the change",
    )
    write_rewards_csv(results, files[2])
    summary = build_summary(results, run_info)
    files[3].write_text(table2_markdown(summary), encoding="utf-8")
    _write_json(summary, files[4])
    files[5].write_text("# " + claims_markdown(summary)[3:], encoding="utf-8")
    return summary, files


def write_ablation_report(
    results: Sequence[RunResult], out: Path, run_info: Mapping[str, Any]
) -> tuple[dict[str, Any], list[Path]]:
    """Write ablation.md, summary.json, pa_cumulative.png and rewards.csv into ``out``.

    Returns the summary and the files written.
    """
    out.mkdir(parents=True, exist_ok=True)
    files = [out / name for name in
             ("ablation.md", "summary.json", "pa_cumulative.png", "rewards.csv")]
    summary = build_summary(results, run_info, paper=False)
    files[0].write_text(ablation_markdown(summary), encoding="utf-8")
    _write_json(summary, files[1])
    pa = group(results).get(PA.name)
    if pa:
        plot_cumulative(
            pa, 0, pa[0].reward.shape[1], files[2],
            title=f"Ablations — PA: cumulative reward over {pa[0].reward.shape[1]} events",
            xlabel="event", ylabel="cumulative reward", change_after=PA.change_at,
        )
    else:
        files.remove(files[2])
    write_rewards_csv(results, files[-1])
    return summary, files
