"""R-MAX (Brafman & Tennenholtz 2002) in the discounted form of Strehl, Li & Littman (2009).

Unknown pairs (n < m) are pinned at Q = optimism x Vmax (Vmax by default), known pairs use the
empirical model; the action is greedy with a seeded tie-break (uniform over the maximal actions,
then one draw).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..config import RmaxParams
from ..planning import greedy, value_iteration
from ..types import FloatArray, Transition
from .base import TabularLearner, check_nonnegative

__all__ = ["RmaxLearner"]


class RmaxLearner(TabularLearner[RmaxParams]):
    """Tables: r (C, P) reward sums, ns (C, P, M) successor counts; the model count of a pair is
    its successor counts' sum (with ``freeze_known`` it stops at m, unlike the raw visits)."""

    algorithm: ClassVar[str] = "rmax"
    params_type = RmaxParams
    _tables: ClassVar[dict[str, tuple[type, str]]] = {
        "r": (np.float64, "CP"),
        "ns": (np.float64, "CPM"),
    }
    _reward_sums: ClassVar[dict[str, str]] = {"r": "ns"}
    r: FloatArray
    ns: FloatArray

    def _observe(self, tr: Transition) -> None:
        c, a = tr.context, tr.action
        if self._params.freeze_known and self.ns[c, a].sum() >= self._params.m:
            return
        self.r[c, a] += tr.reward
        self.ns[c, a, self.space.successor_column(a, tr.next_state)] += 1.0
        self._cache.pop(c, None)

    def _reinforce(
        self, context: int, action: int, episode: int, reward: float, *, pending: bool
    ) -> None:
        c, a = context, action
        if self.ns[c, a].sum() > 0:  # a reward sum with no count under it would mean nothing
            self.r[c, a] += reward
        self._cache.pop(c, None)

    def _check_tables(self) -> None:
        check_nonnegative(ns=self.ns)

    def _compute_q(self, context: int, gamma: float | None = None) -> FloatArray:
        n = self.ns[context].sum(axis=1)
        unknown = n < self._params.m
        safe = np.where(unknown, 1.0, n)
        return value_iteration(
            self.space,
            np.where(unknown, 0.0, self.r[context] / safe),
            self.ns[context] / safe[:, None],
            gamma=self.mission.gamma if gamma is None else gamma,
            tol=self._params.vi_tol,
            max_sweeps=self._params.vi_max_sweeps,
            fixed=unknown,
            fixed_value=self._params.optimism * self.mission.v_max,
        )

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        actions = self.space.actions_of(state)
        values: FloatArray = plan[actions.start : actions.stop]
        return greedy(values)

    def _kept_visits(self, context: int) -> FloatArray:
        out: FloatArray = self.ns[context].sum(axis=1)
        return out
