"""Discounted Thompson sampling over the negotiation MDP: our learner for drifting wishes.

Two ideas the paper's learner does without:

- **Known structure.** Responding and inferring are the robot's own bookkeeping: ``infer_type(k)``
  always leads to TYPE_KNOWN(k) with reward 0. Only what the *person* does is uncertain (accept
  an offer, answer a question, like a service), so only human-facing pairs are learned and the
  planner can chain a learned answer into a silent inference at once (one answered query teaches
  the robot what to infer next time).
- **Forgetting plus posterior sampling** (docs/method.md §8: discounted Thompson sampling, Raj
  & Kalyani 2017; forgetting counts n <- lambda * n + 1): each pair's counts decay by
  ``forgetting`` at every new sample of that pair, so stale evidence fades at the speed the pair
  is used, and exploration comes from sampling models from the posterior instead of a
  temperature.

Per decision, ``samples`` models are drawn (Dirichlet successors, Normal mean rewards), each is
solved by value iteration, and the action distribution is the share of models in which each
action is best; the action is drawn from that distribution. The models are drawn at once, but
solved only when a state's distribution is asked, and only as far as that state needs (a
decision in TYPE_KNOWN needs none of the values of the states before it).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ..beliefs import Item
from ..changes import ContextChange, Step, context_names, step_of
from ..config import DtsAdaptParams, DtsParams, DtsRoutineParams
from ..planning import space_levels, value_iteration
from ..space import Action, ActionKind, StateKind
from ..state import StateFormatError
from ..types import FloatArray, IntArray, Polarity, Transition
from .base import TabularLearner, check_nonnegative

__all__ = ["DtsAdaptLearner", "DtsLearner", "DtsRoutineLearner"]


class _Models:
    """The posterior models of one decision: their draws, taken at once (what ``rng`` yields
    must not depend on the states a decision visits), and their Q once solved (``q``, final up
    to pair level ``level``; None: every pair)."""

    __slots__ = ("context", "gammas", "level", "normals", "q")

    def __init__(self, context: int, gammas: FloatArray, normals: FloatArray) -> None:
        self.context = context
        self.gammas = gammas  # (samples, draws): the Dirichlet draws' gamma variates
        self.normals = normals  # (samples * (P + 1),): the rewards' draws, then the answers'
        self.q: FloatArray | None = None
        self.level: int | None = None


def _slice_or_index(rows: IntArray) -> slice | IntArray:
    """``rows`` as a slice when they are contiguous (indexing by a slice is a view, and faster)."""
    if len(rows) and rows[-1] - rows[0] + 1 == len(rows):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return rows


class DtsLearner(TabularLearner[DtsParams]):
    """Tables: dn (C, P) discounted counts, dr (C, P) discounted reward sums, dns (C, P, M)
    discounted successor counts. Silent pairs are never learned (their dynamics are known)."""

    algorithm: ClassVar[str] = "dts"
    params_type = DtsParams
    _tables: ClassVar[dict[str, tuple[type, str]]] = {
        "dn": (np.float64, "CP"),
        "dr": (np.float64, "CP"),
        "dns": (np.float64, "CPM"),
        "answered": (np.float64, "2"),
        "change": (np.float64, "C4"),
    }
    # States exported before the change test existed have no "change" table: it starts at zero.
    _optional_tables: ClassVar[frozenset[str]] = frozenset({"change"})
    dn: FloatArray
    dr: FloatArray
    dns: FloatArray
    answered: FloatArray  # (2,): discounted count and reward sum of services performed as asked
    # (C, 4) per context, for the change test (only kept while change_alpha > 0): services
    # accepted and rejected since the context's last restart, before the current run; the
    # current run of rejected services; and the run's chance if nothing changed (0: no run).
    change: FloatArray

    def _init_tables(self) -> None:
        space = self.space
        self._query_detail = np.asarray(
            [a.kind is ActionKind.QUERY_DETAIL for a in space.actions], dtype=bool
        )
        self._tested: Transition | None = None
        self._perform_pairs = np.flatnonzero(
            np.asarray([a.kind is ActionKind.PERFORM for a in space.actions], dtype=bool)
        )
        self._to_end = space.to_end
        # The pairs a change restarts: every learned pair but the context's offers (root pairs):
        # a person whose wish changed still wants service there.
        self._restartable = np.ones(space.n_actions, dtype=bool)
        self._restartable[list(space.root_actions)] = False
        rewards = self.mission.rewards
        # Successor priors: prior_count each, but with trust_answers a detail question about a
        # service nobody named is answered with prior chance 1/K (only one of K services is the
        # person's): its END successor weighs as much as the details of the K - 1 others.
        self._query_type = np.asarray(
            [a.kind is ActionKind.QUERY_TYPE for a in space.actions], dtype=bool
        )
        prior = np.where(space.succ_mask, self._params.prior_count, 0.0)
        if self._params.trust_answers and len(self.mission.services) > 1:
            for a in np.flatnonzero(self._query_detail):
                answers = float(prior[a].sum() - prior[a, space.end_column[a]])
                prior[a, space.end_column[a]] = answers * (len(self.mission.services) - 1)
        self._succ_prior = prior
        self._answer_prior = (
            rewards.positive + rewards.accepted_service
            if self._params.trust_answers
            else self._params.reward_prior
        )
        # What a decision's models need, laid out once (_plan). A model draws one gamma variate
        # per possible successor: the flat positions of succ_mask in a (P * M) row, in order,
        # which is the stream of drawing the whole (samples, P, M) Dirichlet table (its other
        # entries have parameter 0, draw nothing and are 0).
        M = space.max_succ
        self._succ_flat = np.flatnonzero(space.succ_mask)
        self._prior_flat = prior.ravel()[self._succ_flat]
        # The pairs _fold_answers ends at once: those that earn what a named service is worth
        # (query_type, with trust_answers), then those that earn the answer's value.
        named = (
            self._query_type
            if self._params.trust_answers
            else np.zeros(space.n_actions, dtype=bool)
        )
        folded = self._query_detail | named
        fold_rows = np.concatenate([np.flatnonzero(named), np.flatnonzero(self._query_detail)])
        self._n_named = int(named.sum())
        # Only some rows of the drawn table are used: those of the pairs whose successors the
        # model learns (not silent, not folded, not END-only: an END-only pair adds gamma * 0 to
        # its reward whatever its row says), then the folded ones, for their chance of END. They
        # are normalised as a (samples, rows, M) table: _drawn_cols picks their draws and
        # _drawn_pos places them in its (rows * M) row.
        learned_rows = np.flatnonzero(~space.silent & ~folded & (space.succ_mask.sum(axis=1) > 1))
        drawn = np.concatenate([learned_rows, fold_rows])
        position = np.full(space.n_actions, -1, dtype=np.int64)
        position[drawn] = np.arange(len(drawn))
        rows, cols = np.divmod(self._succ_flat, M)
        use = position[rows] >= 0
        self._drawn_cols = np.flatnonzero(use)
        self._drawn_pos = position[rows[use]] * M + cols[use]
        self._n_drawn = len(drawn)
        self._n_learned = len(learned_rows)
        self._learned_rows = _slice_or_index(learned_rows)
        self._fold_rows = fold_rows  # their columns in the rewards
        # ...and where their END successor is in the normalised table's (rows * M) row
        self._fold_end = (len(learned_rows) + np.arange(len(fold_rows))) * M + space.end_column[
            fold_rows
        ]
        # The other rows of the solved model: a silent pair moves to its target (its first
        # successor); folded and END-only pairs end.
        first = np.zeros_like(self._to_end)
        first[:, 0] = 1.0
        self._base_trans = np.where(space.silent[:, None], first, self._to_end)
        self._silent_rows = np.flatnonzero(space.silent)
        self._silent_reward = space.silent_reward[self._silent_rows]
        # How far a state's policy needs the models solved: the highest level of its pairs.
        levels = space_levels(space)
        self._state_level = (
            None
            if levels is None
            else [int(x) for x in np.maximum.reduceat(levels, space.state_start)]
        )

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
        if space.actions[tr.action].kind is ActionKind.PERFORM:
            before = self._pending.get(tr.episode)
            if (
                before
                and before[-1].next_state == tr.state
                and space.is_query[before[-1].action]
                and before[-1].state != space.ENGAGED
            ):
                # The service the person named when asked: how well "doing as asked" pays.
                lam = self._params.forgetting
                self.answered *= lam
                self.answered += (1.0, tr.reward)
                self._cache.clear()
        kind = space.actions[tr.action].kind
        if (
            self._params.change_alpha > 0.0
            and tr.signal != Polarity.NEUTRAL
            and (
                kind is ActionKind.PERFORM
                or (
                    self._params.change_on_questions
                    and tr.signal == Polarity.NEGATIVE
                    and kind is ActionKind.QUERY_DETAIL
                )
            )
        ):
            # Tested before the sample is learned: a restart keeps the answer that set it off.
            self._tested = tr  # for the record of a change it decides
            self._test_change(tr.context, accepted=tr.signal == Polarity.POSITIVE)
        column = space.successor_column(tr.action, tr.next_state)
        self._add(tr.context, tr.action, tr.reward, column)
        human_initiated = (
            tr.state == space.OBSERVE and tr.action == space.PASS and tr.next_state != space.END
        )
        if human_initiated and self._params.i1_as_acceptance:
            accept = space.successor_column(space.INITIATE, space.ENGAGED)
            self._add(tr.context, space.INITIATE, self.mission.rewards.positive, accept)

    @property
    def decides_changes(self) -> bool:
        return self._params.change_alpha > 0.0

    def _favourite(self, c: int) -> Item | None:
        """The service and detail the context's posterior expects to pay best when performed
        (among those performed there), or None when none is expected to pay more than 0."""
        perform = self._perform_pairs
        tried = perform[self.dn[c, perform] > 0]
        if not len(tried):
            return None
        mean, _ = self._reward_posterior(c)
        best = int(tried[np.argmax(mean[tried])])
        if mean[best] <= 0.0:
            return None
        act = self.space.actions[best]
        assert act.service is not None
        return Item(act.service, act.detail)

    def _test_change(self, c: int, *, accepted: bool) -> None:
        """The per-context change test (docs/method.md §8, "Adapting after a change").

        With a accepted and b rejected services in context c before the current run of k
        rejections, the chance of that run if nothing changed is the Beta(a+1, b+1) posterior
        predictive of k rejections in a row, prod_{i<k} (b+1+i) / (a+b+2+i). Below
        ``change_alpha`` the context's service-facing counts are scaled by ``change_keep`` and
        its test starts over.
        """
        row = self.change[c]
        if accepted:
            row[0] += 1.0
            row[1] += row[2]
            row[2] = 0.0
            row[3] = 0.0
            return
        # One more factor of the product: plain arithmetic, so replays agree on every machine.
        a, b, i = float(row[0]) + 1.0, float(row[1]) + 1.0, float(row[2])
        row[3] = (row[3] if i > 0 else 1.0) * ((b + i) / (a + b + i))
        row[2] += 1.0
        if row[3] < self._params.change_alpha:
            tr = self._tested
            slot, situation = context_names(self.space, c)
            self._decide(
                ContextChange(
                    episode=0 if tr is None else tr.episode,
                    context=c,
                    time_slot=slot,
                    situation=situation,
                    before=self._favourite(c),
                    now=None,
                    source="change_test",
                    evidence=() if tr is None else (step_of(self.space, tr),),
                    figures={
                        "accepted": float(a - 1.0),
                        "rejected_before": float(b - 1.0),
                        "run": float(row[2]),
                        "p": float(row[3]),
                        "alpha": float(self._params.change_alpha),
                    },
                )
            )
            keep = self._params.change_keep
            mask = self._restartable
            self.dn[c, mask] *= keep
            self.dr[c, mask] *= keep
            self.dns[c, mask] *= keep
            row[:] = 0.0
            self._cache.pop(c, None)

    def _reinforce(
        self, context: int, action: int, episode: int, reward: float, *, pending: bool
    ) -> None:
        c, a = context, action
        if self.space.silent[action] or self.dn[c, a] <= 0:
            return  # silent pairs are not learned (their reward is known)
        self.dr[c, a] += reward  # as if the latest sample (weight 1 in the sums) earned more
        self._cache.pop(c, None)

    # -- the posterior -------------------------------------------------------------------------
    def _posterior(self, context: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Mean reward (P,), its standard deviation (P,), Dirichlet parameters (P, M), and the
        known transition of silent pairs (P, M)."""
        space = self.space
        mean, sd = self._reward_posterior(context)
        alpha = np.where(space.succ_mask, self.dns[context] + self._succ_prior, 0.0)
        known = np.zeros_like(alpha)
        known[space.silent, 0] = 1.0  # a silent pair's first successor is its deterministic target
        return mean, sd, alpha, known

    def _reward_posterior(self, context: int) -> tuple[FloatArray, FloatArray]:
        """Mean reward (P,) and its standard deviation (P,); a silent pair's reward is known."""
        prm = self._params
        n = self.dn[context] + prm.reward_prior_count
        mean = (self.dr[context] + prm.reward_prior * prm.reward_prior_count) / n
        sd = prm.reward_sd / np.sqrt(n)
        mean[self._silent_rows] = self._silent_reward
        sd[self._silent_rows] = 0.0
        return mean, sd

    def _answer_posterior(self) -> tuple[float, float]:
        """Mean and sd of the reward of performing the service the person named when asked."""
        prm = self._params
        n, total = float(self.answered[0]), float(self.answered[1])
        prior = self._answer_prior
        mean = (total + prior * prm.reward_prior_count) / (n + prm.reward_prior_count)
        return mean, prm.reward_sd / float(np.sqrt(n + prm.reward_prior_count))

    def _fold_answers(
        self, reward: FloatArray, trans: FloatArray, v_answer: FloatArray, gamma: float
    ) -> tuple[FloatArray, FloatArray]:
        """Asking for the detail ends, in the model, with the answered service performed:
        Q(query_detail) = r + gamma * P(answer) * V_answer. This is what makes a question worth
        its cost before any service of that context was ever liked."""
        space = self.space
        qd = self._query_detail
        rows = np.flatnonzero(qd)
        p_answer = 1.0 - trans[..., rows, space.end_column[rows]]
        reward = reward.copy()
        reward[..., rows] += gamma * p_answer * v_answer[..., None]
        ends = qd
        if self._params.trust_answers:
            # A named service is the person's: the detail question that follows is answered.
            qt = np.flatnonzero(self._query_type)
            p_named = 1.0 - trans[..., qt, space.end_column[qt]]
            v_named = self.mission.rewards.query + gamma * v_answer
            reward[..., qt] += gamma * p_named * v_named[..., None]
            ends = qd | self._query_type
        trans = np.where(ends[:, None], self._to_end, trans)
        return reward, trans

    def _compute_q(self, context: int, gamma: float | None = None) -> FloatArray:
        """Q of the posterior-mean model."""
        gamma = self.mission.gamma if gamma is None else gamma
        mean, _, alpha, known = self._posterior(context)
        silent = self.space.silent[:, None]
        trans = np.where(silent, known, alpha / alpha.sum(axis=1, keepdims=True))
        v_answer = np.asarray(self._answer_posterior()[0])
        return self._solve(*self._fold_answers(mean, trans, v_answer, gamma), gamma=gamma)

    def _check_tables(self) -> None:
        check_nonnegative(dn=self.dn, dns=self.dns, answered=self.answered[:1], change=self.change)
        if np.any(self.change[:, 3] > 1.0):
            raise StateFormatError("arrays.change: a run's chance must not exceed 1.")

    def _solve(
        self,
        reward: FloatArray,
        trans: FloatArray,
        level: int | None = None,
        *,
        gamma: float | None = None,
    ) -> FloatArray:
        v_max = self.mission.v_max
        q = value_iteration(
            self.space,
            reward,
            trans,
            gamma=self.mission.gamma if gamma is None else gamma,
            tol=self._params.vi_tol,
            max_sweeps=self._params.vi_max_sweeps,
            level=level,
        )
        return np.minimum(np.maximum(q, -v_max, out=q), v_max, out=q)

    def _plan(self, context: int, episode: int, rng: np.random.Generator | None) -> _Models:
        """The ``samples`` models of one decision, drawn from the posterior now (``_models``
        builds them and ``_solved`` solves them when a policy needs their Q).

        From ``rng``, in this order: every model's gamma variates for the Dirichlet draw of each
        pair's successors (silent pairs' too, though they are not used), then every model's
        Normal draw of each pair's mean reward, then every model's Normal draw of the value of
        doing as asked (``_fold_answers``).
        """
        if rng is None:  # explain(): a fixed draw, so the view is stable for a given model
            rng = np.random.default_rng([self.version, context])
        k = self._params.samples
        alpha = self.dns[context].ravel()[self._succ_flat] + self._prior_flat
        gammas = rng.standard_gamma(alpha[None, :].repeat(k, axis=0))
        normals = rng.standard_normal(k * (self.space.n_actions + 1))
        return _Models(context, gammas, normals)

    def _models(self, plan: _Models) -> tuple[FloatArray, FloatArray]:
        """Rewards (samples, P) and transitions (samples, P, M) of a decision's models, with
        the answers folded in (``_fold_answers``, for all its pairs at once)."""
        space, k = self.space, self._params.samples
        P, M = space.n_actions, space.max_succ
        flat = np.zeros((k, self._n_drawn * M), dtype=np.float64)
        flat[:, self._drawn_pos] = plan.gammas.take(self._drawn_cols, axis=1)
        g = flat.reshape(k, self._n_drawn, M)
        total = np.add.reduce(g, axis=2, keepdims=True)  # what g.sum does
        sampled = g / np.maximum(total, 1e-300, out=total)
        trans = np.empty((k, P, M), dtype=np.float64)
        trans[...] = self._base_trans
        trans[:, self._learned_rows] = sampled[:, : self._n_learned]
        mean, sd = self._reward_posterior(plan.context)
        reward = mean + sd * plan.normals[: k * P].reshape(k, P)
        a_mean, a_sd = self._answer_posterior()
        v_answer = a_mean + a_sd * plan.normals[k * P :]
        gamma = self.mission.gamma
        gain = 1.0 - sampled.reshape(k, -1).take(self._fold_end, axis=1)  # P(answer)
        gain *= gamma
        n = self._n_named
        if n:
            gain[:, :n] *= (self.mission.rewards.query + gamma * v_answer)[:, None]
        gain[:, n:] *= v_answer[:, None]
        rows = self._fold_rows
        reward[:, rows] = reward.take(rows, axis=1) + gain
        return reward, trans

    def _solved(self, plan: _Models, state: int) -> FloatArray:
        """Q (samples, P) of a decision's models, final for the pairs of ``state`` and of the
        states it can lead to (those of higher levels may be unfinished). Solved once, as far as
        the first state asked needs: a decision asks its observed state, then the states its
        silent steps lead to, which need less; explain asks OBSERVE first, which needs all. A
        state that needs more solves them again, further."""
        level = None if self._state_level is None else self._state_level[state]
        if plan.q is None or (plan.level is not None and (level is None or level > plan.level)):
            plan.q = self._solve(*self._models(plan), level=level)
            plan.level = level
        return plan.q

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        actions = self.space.actions_of(state)
        q = self._solved(plan, state)
        best = q[:, actions.start : actions.stop].argmax(axis=1)
        out: FloatArray = np.bincount(best, minlength=len(actions)) / best.shape[0]
        return out

    def _kept_visits(self, context: int) -> FloatArray:
        out: FloatArray = self.dn[context].copy()
        return out


