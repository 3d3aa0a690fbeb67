"""The numbers of an experiment report: every metric per method and block of events, the
cumulative-reward curves, and the summary (``summary.json``) that the text and the plots show.

Every number is a mean and a standard deviation over users x seeds: one sample per simulated user
per seed, as ``app.learning.evaluation.summarize`` computes them. The curves carry a 95%
confidence interval of the mean instead (the spread of single users would hide the differences
between methods).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.learning.claims import check_claims
from app.learning.evaluation import E1E2, E3, PA, Protocol, RunResult, summarize

__all__ = [
    "METRICS",
    "PAPER_TABLE2",
    "PROTOCOLS",
    "SHADE_LABEL",
    "SPREAD_LABEL",
    "Block",
    "Metric",
    "Stats",
    "block_stats",
    "blocks_for",
    "build_summary",
    "cumulative_curve",
    "group",
    "mean_ci95",
    "method_order",
    "t95",
]

SPREAD_LABEL = "mean ± std over users × seeds (one sample per simulated user and seed)"
SHADE_LABEL = "shaded: 95% CI of the mean (±1.96 standard errors over users × seeds)"

# docs/method.md §13: the paper's Table II (E3); other methods are not in the paper.
PAPER_TABLE2: dict[str, dict[str, float]] = {
    "R-MAX": {"interaction_rate": 0.4992, "success_rate": 0.7148, "queries_per_mission": 1.2},
    "HRI τ=0.01": {"interaction_rate": 0.765, "success_rate": 0.725, "queries_per_mission": 0.79},
    "HRI τ=0.005": {
        "interaction_rate": 0.805,
        "success_rate": 0.7204,
        "queries_per_mission": 1.095,
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


# Two-sided 95% quantiles of Student's t by degrees of freedom (1-30, then a few beyond).
_T95 = (
    12.706,
    4.303,
    3.182,
    2.776,
    2.571,
    2.447,
    2.365,
    2.306,
    2.262,
    2.228,
    2.201,
    2.179,
    2.160,
    2.145,
    2.131,
    2.120,
    2.110,
    2.101,
    2.093,
    2.086,
    2.080,
    2.074,
    2.069,
    2.064,
    2.060,
    2.056,
    2.052,
    2.048,
    2.045,
    2.042,
)
_T95_BEYOND = ((40, 2.021), (60, 2.000), (120, 1.980))


def t95(df: int) -> float:
    """The two-sided 95% quantile of Student's t with ``df`` degrees of freedom (beyond 30, the
    value at the largest tabulated df not above it: slightly wide, never narrow)."""
    if df < 1:
        raise ValueError(f"df must be at least 1, got {df}.")
    if df <= len(_T95):
        return _T95[df - 1]
    value = _T95[-1]
    for at, quantile in _T95_BEYOND:
        if df >= at:
            value = quantile
    return value if df < 1000 else 1.960


def mean_ci95(values: Sequence[float] | np.ndarray) -> tuple[float, float, float] | None:
    """Mean and 95% confidence interval of the mean (Student's t) of the finite ``values``;
    None when there are none. One value gives an interval of zero width around it."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return None
    mean = float(x.mean())
    if x.size == 1:
        return mean, mean, mean
    half = t95(x.size - 1) * float(x.std(ddof=1)) / math.sqrt(x.size)
    return mean, mean - half, mean + half


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
        "fig2": (0, E1E2.change_at),
        "fig3": (E1E2.change_at, E1E2.n_events),
    }.items():
        methods: dict[str, Any] = {}
        for method in method_order(runs):
            mean, half = cumulative_curve(runs, method, start, stop)
            methods[method] = {"mean": mean.round(6).tolist(), "ci95": half.round(6).tolist()}
        out[fig] = {"events": list(range(start + 1, stop + 1)), "methods": methods}
    return out
