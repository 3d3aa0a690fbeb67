"""The paper's qualitative claims (docs/method.md §13), checked on experiment results.

Each check returns a :class:`Claim` with the numbers it was decided on, so a report can say
plainly which claims our reconstruction reproduces and which it does not. Method labels are
those of ``evaluation.PAPER_METHODS``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from .evaluation import RunResult, summarize

__all__ = ["Claim", "check_claims", "recovery_event"]

RMAX, QL, HRI100, HRI200, DTS = "R-MAX", "Q-learning", "HRI τ=0.01", "HRI τ=0.005", "DTS"
PAPER = (RMAX, QL, HRI100, HRI200)
HRIS = (HRI100, HRI200)


@dataclass(frozen=True)
class Claim:
    key: str
    text: str
    reproduced: bool
    evidence: str


def _rewards(results: Iterable[RunResult], protocol: str) -> dict[str, np.ndarray]:
    """Per method, the per-event rewards of every (seed, user): shape (runs, events)."""
    out: dict[str, list[np.ndarray]] = {}
    for res in results:
        if res.protocol == protocol:
            out.setdefault(res.method, []).append(res.reward)
    return {m: np.concatenate(v) for m, v in out.items()}


def recovery_event(
    reward: np.ndarray, change_at: int, *, window: int = 5, level: float = 0.9, floor: float = 0.0
) -> int | None:
    """First event k (1-based, counted from the change) whose mean reward over events
    k..k+window-1 reaches ``level`` x the mean of the ``2 * window`` events before the change.

    ``reward``: (runs, events), averaged over runs first. None if it never recovers, or if there
    was nothing to recover (the pre-change reward per event was not above ``floor``).
    """
    mean = reward.mean(axis=0)
    before = mean[change_at - 2 * window : change_at].mean()
    if before <= max(floor, 0.0):
        return None
    after = mean[change_at:]
    for k in range(len(after) - window + 1):
        if after[k : k + window].mean() >= level * before:
            return k + 1
    return None


def _event(k: int | None) -> str:
    return "never" if k is None else str(k)


def _fmt(values: dict[str, float], digits: int = 1) -> str:
    return ", ".join(f"{m} {v:.{digits}f}" for m, v in values.items())


def check_claims(results: Sequence[RunResult], *, change_at: int = 50) -> list[Claim]:
    """Decide every claim from E1E2 ("e1e2") and E3 ("e3") results of the paper's methods."""
    e12 = _rewards(results, "e1e2")
    methods = [m for m in (*PAPER, DTS) if m in e12]
    paper = [m for m in PAPER if m in e12]
    cum50 = {m: float(e12[m][:, :change_at].sum(axis=1).mean()) for m in methods}
    early = {m: float(e12[m][:, :20].sum(axis=1).mean()) for m in methods}
    phase2 = {m: float(e12[m][:, change_at:].sum(axis=1).mean()) for m in methods}
    per_event = {m: e12[m].mean(axis=0) for m in methods}
    # A method that never reached half the best pre-change level had no policy to recover.
    pre = {
        m: float(per_event_mean[change_at - 10 : change_at].mean())
        for m, per_event_mean in ((m, e12[m].mean(axis=0)) for m in methods)
    }
    floor = 0.5 * max(pre.values())
    recover = {m: recovery_event(e12[m], change_at, floor=floor) for m in methods}
    claims: list[Claim] = []

    def add(key: str, text: str, ok: bool, evidence: str) -> None:
        claims.append(Claim(key, text, bool(ok), evidence))

    best_hri = max(cum50[m] for m in HRIS)
    add(
        "E1-most-reward",
        "E1: HRI collects the most cumulative reward; R-MAX stays below HRI.",
        all(best_hri > cum50[m] for m in paper if m not in HRIS),
        f"cumulative reward at event {change_at}: {_fmt({m: cum50[m] for m in paper})}",
    )
    ql_first, ql_late = per_event[QL][:20].mean(), per_event[QL][30:change_at].mean()
    add(
        "E1-Q-rebound",
        "E1: Q-learning is slow, then rebounds to a competent policy (~event 30).",
        ql_late > ql_first + 0.5 and cum50[QL] < best_hri,
        f"Q-learning reward per event: events 1-20 {ql_first:.2f}, events 31-{change_at} "
        f"{ql_late:.2f}",
    )
    add(
        "E1-tau005-early",
        "E1: HRI τ=0.005 is best in the initial stage (events 1-20).",
        all(early[HRI200] >= early[m] for m in paper),
        f"cumulative reward at event 20: {_fmt({m: early[m] for m in paper})}",
    )
    drops = {
        m: float(
            per_event[m][change_at : change_at + 5].mean()
            - per_event[m][change_at - 10 : change_at].mean()
        )
        for m in paper
    }
    add(
        "E2-drop",
        "E2: all four methods drop right after the change.",
        all(d < 0 for d in drops.values()),
        f"reward per event, events {change_at + 1}-{change_at + 5} minus events "
        f"{change_at - 9}-{change_at}: {_fmt(drops, 2)}",
    )
    fast = [RMAX, *HRIS]
    add(
        "E2-recover",
        "E2: R-MAX and both HRIs recover within about 10-12 events of the change.",
        all(recover[m] is not None and recover[m] <= 15 for m in fast),  # type: ignore[operator]
        "first event after the change whose 5-event mean reaches 90% of the pre-change level: "
        + ", ".join(f"{m} {_event(recover[m])}" for m in paper),
    )
    add(
        "E2-Q-slow",
        "E2: Q-learning fails to learn a new policy and collects reward slowly.",
        all(phase2[QL] < phase2[m] for m in paper if m != QL),
        f"reward over events {change_at + 1}-100: {_fmt({m: phase2[m] for m in paper})}",
    )
    add(
        "E2-tau001-best",
        "E2: HRI τ=0.01 is the best method after the change.",
        all(phase2[HRI100] >= phase2[m] for m in paper),
        f"reward over events {change_at + 1}-100: {_fmt({m: phase2[m] for m in paper})}",
    )
    final = {m: float(per_event[m][-20:].mean()) for m in paper}
    add(
        "E2-rmax-final",
        "R-MAX starts weaker, but its final policy is about as good as HRI's.",
        final[RMAX] >= 0.9 * max(final[m] for m in HRIS) and cum50[RMAX] < best_hri,
        f"reward per event over the last 20 events: {_fmt(final, 2)}",
    )
    window20 = {m: float(e12[m][:, change_at : change_at + 20].sum(axis=1).mean()) for m in methods}
    add(
        "HRI-recovers-faster-than-Q",
        "After the change, HRI recovers faster than Q-learning: more reward in the 20 events "
        "after the change, and back at its own level no later.",
        all(
            window20[m] > window20[QL]
            and recover[m] is not None
            and (recover[QL] is None or recover[m] <= recover[QL])  # type: ignore[operator]
            for m in HRIS
        ),
        f"reward over events {change_at + 1}-{change_at + 20}: "
        f"{_fmt({m: window20[m] for m in (*HRIS, QL)})}; recovery event: "
        f"{', '.join(f'{m} {_event(recover[m])}' for m in (*HRIS, QL))}",
    )

    table = summarize([r for r in results if r.protocol == "e3"])
    if all(m in table for m in (RMAX, *HRIS)):
        ir = {m: table[m]["interaction_rate"][0] for m in (RMAX, *HRIS)}
        sr = {m: table[m]["success_rate"][0] for m in (RMAX, *HRIS)}
        qm = {m: table[m]["queries_per_mission"][0] for m in (RMAX, *HRIS)}
        add(
            "T2-interaction",
            "Table II: HRI's interaction rate is well above R-MAX's.",
            all(ir[m] > ir[RMAX] for m in HRIS),
            f"interaction rate: {_fmt(ir, 3)}",
        )
        add(
            "T2-success",
            "Table II: success rates are within about 5 points of each other.",
            max(sr.values()) - min(sr.values()) <= 0.05,
            f"success rate: {_fmt(sr, 3)}",
        )
        add(
            "T2-queries",
            "Table II: HRI τ=0.01 asks fewer queries per mission than R-MAX.",
            qm[HRI100] < qm[RMAX],
            f"queries per mission: {_fmt(qm, 2)}",
        )
    if DTS in e12:
        others = list(paper)
        e3 = _rewards(results, "e3")
        total = {m: float(e3[m].sum(axis=1).mean()) for m in e3}
        add(
            "DTS-beats-paper",
            "Ours: DTS collects more reward than every method of the paper, "
            "before the change (E1), after it (E2) and in the rerun (E3).",
            all(
                cum50[DTS] > cum50[m] and phase2[DTS] > phase2[m] and total[DTS] > total[m]
                for m in others
            ),
            f"E1 {_fmt({m: cum50[m] for m in methods})}; E2 "
            f"{_fmt({m: phase2[m] for m in methods})}; E3 {_fmt(total)}",
        )
    return claims
