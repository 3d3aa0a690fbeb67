"""The paper's HRI-based learner (docs/method.md §4-§5).

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
from ..negotiation import interaction_class
from ..planning import gibbs, value_iteration
from ..state import StateFormatError
from ..types import FloatArray, IntArray, Interaction, Polarity, Transition
from .base import TabularLearner, check_nonnegative

__all__ = ["HriLearner"]

_LOG_CAP = float(np.log(1e6))
# The polarities a pair's reference keeps, by reference (none, +, -): the neutral samples and
# those of the reference's polarity; with no reference, every sample.
_KEEP = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 0.0], [1.0, 0.0, 1.0]])
_KEEP.setflags(write=False)


class HriLearner(TabularLearner[HriParams]):
    """HRI-based model learning with the temporal-measure Gibbs policy.

    Tables: ns (C, P, 3, M) weighted successor counts per polarity; rs (C, P, 3) weighted reward
    sums per polarity; rho (C, P) int8 reference polarity (0 = none); rho_episode (C, P) int64,
    the episode whose response set rho (episodes of a fleet may close out of order: the most
    recent episode, not the last to close, is "the last interaction").
    """

    algorithm: ClassVar[str] = "hri"
    params_type = HriParams
    # The temperature, the temporal measure and how it counts: how Q is turned into a choice.
    POLICY_PARAMS: ClassVar[frozenset[str]] = frozenset(
        {"tau", "kappa", "measure", "pref_scale", "staleness"}
    )
    _tables: ClassVar[dict[str, tuple[type, str]]] = {
        "ns": (np.float64, "CP3M"),
        "rs": (np.float64, "CP3"),
        "rho": (np.int8, "CP"),
        "rho_episode": (np.int64, "CP"),
    }
    _reward_sums: ClassVar[dict[str, str]] = {"rs": "ns"}
    ns: FloatArray
    rs: FloatArray
    rho: np.ndarray
    rho_episode: IntArray

    def _observe(self, tr: Transition) -> None:
        if self._params.unknown == "vmax_if_never_tried":
            self._cache.pop(tr.context, None)  # which pairs are pinned depends on the visits

    def _set_rho(self, c: int, actions: list[int], polarity: Polarity, episode: int) -> None:
        rho, rho_episode = self.rho, self.rho_episode
        for a in actions:
            if episode >= rho_episode[c, a]:
                rho[c, a] = polarity
                rho_episode[c, a] = episode

    def _close(self, rows: list[Transition]) -> None:
        space, prm = self.space, self._params
        if not any(tr.state == space.OBSERVE for tr in rows):
            return  # the start of this episode was forgotten (never closed in time): no labels
        iota = interaction_class(space, rows)
        root_pol = {
            Interaction.I1: Polarity.POSITIVE,
            Interaction.I2: Polarity.POSITIVE,
            Interaction.I3: Polarity.NEGATIVE,
            Interaction.NONE: Polarity.NEUTRAL,
        }[iota]
        omega = Polarity(rows[-1].signal) if iota is not Interaction.NONE else Polarity.NEUTRAL
        w = prm.w_i1 if iota is Interaction.I1 else 1.0
        episode, contexts = rows[-1].episode, set()
        for tr in rows:
            c, a = tr.context, tr.action
            pol = root_pol if tr.state == space.OBSERVE else omega
            self.ns[c, a, pol, space.successor_column(a, tr.next_state)] += w
            self.rs[c, a, pol] += w * tr.reward
            contexts.add(c)
            if prm.exclusion == "per_pair" and tr.state != space.OBSERVE:
                self._set_rho(c, [a], omega, episode)
        if prm.exclusion != "none" and iota is not Interaction.NONE:
            for c in contexts:
                self._set_rho(c, list(space.root_actions), root_pol, episode)
        for c in contexts:
            self._cache.pop(c, None)

    def _reinforce(
        self, context: int, action: int, episode: int, reward: float, *, pending: bool
    ) -> None:
        if pending:
            return  # the open row carries the feedback: it is learned with the episode at close
        c, a = context, action
        # The episode's sample sits under rho while that episode still sets the pair's reference;
        # otherwise add to the neutral samples, which every rho keeps, so the feedback counts.
        pol = int(self.rho[c, a]) if self.rho_episode[c, a] == episode else int(Polarity.NEUTRAL)
        counts = self.ns[c, a].sum(axis=1)  # (3,) the weighted sample count per polarity
        if counts.sum() <= 0:
            return  # no sample of this pair was learned (its episode was forgotten while open)
        if counts[pol] <= 0:
            # Never leave a reward sum in a bucket with no samples under it: R^ = r'/n' would
            # charge it to the samples of other buckets, and with few of them kept (n' just
            # above m_h, which may be tiny) R^ could blow up. Put it where the samples are.
            pol = int(np.argmax(counts))
        self.rs[c, a, pol] += reward
        self._cache.pop(c, None)

    def _check_tables(self) -> None:
        check_nonnegative(ns=self.ns, rho_episode=self.rho_episode)
        if not np.isin(self.rho, (0, 1, 2)).all():
            raise StateFormatError("arrays.rho must hold polarities 0, 1 or 2.")
        if np.any(self.rho_episode > self.episodes):
            raise StateFormatError("arrays.rho_episode must not exceed the episodes seen.")

    def _filtered(self, context: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """n'(s,a), r'(s,a), n'(s,a,s') of one context: (P,), (P,), (P, M)."""
        keep = _KEEP[self.rho[context]]
        ns = np.einsum("pkm,pk->pm", self.ns[context], keep)
        rs = np.einsum("pk,pk->p", self.rs[context], keep)
        return ns.sum(axis=1), rs, ns

    def _compute_q(self, context: int, gamma: float | None = None) -> FloatArray:
        space, prm, mission = self.space, self._params, self.mission
        n, r, ns = self._filtered(context)
        known = n >= prm.m_h
        safe = np.where(known, n, 1.0)
        reward = np.where(known, r / safe, 0.0)
        trans = np.where(known[:, None], ns / safe[:, None], space.to_end)
        fixed = None
        if prm.unknown == "vmax_if_never_tried":
            fixed = self.visits[context] == 0
        q = value_iteration(
            space,
            reward,
            trans,
            gamma=mission.gamma if gamma is None else gamma,
            tol=prm.vi_tol,
            max_sweeps=prm.vi_max_sweeps,
            fixed=fixed,
            fixed_value=mission.v_max,
        )
        out: FloatArray = np.minimum(np.maximum(q, -mission.v_max, out=q), mission.v_max, out=q)
        return out

    def _tau(self, context: int) -> float:
        prm = self._params
        if prm.kappa == 0.0:
            return prm.tau
        unvisited = float(np.mean(self.visits[context] == 0))
        return prm.tau * (1.0 + prm.kappa * unvisited)

    def _pref_parts(
        self, q: FloatArray, context: int, state: int, episode: int
    ) -> tuple[FloatArray, FloatArray]:
        """Q~ and M for the actions of one state."""
        actions = self.space.actions_of(state)
        sl = slice(actions.start, actions.stop)
        qs = q[sl] / self.mission.v_max if self._params.pref_scale == "vmax" else q[sl]
        if not self._params.measure:
            return qs, np.zeros_like(qs)
        dq = qs - qs.sum() / qs.shape[0]  # the mean, without np.mean's overhead
        t_eff = np.maximum(self.since_last(context, episode)[sl], 1)
        log_t = np.log(t_eff.astype(np.float64))
        x = dq * log_t
        return qs, np.exp(np.minimum(np.maximum(x, -30.0, out=x), _LOG_CAP, out=x), out=x)

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        qs, m = self._pref_parts(plan, context, state, episode)
        return gibbs(qs + m, self._tau(context))

    def since_last(self, context: int, episode: int) -> IntArray:
        """t(s, a) as the temporal measure counts it: over all episodes, or over the context's
        episodes with ``staleness="context"`` (where OBSERVE counts the episode being decided)."""
        if self._params.staleness == "global":
            return super().since_last(context, episode)
        space = self.space
        begun = self.visits[context, list(space.root_actions)].sum()
        out: IntArray = begun + (space.pair_state == space.OBSERVE) - self.last_ctx[context]
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
