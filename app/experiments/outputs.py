"""The files of an experiment report, written into the ``--out`` folder of ``attune experiment
paper`` and ``attune experiment ablation``: every event as CSV, the figures, the markdown tables
and ``summary.json``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.learning.evaluation import E1E2, E3, PA, RunResult

from .plots import plot_cumulative
from .report import write_csv, write_json
from .statistics import build_summary, group
from .text import ablation_markdown, claims_markdown, table2_markdown

__all__ = [
    "CSV_COLUMNS",
    "write_ablation_report",
    "write_paper_report",
    "write_rewards_csv",
]

CSV_COLUMNS = (
    "protocol",
    "method",
    "seed",
    "user",
    "event",
    "reward",
    "initiated",
    "interaction",
    "success",
    "queries",
)
INTERACTION_NAMES = ("none", "I1", "I2", "I3")  # RunResult.interaction codes 0..3


def write_rewards_csv(results: Iterable[RunResult], path: Path) -> int:
    """Write every per-event record (event 1-based, user and seed as seeded); returns the rows.

    ``initiated`` and ``success`` are 0/1; ``interaction`` is none, I1, I2 or I3.
    """
    return write_csv(path, CSV_COLUMNS, _reward_rows(results))


def _reward_rows(results: Iterable[RunResult]) -> Iterator[tuple[object, ...]]:
    for res in results:
        users, events = res.reward.shape
        for user in range(users):
            reward = res.reward[user].tolist()
            initiated = res.initiated[user].astype(np.int8).tolist()
            interaction = [INTERACTION_NAMES[c] for c in res.interaction[user].tolist()]
            success = res.success[user].astype(np.int8).tolist()
            queries = res.queries[user].tolist()
            for e in range(events):
                yield (
                    res.protocol,
                    res.method,
                    res.seed,
                    user,
                    e + 1,
                    f"{reward[e]:.10g}",
                    initiated[e],
                    interaction[e],
                    success[e],
                    queries[e],
                )


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
    files = [
        out / name
        for name in (
            "fig2.png",
            "fig3.png",
            "rewards.csv",
            "table2.md",
            "summary.json",
            "claims.md",
        )
    ]
    e1e2 = by_protocol[E1E2.name]
    plot_cumulative(
        e1e2,
        0,
        E1E2.change_at,
        files[0],
        title=f"Fig. 2 — E1: cumulative reward, events 1–{E1E2.change_at} (learning from scratch)",
        xlabel="event",
        ylabel="cumulative reward",
    )
    plot_cumulative(
        e1e2,
        E1E2.change_at,
        E1E2.n_events,
        files[1],
        title=f"Fig. 3 — E2: cumulative reward after the needs change, events "
        f"{E1E2.change_at + 1}–{E1E2.n_events} (re-zeroed)",
        xlabel=f"event (the users' needs changed after event {E1E2.change_at})",
        ylabel="cumulative reward since the change",
    )
    write_rewards_csv(results, files[2])
    summary = build_summary(results, run_info)
    files[3].write_text(table2_markdown(summary), encoding="utf-8")
    write_json(summary, files[4])
    files[5].write_text("# " + claims_markdown(summary)[3:], encoding="utf-8")
    return summary, files


def write_ablation_report(
    results: Sequence[RunResult], out: Path, run_info: Mapping[str, Any]
) -> tuple[dict[str, Any], list[Path]]:
    """Write ablation.md, summary.json, pa_cumulative.png and rewards.csv into ``out``.

    Returns the summary and the files written.
    """
    out.mkdir(parents=True, exist_ok=True)
    files = [
        out / name for name in ("ablation.md", "summary.json", "pa_cumulative.png", "rewards.csv")
    ]
    summary = build_summary(results, run_info, paper=False)
    files[0].write_text(ablation_markdown(summary), encoding="utf-8")
    write_json(summary, files[1])
    pa = group(results).get(PA.name)
    if pa:
        plot_cumulative(
            pa,
            0,
            pa[0].reward.shape[1],
            files[2],
            title=f"Ablations — PA: cumulative reward over {pa[0].reward.shape[1]} events",
            xlabel="event",
            ylabel="cumulative reward",
            change_after=PA.change_at,
        )
    else:
        files.remove(files[2])
    write_rewards_csv(results, files[-1])
    return summary, files
