"""Plots of experiment runs: the Fig. 2/3 style cumulative-reward curves.

matplotlib is imported inside the plotting function, so that importing this module (and the
command line, and the worker processes) stays fast; it draws on the Agg canvas, without pyplot.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from app.learning.evaluation import RunResult

from .report import figure
from .statistics import SHADE_LABEL, cumulative_curve, method_order

__all__ = ["plot_cumulative"]


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
    fig = figure(10, 6)
    ax = fig.add_subplot()
    events = np.arange(start + 1, stop + 1)
    methods = method_order(results)
    samples = sum(res.reward.shape[0] for res in results if res.method == methods[0])
    styles = ("-", "--", "-.", ":")
    for i, method in enumerate(methods):
        mean, half = cumulative_curve(results, method, start, stop)
        color = f"C{i % 10}"
        ax.plot(
            events, mean, color=color, linestyle=styles[i % len(styles)], linewidth=2, label=method
        )
        ax.fill_between(events, mean - half, mean + half, color=color, alpha=0.18, linewidth=0)
    if change_after is not None:
        ax.axvline(change_after + 0.5, color="0.4", linestyle=":", linewidth=1.5)
        ax.annotate(
            "needs change",
            xy=(change_after + 0.5, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(4, -14),
            textcoords="offset points",
            color="0.3",
            fontsize=10,
        )
    ax.axhline(0.0, color="0.75", linewidth=0.8, zorder=0)
    ax.set_xlim(events[0], events[-1])
    ax.set_xlabel(xlabel, fontsize=12)
    ax.set_ylabel(ylabel, fontsize=12)
    ax.tick_params(labelsize=11)
    ax.grid(True, alpha=0.3)
    fig.suptitle(title, fontsize=14)
    ax.set_title(
        f"mean over {samples} user-runs per method; {SHADE_LABEL}", fontsize=10, color="0.3"
    )
    ax.legend(loc="upper left", fontsize=11, framealpha=0.9)
    fig.savefig(path, format="png")