class DtsAdaptLearner(DtsLearner):
    """DTS with the defaults that adapt after a change (:class:`DtsAdaptParams`); the same
    tables, so the same export format under its own algorithm name."""

    algorithm: ClassVar[str] = "dts-adapt"
    params_type = DtsAdaptParams


class DtsRoutineLearner(DtsLearner):
    """DTS with the person's routine per context (docs/method.md §8, "``dts-routine``").

    The DTS tables learn as in ``dts-adapt``; beside them, per context, the **routine**: the
    service and detail the person last took there (a performed service they accepted), and how
    far it is trusted. It steers the negotiation:

    - a *trusted* routine (taken, and not refused since) is followed: the robot offers (unless
      the latest offer there was turned down), infers its service and its detail;
    - once the routine was refused, the robot *asks* there (which service, then which detail)
      until the person takes a service again: a refusal of something it was sure of is
      evidence about that context only, and the person's answer settles it;
    - where no routine is held yet, the robot asks rather than guesses.

    Elsewhere (whether to offer where no routine is trusted) the posterior draws decide, as in
    DTS. A routine replaced by another service or detail the person took, or dropped because
    the person kept turning offers down there, is a change the learner decided (``changes``).

    Tables, beside DTS's: ``routine`` (C, P): in each context at most one non-zero entry, at the
    ``perform`` pair of the routine's service and detail: the number of times in a row it was
    taken (> 0: trusted), or minus the number of times it was refused since (< 0: in doubt).
    ``offers`` (C, 4): the test on offers that drops a routine (``offer_alpha``): offers taken
    (and requests) since the routine was last dropped, those turned down before the current
    run, the current run of offers turned down, and the run's chance if nothing changed.
    """

    algorithm: ClassVar[str] = "dts-routine"
    params_type = DtsRoutineParams
    _tables: ClassVar[dict[str, tuple[type, str]]] = {
        **DtsLearner._tables,
        "routine": (np.float64, "CP"),
        "offers": (np.float64, "C4"),
    }
    routine: FloatArray
    offers: FloatArray
    _params: DtsRoutineParams

    def _init_tables(self) -> None:
        super()._init_tables()
        space = self.space
        # Per service: its infer_type pair; per perform pair: its infer_detail pair and service.
        self._infer_type: dict[str, int] = {}
        self._infer_detail: dict[int, int] = {}
        for p, act in enumerate(space.actions):
            if act.kind is ActionKind.INFER_TYPE:
                assert act.service is not None
                self._infer_type[act.service] = p
        for pair in self._perform_pairs.tolist():
            act = space.actions[pair]
            assert act.service is not None
            assert act.detail is not None
            infer = space.action_index(Action(ActionKind.INFER_DETAIL, act.service, act.detail))
            self._infer_detail[pair] = infer

    @property
    def decides_changes(self) -> bool:
        return self._params.routine or self._params.change_alpha > 0.0

    # -- the routine ---------------------------------------------------------------------------
    def held(self, context: int) -> tuple[int, float] | None:
        """The routine of ``context``: its ``perform`` pair and its trust (> 0: taken that many
        times in a row; < 0: refused that many times since), or None."""
        row = self.routine[context]
        nz = np.flatnonzero(row)
        if not len(nz):
            return None
        a = int(nz[0])
        return a, float(row[a])

    def _item(self, pair: int) -> Item:
        act = self.space.actions[pair]
        assert act.service is not None
        return Item(act.service, act.detail)

    def _observe(self, tr: Transition) -> None:
        super()._observe(tr)
        space = self.space
        kind = space.actions[tr.action].kind
        c = tr.context
        if kind is ActionKind.PERFORM and tr.signal != Polarity.NEUTRAL:
            held = self.held(c)
            if tr.signal == Polarity.POSITIVE:
                if held is not None and held[0] == tr.action:
                    self.routine[c, tr.action] = max(held[1], 0.0) + 1.0
                else:
                    if held is not None and self._params.routine:
                        self._switched(tr, held)
                    self.routine[c] = 0.0
                    self.routine[c, tr.action] = 1.0
            elif held is not None and held[0] == tr.action:
                self.routine[c, tr.action] = min(held[1], 0.0) - 1.0
        elif kind is ActionKind.INITIATE or (
            kind is ActionKind.PASS and tr.next_state != space.END
        ):
            self._test_offer(tr)

    def _switched(self, tr: Transition, held: tuple[int, float]) -> None:
        """The person took another service or detail where a routine was held: a change."""
        before, trust = held
        c = tr.context
        episode_steps = [
            step_of(self.space, t)
            for t in self._pending.get(tr.episode, [])
            if not self.space.silent[t.action]
        ]
        refused = []
        if trust < 0 and self.last[c, before] > 0:
            # The latest refusal of the routine: its pair's last execution.
            refused.append(
                Step(int(self.last[c, before]), self.space.action_name(before), "rejected")
            )
        slot, situation = context_names(self.space, c)
        self._decide(
            ContextChange(
                episode=tr.episode,
                context=c,
                time_slot=slot,
                situation=situation,
                before=self._item(before),
                now=self._item(tr.action),
                source="routine",
                evidence=(*refused, *episode_steps, step_of(self.space, tr)),
                figures={"refused": max(-trust, 0.0)},
            )
        )

    def _test_offer(self, tr: Transition) -> None:
        """The test on offers (``offer_alpha``; the arithmetic of the change test, §8)."""
        c = tr.context
        row = self.offers[c]
        if tr.next_state != self.space.END:  # an offer taken, or a request after a pass
            row[0] += 1.0
            row[1] += row[2]
            row[2] = 0.0
            row[3] = 0.0
            return
        a, b, i = float(row[0]) + 1.0, float(row[1]) + 1.0, float(row[2])
        row[3] = (row[3] if i > 0 else 1.0) * ((b + i) / (a + b + i))
        row[2] += 1.0
        held = self.held(c)
        if held is None or not row[3] < self._params.offer_alpha or not self._params.routine:
            return
        slot, situation = context_names(self.space, c)
        self._decide(
            ContextChange(
                episode=tr.episode,
                context=c,
                time_slot=slot,
                situation=situation,
                before=self._item(held[0]),
                now=None,
                source="routine",
                evidence=(step_of(self.space, tr),),
                figures={
                    "offers_taken": float(a - 1.0),
                    "offers_refused_before": float(b - 1.0),
                    "run": float(row[2]),
                    "p": float(row[3]),
                    "alpha": float(self._params.offer_alpha),
                },
            )
        )
        self.routine[c] = 0.0
        row[:] = 0.0

    # -- decisions -----------------------------------------------------------------------------
    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        steered = self._steer(context, state)
        if steered is not None:
            return steered
        return super()._policy(plan, context, state, episode)

    def _steer(self, context: int, state: int) -> FloatArray | None:
        """The routine's choice in ``state`` (a one-hot distribution), or None to leave it to
        the posterior draws."""
        prm = self._params
        space = self.space
        info = space.states[state]
        held = self.held(context)
        service = None if held is None else space.actions[held[0]].service
        trusted = held is not None and held[1] > 0.0
        # Ask where the routine is in doubt (or names another service than the one settled),
        # or where none is held yet.
        ask = prm.ask_unknown if held is None else prm.ask_in_doubt
        actions = space.actions_of(state)
        choice: int | None = None
        if info.kind is StateKind.OBSERVE:
            if prm.routine_offers and trusted and self.offers[context, 2] == 0.0:
                choice = space.INITIATE
        elif info.kind is StateKind.ENGAGED:
            if trusted and prm.routine:
                assert service is not None
                choice = self._infer_type[service]
            elif ask and not trusted:
                choice = actions.start  # query_type
        elif info.kind is StateKind.TYPE_KNOWN:
            if trusted and prm.routine and service == info.service:
                assert held is not None
                choice = self._infer_detail[held[0]]
            elif ask and not (trusted and service == info.service):
                choice = actions.start  # query_detail
        if choice is None:
            return None
        out = np.zeros(len(actions), dtype=np.float64)
        out[choice - actions.start] = 1.0
        return out

    def _check_tables(self) -> None:
        super()._check_tables()
        check_nonnegative(offers=self.offers)
        if np.any(self.offers[:, 3] > 1.0):
            raise StateFormatError("arrays.offers: a run's chance must not exceed 1.")
        if np.any((self.routine != 0.0).sum(axis=1) > 1):
            raise StateFormatError("arrays.routine: a context holds at most one routine.")
        if np.any(self.routine[:, ~np.isin(np.arange(self.space.n_actions), self._perform_pairs)]):
            raise StateFormatError("arrays.routine: a routine is a performed service's pair.")
