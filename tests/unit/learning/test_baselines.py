"""R-MAX, Q-learning and discounted Thompson sampling against docs/method.md §6-§8 (and the
DTS learner's own docstring), on hand-built histories with hand-computed expectations."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from app.learning import (
    Observation,
    Transition,
    make_learner,
)
from app.learning.learners import DtsLearner, QLearner, RmaxLearner, TabularLearner
from tests.support.office import (
    DK,
    END,
    ENGAGED,
    INFER_DRINK,
    INFER_TEA,
    INITIATE,
    MISSION,
    NEG,
    NEU,
    OBS,
    PASS,
    PERFORM_TEA,
    POS,
    QUERY_TYPE,
    REQ,
    RESPOND,
    TK,
    VMAX,
    G,
    S,
)


def learner(algorithm: str, **params: Any) -> TabularLearner[Any]:
    return make_learner(algorithm, params, MISSION)


def i3(ep: int, c: int = 0, reward: float = -2.0) -> list[Transition]:
    return [Transition(ep, c, OBS, INITIATE, reward, END, NEG)]


def i0(ep: int, c: int = 0) -> list[Transition]:
    return [Transition(ep, c, OBS, PASS, 0.0, END, NEU)]


def i1(ep: int, c: int = 0) -> list[Transition]:
    return [
        Transition(ep, c, OBS, PASS, 0.0, REQ, POS),
        Transition(ep, c, REQ, RESPOND, 1.0, TK),
        Transition(ep, c, TK, INFER_TEA, 0.0, DK),
        Transition(ep, c, DK, PERFORM_TEA, 6.0, END, POS),
    ]


def i2(ep: int, c: int = 0, reward: float = 6.0) -> list[Transition]:
    return [
        Transition(ep, c, OBS, INITIATE, 1.0, ENGAGED, POS),
        Transition(ep, c, ENGAGED, INFER_DRINK, 0.0, TK),
        Transition(ep, c, TK, INFER_TEA, 0.0, DK),
        Transition(ep, c, DK, PERFORM_TEA, reward, END, POS if reward > 0 else NEG),
    ]


def probs(lr: TabularLearner[Any], state: int, episode: int, c: int = 0) -> list[float]:
    r = S.actions_of(state)
    return [float(p) for p in lr.explain(c, episode).probabilities[r.start : r.stop]]


class TestRmax:
    def test_unknown_pairs_are_at_vmax_and_ties_are_uniform(self) -> None:
        lr = learner("rmax")
        assert isinstance(lr, RmaxLearner)
        assert lr.explain(0, 1).q == pytest.approx(np.full(S.n_actions, VMAX), rel=1e-12)
        assert probs(lr, OBS, 1) == [0.5, 0.5]
        assert probs(lr, TK, 1) == [0.25] * 4
        picks = {
            lr.select_action(Observation(0, OBS, 1), np.random.default_rng(s)).action
            for s in range(20)
        }
        assert picks == {INITIATE, PASS}  # a seeded tie-break, not always the first

    def test_known_after_m_visits(self) -> None:
        lr = learner("rmax")  # m = 2
        lr.update(i3(1))
        assert lr.explain(0, 2).q[INITIATE] == pytest.approx(VMAX, rel=1e-12)
        lr.update(i3(2))
        q = lr.explain(0, 3).q
        assert q[INITIATE] == pytest.approx(-2.0)  # known: r/n, and END has value 0
        assert q[PASS] == pytest.approx(VMAX, rel=1e-12)
        assert probs(lr, OBS, 3) == [0.0, 1.0]  # greedy
        lr1 = learner("rmax", m=1)
        lr1.update(i3(1))
        assert lr1.explain(0, 2).q[INITIATE] == pytest.approx(-2.0)

    def test_empirical_model_by_hand(self) -> None:
        lr = learner("rmax")
        lr.update(i0(1))
        lr.update(i1(2))
        q = lr.explain(0, 3).q
        # pass: n = 2, reward 0, half to END (0), half to REQUEST(drink), whose respond has
        # n = 1 < m so it is at Vmax.
        assert q[RESPOND] == pytest.approx(VMAX, rel=1e-12)
        assert q[PASS] == pytest.approx(G * 0.5 * VMAX, rel=1e-12)
        assert q[PASS] == pytest.approx(27.0)
        lr.update(i1(3))
        q = lr.explain(0, 4).q
        # Now the whole I1 path is known: perform 6, infer 5.4, respond 1 + 0.9 * 5.4; pass
        # still has one sample of three to END.
        v_tk = max(G * 6.0, VMAX)  # query_detail and two infer_details are still unknown
        assert q[INFER_TEA] == pytest.approx(G * 6.0)
        assert q[RESPOND] == pytest.approx(1.0 + G * v_tk)
        assert q[PASS] == pytest.approx(G * (2 / 3) * (1.0 + G * v_tk))

    def test_greedy_with_ties_among_the_best(self) -> None:
        lr = learner("rmax", m=1)
        lr.update(
            [
                Transition(1, 0, OBS, INITIATE, 1.0, ENGAGED, POS),
                Transition(1, 0, ENGAGED, QUERY_TYPE, -0.5, TK, POS),
            ]
        )
        q = lr.explain(0, 2).q
        assert q[QUERY_TYPE] == pytest.approx(-0.5 + G * VMAX)  # 53.5 < Vmax
        assert probs(lr, ENGAGED, 2) == pytest.approx([0.0, 1 / 3, 1 / 3, 1 / 3])

    @pytest.mark.parametrize("freeze", [True, False])
    def test_freeze_known(self, freeze: bool) -> None:
        lr = learner("rmax", m=2, freeze_known=freeze)
        lr.update(i3(1))
        lr.update(i3(2))
        for ep in (3, 4, 5):  # three accepted initiations (the episodes stay open)
            lr.update([Transition(ep, 0, OBS, INITIATE, 1.0, ENGAGED, POS)])
        view = lr.explain(0, 6)
        assert view.kept_visits is not None  # R-MAX's model counts n(s, a)
        if freeze:
            assert view.q[INITIATE] == pytest.approx(-2.0)  # the model stopped at n = m
            assert view.kept_visits[INITIATE] == 2
        else:
            # n = 5: mean reward (-4 + 3) / 5, 3/5 of the mass to ENGAGED (all unknown: Vmax).
            assert view.q[INITIATE] == pytest.approx(-0.2 + G * 0.6 * VMAX)
            assert view.kept_visits[INITIATE] == 5
        assert view.visits[INITIATE] == 5  # raw visits always count


class TestQLearning:
    def test_update_rule_by_hand(self) -> None:
        lr = learner("qlearning")
        assert isinstance(lr, QLearner)
        lr.update([Transition(1, 0, ENGAGED, QUERY_TYPE, 2.0, TK, POS)])
        q = lr.explain(0, 1).q
        assert q[QUERY_TYPE] == pytest.approx(2.0)  # alpha = 1/1; max Q(TK) = 0
        lr.update([Transition(2, 0, OBS, INITIATE, 1.0, ENGAGED, POS)])
        assert lr.explain(0, 2).q[INITIATE] == pytest.approx(1.0 + G * 2.0)  # 2.8
        lr.update(i3(3))  # n = 2: alpha = 1/2, target -2 (END has Q = 0)
        assert lr.explain(0, 3).q[INITIATE] == pytest.approx(2.8 + 0.5 * (-2.0 - 2.8))  # 0.4
        lr.update(i3(4))  # alpha = 1/3
        assert lr.explain(0, 4).q[INITIATE] == pytest.approx(0.4 + (-2.0 - 0.4) / 3)  # -0.4

    @pytest.mark.parametrize("alpha_min", [0.1, 0.25])
    def test_step_size_floor(self, alpha_min: float) -> None:
        lr = learner("qlearning", alpha_min=alpha_min)
        q = 0.0
        for n in range(1, 31):
            reward = 3.0 if n % 3 else -2.0
            lr.update([Transition(n, 0, OBS, PASS, reward, END, NEU)])
            q += max(alpha_min, 1.0 / n) * (reward - q)
            assert lr.explain(0, n).q[PASS] == pytest.approx(q, rel=1e-12), n

    def test_initial_value(self) -> None:
        lr = learner("qlearning", q0=3.0)
        assert np.all(lr.explain(0, 1).q == 3.0)
        lr.update(i3(1))
        assert lr.explain(0, 2).q[INITIATE] == pytest.approx(-2.0)
        lr.update([Transition(2, 0, OBS, PASS, 0.0, REQ, POS)])
        assert lr.explain(0, 3).q[PASS] == pytest.approx(0.0 + G * 3.0)  # bootstraps on q0

    @pytest.mark.parametrize("episode", [1, 2, 10, 30, 49, 50, 51, 200])
    def test_epsilon_schedule(self, episode: int) -> None:
        lr = learner("qlearning")
        assert isinstance(lr, QLearner)
        eps = max(0.01, 0.3 * 0.93 ** (episode - 1))
        assert lr.epsilon(episode) == pytest.approx(eps, rel=1e-12)
        lr.update(i3(1))  # Q(initiate) = -2 < Q(pass) = 0
        assert probs(lr, OBS, episode) == pytest.approx([eps / 2, 1 - eps + eps / 2], rel=1e-12)
        assert probs(lr, TK, episode) == [0.25] * 4  # all tied: uniform

    def test_epsilon_reaches_its_floor_near_event_50(self) -> None:
        lr = learner("qlearning")
        assert isinstance(lr, QLearner)
        assert lr.epsilon(1) == 0.3
        assert lr.epsilon(45) > 0.01
        assert lr.epsilon(50) == 0.01
        assert lr.epsilon(10**12) == 0.01

    def test_boltzmann(self) -> None:
        lr = learner("qlearning", exploration="boltzmann", temperature=0.5)
        assert probs(lr, OBS, 1) == [0.5, 0.5]
        lr.update(i3(1))
        w = math.exp(-2.0 / 0.5)
        assert probs(lr, OBS, 2) == pytest.approx([w / (1 + w), 1 / (1 + w)], rel=1e-12)
        assert probs(lr, OBS, 10**6) == pytest.approx([w / (1 + w), 1 / (1 + w)], rel=1e-12)

    def test_silent_steps_are_learned_too(self) -> None:
        lr = learner("qlearning")
        lr.update(i2(1))
        q = lr.explain(0, 2).q
        # In report order: initiate (max Q(ENGAGED) still 0), infer_type, infer_detail (their
        # successors still 0), then perform: each with alpha = 1.
        assert q[INITIATE] == pytest.approx(1.0)
        assert q[INFER_DRINK] == 0.0
        assert q[INFER_TEA] == 0.0
        assert q[PERFORM_TEA] == pytest.approx(6.0)
        lr.update(i2(2))  # alpha = 1/2 everywhere
        q = lr.explain(0, 3).q
        assert q[INITIATE] == pytest.approx(1.0)  # max Q(ENGAGED) = 0 still at that moment
        assert q[INFER_DRINK] == pytest.approx(0.5 * G * 0.0)
        assert q[INFER_TEA] == pytest.approx(0.5 * (G * 6.0))
        assert q[PERFORM_TEA] == pytest.approx(6.0)


DTS_PARAMS: dict[str, Any] = {
    "forgetting": 0.8,
    "prior_count": 0.25,
    "reward_prior": 0.0,
    "reward_prior_count": 1.0,
    "reward_sd": 1.0,
    "samples": 8,
}


def dts(**params: Any) -> DtsLearner:
    lr = learner("dts", **{**DTS_PARAMS, **params})
    assert isinstance(lr, DtsLearner)
    return lr


class TestDts:
    def test_silent_pairs_are_never_learned(self) -> None:
        lr = dts()
        lr.update(i2(1))
        lr.update(i1(2))
        view = lr.explain(0, 3)
        for silent in (INFER_DRINK, INFER_TEA, RESPOND):
            assert view.visits[silent] >= 1
            assert view.kept_visits is not None
            assert view.kept_visits[silent] == 0.0
        assert view.kept_visits is not None
        assert view.kept_visits[PERFORM_TEA] == pytest.approx(0.8 * 1.0 + 1.0)

    @pytest.mark.parametrize("forgetting", [0.8, 0.5, 1.0])
    def test_forgetting_decays_counts(self, forgetting: float) -> None:
        lr = dts(forgetting=forgetting)
        lr.update(i0(1))
        for ep in (2, 3, 4):
            lr.update(i3(ep))
        lam = forgetting
        n = lam * (lam * 1.0 + 1.0) + 1.0  # n <- lambda * n + 1, three times from 0
        kept = lr.explain(0, 5).kept_visits
        assert kept is not None
        assert kept[INITIATE] == pytest.approx(n)
        assert kept[PASS] == pytest.approx(1.0)  # a pair decays only when it gets a sample
        assert lr.dr[0, INITIATE] == pytest.approx(-2.0 * n)
        assert lr.dns[0, INITIATE, S.end_column[INITIATE]] == pytest.approx(n)

    def test_counts_stay_bounded_under_forgetting(self) -> None:
        lr = dts(forgetting=0.8)
        for ep in range(1, 201):
            lr.update(i3(ep))
        kept = lr.explain(0, 201).kept_visits
        assert kept is not None
        assert kept[INITIATE] == pytest.approx(1.0 / (1.0 - 0.8))

    @pytest.mark.parametrize("as_acceptance", [True, False])
    def test_human_initiated_episode_counts_as_accepted_initiation(
        self, as_acceptance: bool
    ) -> None:
        lr = dts(i1_as_acceptance=as_acceptance)
        lr.update(i1(1))
        kept = lr.explain(0, 2).kept_visits
        assert kept is not None
        assert kept[PASS] == pytest.approx(1.0)
        if as_acceptance:
            assert kept[INITIATE] == pytest.approx(1.0)
            assert lr.dr[0, INITIATE] == pytest.approx(MISSION.rewards.positive)
            column = S.successor_column(INITIATE, ENGAGED)
            assert lr.dns[0, INITIATE, column] == pytest.approx(1.0)
        else:
            assert kept[INITIATE] == 0.0
        assert lr.explain(0, 2).visits[INITIATE] == 0  # the robot itself never initiated

    @pytest.mark.parametrize("samples", [1, 4, 8, 32])
    def test_probabilities_are_argmax_shares(self, samples: int) -> None:
        lr = dts(samples=samples)
        for ep in range(1, 6):
            lr.update(i2(ep, reward=6.0 if ep % 2 else -2.0))
        rng = np.random.default_rng(0)
        for state in range(S.n_states):
            for episode in (6, 7):
                d = lr.select_action(Observation(0, state, episode), rng)
                for p in [d.probabilities, *(step.probabilities for step in d.chain)]:
                    if len(p) > 1:
                        shares = np.asarray(p) * samples
                        assert np.allclose(shares, np.round(shares), atol=1e-9), p
        view = lr.explain(0, 6).probabilities
        assert np.allclose(view * samples, np.round(view * samples), atol=1e-9)

    def test_explain_is_stable_for_a_given_model(self) -> None:
        lr = dts()
        lr.update(i2(1))
        first = lr.explain(0, 2).probabilities
        assert np.array_equal(first, lr.explain(0, 2).probabilities)

    def test_strong_evidence_decides(self) -> None:
        lr = dts(forgetting=1.0, samples=16)
        for ep in range(1, 41):
            lr.update(i3(ep))
        assert probs(lr, OBS, 41)[1] >= 0.75  # initiate: -2 forty times; pass: unknown
