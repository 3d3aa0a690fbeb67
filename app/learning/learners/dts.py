"""Discounted Thompson sampling over the negotiation MDP: our learner for drifting wishes.

Two ideas the paper's learner does without:

- **Known structure.** Responding and inferring are the robot's own bookkeeping: ``infer_type(k)``
  always leads to TYPE_KNOWN(k) with reward 0. Only what the *person* does is uncertain (accept
  an offer, answer a question, like a service), so only human-facing pairs are learned and the
  planner can chain a learned answer into a silent inference at once (one answered query teaches
  the robot what to infer next time).
- **Forgetting plus posterior sampling** (section 8: discounted Thompson sampling, Raj & Kalyani
  2017; forgetting counts n <- lambda * n + 1): each pair's counts decay by ``forgetting`` at
  every new sample of that pair, so stale evidence fades at the speed the pair is used, and
  exploration comes from sampling models from the posterior instead of a temperature.

Per decision, ``samples`` models are drawn (Dirichlet successors, Normal mean rewards), each is
solved by value iteration, and the action distribution is the share of models in which each
action is best; the action is drawn from that distribution.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..config import DtsParams
from ..planning import value_iteration
from ..types import FloatArray, Transition
from .base import TabularLearner

__all__ = ["DtsLearner"]


class DtsLearner(TabularLearner[DtsParams]):
    """Tables: dn (C, P) discounted counts, dr (C, P) discounted reward sums, dns (C, P, M)
    discounted successor counts. Silent pairs are never learned (their dynamics are known)."""

    algorithm: ClassVar[str] = "dts"
    params_type = DtsParams
    _tables: ClassVar[dict[str, tuple[type, str]]] = {
        "dn": (np.float64, "CP"),
        "dr": (np.float64, "CP"),
        "dns": (np.float64, "CPM"),
    }
    dn: FloatArray
    dr: FloatArray
    dns: FloatArray

    def _add(self, c: int, a: int, reward: float, column: int) -> None:
        lam = self._params.forgetting
        self.dn[c, a] = lam * self.dn[c, a] + 1.0
        self.dr[c, a] = lam * self.dr[c, a] + reward
        self.dns[c, a] *= lam
        self.dns[c, a, column] += 1.0
        self._cache.pop(c, None)

    def _observe(self, tr: Transition) -> None:
        space = self.space
        if space.silent[tr.action]:
            return
        self._add(tr.context, tr.action, tr.reward, space.successor_column(tr.action, tr.next_state))
        human_initiated = (
            tr.state == space.OBSERVE and tr.action == space.PASS and tr.next_state != space.END
        )
        if human_initiated and self._params.i1_as_acceptance:
            accept = space.successor_column(space.INITIATE, space.ENGAGED)
            self._add(tr.context, space.INITIATE, self.mission.rewards.positive, accept)

    # -- the posterior -------------------------------------------------------------------------
    def _posterior(self, context: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Mean reward (P,), its standard deviation (P,), Dirichlet parameters (P, M), and the
        known transition of silent pairs (P, M)."""
        space, prm = self.space, self._params
        n = self.dn[context]
        mean = (self.dr[context] + prm.reward_prior * prm.reward_prior_count) / (
            n + prm.reward_prior_count
        )
        sd = prm.reward_sd / np.sqrt(n + prm.reward_prior_count)
        alpha = np.where(space.succ_mask, self.dns[context] + prm.prior_count, 0.0)
        silent = space.silent
        mean = np.where(silent, space.silent_reward, mean)
        sd = np.where(silent, 0.0, sd)
        known = np.zeros_like(alpha)
        known[silent, 0] = 1.0  # a silent pair's first successor is its deterministic target
        return mean, sd, alpha, known

    def _q(self, context: int) -> FloatArray:
        """Q of the posterior-mean model."""
        cached = self._cache.get(context)
        if cached is not None:
            return cached  # type: ignore[no-any-return]
        mean, _, alpha, known = self._posterior(context)
        silent = self.space.silent[:, None]
        trans = np.where(silent, known, alpha / alpha.sum(axis=1, keepdims=True))
        q = self._solve(mean, trans)
        q.setflags(write=False)
        self._cache[context] = q
        return q

    def _solve(self, reward: FloatArray, trans: FloatArray) -> FloatArray:
        v_max = self.mission.v_max
        q = value_iteration(
            self.space, reward, trans, gamma=self.mission.gamma, tol=self._params.vi_tol,
            max_sweeps=self._params.vi_max_sweeps,
        )
        return np.clip(q, -v_max, v_max)

    def _plan(self, context: int, episode: int, rng: np.random.Generator | None) -> Any:
        if rng is None:  # explain(): a fixed draw, so the view is stable for a given model
            rng = np.random.default_rng([self.version, context])
        k = self._params.samples
        mean, sd, alpha, known = self._posterior(context)
        g = rng.standard_gamma(np.broadcast_to(alpha, (k, *alpha.shape)))
        total = g.sum(axis=2, keepdims=True)
        trans = np.where(self.space.silent[None, :, None], known[None], g / np.maximum(total, 1e-300))
        reward = mean + sd * rng.standard_normal((k, mean.shape[0]))
        return self._solve(reward, trans)

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        actions = self.space.actions_of(state)
        best = np.argmax(plan[:, actions.start : actions.stop], axis=1)
        counts = np.bincount(best, minlength=len(actions)).astype(np.float64)
        out: FloatArray = counts / counts.sum()
        return out

    def _kept_visits(self, context: int) -> FloatArray:
        return self.dn[context].copy()
