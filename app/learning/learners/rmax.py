"""R-MAX (Brafman & Tennenholtz 2002) in the discounted form of Strehl, Li & Littman (2009).

Unknown pairs (n < m) are pinned at Q = Vmax, known pairs use the empirical model; the action is
greedy with a seeded tie-break (uniform over the maximal actions, then one draw).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..config import RmaxParams
from ..planning import greedy, value_iteration
from ..types import FloatArray, Transition
from .base import TabularLearner

__all__ = ["RmaxLearner"]


class RmaxLearner(TabularLearner[RmaxParams]):
    """Tables: n (C, P) model counts, r (C, P) reward sums, ns (C, P, M) successor counts."""

    algorithm: ClassVar[str] = "rmax"
    params_type = RmaxParams
    _tables: ClassVar[dict[str, tuple[type, str]]] = {
        "n": (np.float64, "CP"),
        "r": (np.float64, "CP"),
        "ns": (np.float64, "CPM"),
    }
    n: FloatArray
    r: FloatArray
    ns: FloatArray

    def _observe(self, tr: Transition) -> None:
        c, a = tr.context, tr.action
        if self._params.freeze_known and self.n[c, a] >= self._params.m:
            return
        self.n[c, a] += 1.0
        self.r[c, a] += tr.reward
        self.ns[c, a, self.space.successor_column(a, tr.next_state)] += 1.0
        self._cache.pop(c, None)

    def _q(self, context: int) -> FloatArray:
        cached = self._cache.get(context)
        if cached is not None:
            return cached  # type: ignore[no-any-return]
        n = self.n[context]
        unknown = n < self._params.m
        safe = np.where(unknown, 1.0, n)
        q = value_iteration(
            self.space,
            np.where(unknown, 0.0, self.r[context] / safe),
            self.ns[context] / safe[:, None],
            gamma=self.mission.gamma,
            tol=self._params.vi_tol,
            max_sweeps=self._params.vi_max_sweeps,
            fixed=unknown,
            fixed_value=self.mission.v_max,
        )
        q.setflags(write=False)
        self._cache[context] = q
        return q

    def _plan(self, context: int, episode: int, rng: np.random.Generator | None) -> Any:
        return self._q(context)

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        actions = self.space.actions_of(state)
        values: FloatArray = plan[actions.start : actions.stop]
        return greedy(values)

    def _kept_visits(self, context: int) -> FloatArray:
        out: FloatArray = self.n[context].copy()
        return out
