"""The paper's HRI-based learner (algorithm.md sections 3-4).

Model learning keeps, per (context, pair) and per sample polarity (neutral, +, -), the weighted
successor counts ``ns`` and reward sums ``rs``; ``rho`` is the reference polarity, the human's
response in the last interaction (root pairs: the context's last episode with an interaction;
in-mission pairs: the last episode that executed the pair). The kept set excludes samples of the
opposite non-zero polarity, so n' = n[0] + n[rho] is O(1) per pair whatever the history length.
Value iteration on the filtered model (eqs. 2-3, neutral for unknown pairs) gives Q; the action is
drawn from a Gibbs distribution over Pref = Q~ + t^dQ~ (eqs. 4-6).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..config import HriParams
from ..planning import gibbs, value_iteration
from ..types import FloatArray, IntArray, Interaction, Polarity, Transition
from .base import TabularLearner, interaction_class

__all__ = ["HriLearner"]

_LOG_CAP = float(np.log(1e6))


class HriLearner(TabularLearner[HriParams]):
    """HRI-based model learning with the temporal-measure Gibbs policy.

    Tables: ns (C, P, 3, M) weighted successor counts per polarity; rs (C, P, 3) weighted reward
    sums per polarity; rho (C, P) int8 reference polarity (0 = none).
    """

    algorithm: ClassVar[str] = "hri"
    params_type = HriParams
    _tables: ClassVar[dict[str, tuple[type, str]]] = {
        "ns": (np.float64, "CP3M"),
        "rs": (np.float64, "CP3"),
        "rho": (np.int8, "CP"),
    }
    ns: FloatArray
    rs: FloatArray
    rho: np.ndarray

    def _close(self, rows: list[Transition]) -> None:
        space, prm = self.space, self._params
        iota = interaction_class(space, rows)
        root_pol = {
            Interaction.I1: Polarity.POSITIVE,
            Interaction.I2: Polarity.POSITIVE,
            Interaction.I3: Polarity.NEGATIVE,
            Interaction.NONE: Polarity.NEUTRAL,
        }[iota]
        omega = Polarity(rows[-1].signal) if iota is not Interaction.NONE else Polarity.NEUTRAL
        w = prm.w_i1 if iota is Interaction.I1 else 1.0
        contexts = set()
        for tr in rows:
            c, a = tr.context, tr.action
            pol = root_pol if tr.state == space.OBSERVE else omega
            self.ns[c, a, pol, space.successor_column(a, tr.next_state)] += w
            self.rs[c, a, pol] += w * tr.reward
            contexts.add(c)
            if prm.exclusion == "per_pair" and tr.state != space.OBSERVE:
                self.rho[c, a] = omega
        if prm.exclusion != "none" and iota is not Interaction.NONE:
            for c in contexts:
                self.rho[c, list(space.root_actions)] = root_pol
        for c in contexts:
            self._cache.pop(c, None)

    def _filtered(self, context: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """n'(s,a), r'(s,a), n'(s,a,s') of one context: (P,), (P,), (P, M)."""
        rho = self.rho[context].astype(np.int64)
        pol = np.arange(3)
        keep = (rho[:, None] == 0) | (pol[None, :] == 0) | (pol[None, :] == rho[:, None])
        ns = np.einsum("pkm,pk->pm", self.ns[context], keep)
        rs = np.einsum("pk,pk->p", self.rs[context], keep)
        return ns.sum(axis=1), rs, ns

    def _q(self, context: int) -> FloatArray:
        cached = self._cache.get(context)
        if cached is not None:
            return cached  # type: ignore[no-any-return]
        space, prm, mission = self.space, self._params, self.mission
        n, r, ns = self._filtered(context)
        known = n >= prm.m_h
        safe = np.where(known, n, 1.0)
        reward = np.where(known, r / safe, 0.0)
        unknown_t = np.zeros_like(ns)
        unknown_t[np.arange(space.n_actions), space.end_column] = 1.0
        trans = np.where(known[:, None], ns / safe[:, None], unknown_t)
        fixed = None
        if prm.unknown == "vmax_if_never_tried":
            fixed = self.visits[context] == 0
        q = value_iteration(
            space, reward, trans, gamma=mission.gamma, tol=prm.vi_tol,
            max_sweeps=prm.vi_max_sweeps, fixed=fixed, fixed_value=mission.v_max,
        )
        q = np.clip(q, -mission.v_max, mission.v_max)
        q.setflags(write=False)
        self._cache[context] = q
        return q

    def _plan(self, context: int, episode: int, rng: np.random.Generator | None) -> Any:
        return self._q(context)

    def _tau(self, context: int) -> float:
        prm = self._params
        if prm.kappa == 0.0:
            return prm.tau
        unvisited = float(np.mean(self.visits[context] == 0))
        return prm.tau * (1.0 + prm.kappa * unvisited)

    def _staleness(self, context: int, actions: slice, state: int, episode: int) -> np.ndarray:
        if self._params.staleness == "global":
            t = episode - self.last[context, actions]
        else:
            now = self.ctx_count[context] + (1 if state == self.space.OBSERVE else 0)
            t = now - self.last_ctx[context, actions]
        return np.maximum(t, 1)

    def _pref_parts(self, q: FloatArray, context: int, state: int, episode: int
                    ) -> tuple[FloatArray, FloatArray]:
        """Q~ and M for the actions of one state."""
        actions = self.space.actions_of(state)
        sl = slice(actions.start, actions.stop)
        qs = q[sl] / self.mission.v_max if self._params.pref_scale == "vmax" else q[sl]
        if not self._params.measure:
            return qs, np.zeros_like(qs)
        dq = qs - qs.mean()
        log_t = np.log(self._staleness(context, sl, state, episode).astype(np.float64))
        return qs, np.exp(np.clip(dq * log_t, -30.0, _LOG_CAP))

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        qs, m = self._pref_parts(plan, context, state, episode)
        return gibbs(qs + m, self._tau(context))

    def since_last(self, context: int, episode: int) -> IntArray:
        """t(s, a) as the temporal measure counts it: over all episodes, or over the context's
        episodes with ``staleness="context"`` (where OBSERVE counts the episode being decided)."""
        if self._params.staleness == "global":
            return super().since_last(context, episode)
        now = self.ctx_count[context] + (self.space.pair_state == self.space.OBSERVE)
        out: IntArray = now - self.last_ctx[context]
        return out

    def _kept_visits(self, context: int) -> FloatArray:
        return self._filtered(context)[0]

    def _measure(self, context: int, episode: int) -> FloatArray:
        q = self._q(context)
        out = np.empty(self.space.n_actions, dtype=np.float64)
        for s in range(self.space.n_states):
            actions = self.space.actions_of(s)
            out[actions.start : actions.stop] = self._pref_parts(q, context, s, episode)[1]
        return out
