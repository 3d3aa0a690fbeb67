"""Tabular Q-learning (Watkins 1989) over the negotiation states, epsilon-greedy or Boltzmann."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..config import QLearningParams
from ..planning import gibbs, greedy
from ..types import FloatArray, Transition
from .base import TabularLearner

__all__ = ["QLearner"]


class QLearner(TabularLearner[QLearningParams]):
    """Tables: q (C, P), the action values; the step size uses the raw visit counts."""

    algorithm: ClassVar[str] = "qlearning"
    params_type = QLearningParams
    _tables: ClassVar[dict[str, tuple[type, str]]] = {"q": (np.float64, "CP")}
    q: FloatArray

    def _init_tables(self) -> None:
        self.q[...] = self._params.q0

    def _observe(self, tr: Transition) -> None:
        c, a = tr.context, tr.action
        alpha = max(self._params.alpha_min, 1.0 / float(self.visits[c, a]))
        target = tr.reward
        if tr.next_state != self.space.END:
            nxt = self.space.actions_of(tr.next_state)
            target += self.mission.gamma * float(self.q[c, nxt.start : nxt.stop].max())
        self.q[c, a] += alpha * (target - self.q[c, a])

    def _reinforce(
        self, context: int, action: int, episode: int, reward: float, *, pending: bool
    ) -> None:
        # The sample's target grows by ``reward``: its update moves Q by alpha times as much.
        c, a = context, action
        alpha = max(self._params.alpha_min, 1.0 / float(self.visits[c, a]))
        self.q[c, a] += alpha * reward

    def _q(self, context: int) -> FloatArray:
        out: FloatArray = self.q[context]  # the table itself: nothing to plan or cache
        return out

    def _compute_q(self, context: int, gamma: float | None = None) -> FloatArray:
        # Without a model there is nothing to solve at another discount: the values learned,
        # discounted by the mission's gamma, are all there is.
        out: FloatArray = self.q[context].copy()
        return out

    def _cached_q(self, context: int, gamma: float | None) -> FloatArray:
        # The table changes with every sample and no hook drops a cache: never keep one.
        return self._q(context)

    def epsilon(self, episode: int) -> float:
        prm = self._params
        return max(prm.epsilon_min, prm.epsilon0 * prm.epsilon_decay ** (episode - 1))

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        actions = self.space.actions_of(state)
        q = plan[actions.start : actions.stop]
        if self._params.exploration == "boltzmann":
            return gibbs(q, self._params.temperature)
        eps = self.epsilon(episode)
        out: FloatArray = eps / len(actions) + (1.0 - eps) * greedy(q)
        return out
