"""The HRI learner against docs/method.md §4-§5, on small hand-built histories.

Every expected number is worked out by hand from the spec (office mission: gamma 0.9, Vmax 60,
r_pos 1, r_acc 5, r_neg -2, r_q -0.5), not read back from the code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from app.learning import (
    ActionKind,
    Interaction,
    Observation,
    Transition,
    make_learner,
)
from app.learning.learners import HriLearner
from app.learning.negotiation import interaction_class
from tests.support.office import (
    DRINK,
    END,
    ENGAGED,
    INFO,
    INITIATE,
    MISSION,
    NEG,
    NEU,
    OBS,
    PASS,
    POS,
    QUERY_TYPE,
    VMAX,
    G,
    S,
    act,
)


def hri(**params: Any) -> HriLearner:
    learner = make_learner("hri", params, MISSION)
    assert isinstance(learner, HriLearner)
    return learner


def i3(ep: int, c: int = 0) -> list[Transition]:
    """The robot initiated and was rejected."""
    return [Transition(ep, c, OBS, INITIATE, -2.0, END, NEG)]


def i0(ep: int, c: int = 0) -> list[Transition]:
    """The robot passed and nobody asked for anything."""
    return [Transition(ep, c, OBS, PASS, 0.0, END, NEU)]


def i2(
    ep: int,
    c: int = 0,
    service: str = DRINK,
    detail: str = "tea",
    *,
    reward: float = 6.0,
    query_detail: bool = False,
) -> list[Transition]:
    """Initiated, accepted, inferred the type, inferred (or asked) the detail, performed."""
    tk, dk = S.type_known_state(service), S.detail_known_state(service, detail)
    rows = [
        Transition(ep, c, OBS, INITIATE, 1.0, ENGAGED, POS),
        Transition(ep, c, ENGAGED, act(ActionKind.INFER_TYPE, service), 0.0, tk),
    ]
    if query_detail:
        rows.append(Transition(ep, c, tk, act(ActionKind.QUERY_DETAIL, service), -0.5, dk, POS))
    else:
        rows.append(Transition(ep, c, tk, act(ActionKind.INFER_DETAIL, service, detail), 0.0, dk))
    rows.append(
        Transition(
            ep,
            c,
            dk,
            act(ActionKind.PERFORM, service, detail),
            reward,
            END,
            POS if reward > 0 else NEG,
        )
    )
    return rows


def i1(
    ep: int, c: int = 0, service: str = DRINK, detail: str = "tea", *, reward: float = 6.0
) -> list[Transition]:
    """The human asked after a pass; the robot responded, inferred the detail, performed."""
    rq = S.request_state(service)
    tk, dk = S.type_known_state(service), S.detail_known_state(service, detail)
    return [
        Transition(ep, c, OBS, PASS, 0.0, rq, POS),
        Transition(ep, c, rq, act(ActionKind.RESPOND, service), 1.0, tk),
        Transition(ep, c, tk, act(ActionKind.INFER_DETAIL, service, detail), 0.0, dk),
        Transition(
            ep,
            c,
            dk,
            act(ActionKind.PERFORM, service, detail),
            reward,
            END,
            POS if reward > 0 else NEG,
        ),
    ]


def feed(learner: HriLearner, *episodes: Sequence[Transition]) -> None:
    for rows in episodes:
        learner.update(rows)


def perform(detail: str, service: str = DRINK) -> int:
    return act(ActionKind.PERFORM, service, detail)


def infer_detail(detail: str, service: str = DRINK) -> int:
    return act(ActionKind.INFER_DETAIL, service, detail)


def gibbs(prefs: Sequence[float], tau: float) -> list[float]:
    top = max(prefs)
    weights = [math.exp((p - top) / tau) for p in prefs]
    return [w / sum(weights) for w in weights]


def view_of(learner: HriLearner, episode: int, c: int = 0) -> Any:
    return learner.explain(c, episode)


# Values of the all-accepted tea path (every pair known with a positive model):
V_DK_TEA = 6.0  # Q(perform tea) = r'/n' = 6
Q_INFER_TEA = G * V_DK_TEA  # 5.4
Q_INFER_DRINK = G * Q_INFER_TEA  # 4.86
Q_INITIATE_OK = 1.0 + G * Q_INFER_DRINK  # 5.374


class TestInteractionClasses:
    def test_classes(self) -> None:
        assert interaction_class(S, i0(1)) is Interaction.NONE
        assert interaction_class(S, i1(1)) is Interaction.I1
        assert interaction_class(S, i2(1)) is Interaction.I2
        assert interaction_class(S, i2(1, reward=-2.0)) is Interaction.I2
        assert interaction_class(S, i3(1)) is Interaction.I3
        assert interaction_class(S, i2(1)[1:]) is Interaction.NONE  # no root step


class TestRootPolarity:
    def test_rejection_excludes_accepted_initiations(self) -> None:
        learner = hri()
        feed(learner, i2(1), i3(2))
        view = view_of(learner, 3)
        assert view.visits[INITIATE] == 2
        assert view.kept_visits[INITIATE] == 1  # only the I3 sample: rho(root) = -
        assert view.q[INITIATE] == pytest.approx(-2.0)

    def test_acceptance_brings_them_back(self) -> None:
        learner = hri()
        feed(learner, i2(1), i3(2), i2(3))
        view = view_of(learner, 4)
        assert view.kept_visits[INITIATE] == 2  # the two I2 samples; the I3 one is excluded
        assert view.q[INITIATE] == pytest.approx(Q_INITIATE_OK, rel=1e-9)
        assert Q_INITIATE_OK == pytest.approx(5.374)

    def test_no_interaction_keeps_the_reference(self) -> None:
        learner = hri()
        feed(learner, i2(1), i3(2), i0(3))
        view = view_of(learner, 4)
        assert view.kept_visits[INITIATE] == 1  # rho is still - after an I0 episode
        assert view.kept_visits[PASS] == 1  # the I0 sample has polarity 0: always kept

    def test_human_initiated_episode_reenables_initiation(self) -> None:
        learner = hri()
        feed(learner, i2(1), i3(2), i0(3), i1(4))
        view = view_of(learner, 5)
        # rho(root) = + after the I1 episode: the I2 sample is back, the I3 sample is out.
        assert view.kept_visits[INITIATE] == 1
        assert view.q[INITIATE] == pytest.approx(Q_INITIATE_OK, rel=1e-9)
        # pass: the I0 sample (-> END) and the I1 sample (-> REQUEST(drink)), half each.
        assert view.kept_visits[PASS] == 2
        v_request = 1.0 + G * Q_INFER_TEA  # respond: r_pos, then TYPE_KNOWN(drink)
        assert view.q[PASS] == pytest.approx(G * 0.5 * v_request, rel=1e-9)
        assert view.q[PASS] == pytest.approx(2.637)
        # A later rejection excludes the I1 pass sample again (it had polarity +).
        feed(learner, i3(5))
        view = view_of(learner, 6)
        assert view.kept_visits[PASS] == 1
        assert view.kept_visits[INITIATE] == 2  # the two I3 samples
        assert view.q[PASS] == pytest.approx(0.0)

    def test_root_reference_is_per_context(self) -> None:
        learner = hri()
        feed(learner, i2(1, c=0), i2(2, c=1), i3(3, c=1))
        assert view_of(learner, 4, c=0).kept_visits[INITIATE] == 1
        assert view_of(learner, 4, c=0).q[INITIATE] == pytest.approx(Q_INITIATE_OK, rel=1e-9)
        assert view_of(learner, 4, c=1).q[INITIATE] == pytest.approx(-2.0)


class TestInMissionPolarity:
    def test_rejection_then_acceptance_per_pair(self) -> None:
        learner = hri()
        feed(learner, i2(1), i2(2, reward=-2.0))
        view = view_of(learner, 3)
        # The failed episode's omega is -: for the in-mission pairs it ran, rho = -.
        assert view.visits[perform("tea")] == 2
        assert view.kept_visits[perform("tea")] == 1
        assert view.q[perform("tea")] == pytest.approx(-2.0)
        assert view.kept_visits[infer_detail("tea")] == 1
        assert view.q[infer_detail("tea")] == pytest.approx(G * -2.0)
        # The root pair follows the interaction class (both I2, so +), not the outcome.
        assert view.kept_visits[INITIATE] == 2
        feed(learner, i2(3))
        view = view_of(learner, 4)
        assert view.kept_visits[perform("tea")] == 2  # episodes 1 and 3; not 2
        assert view.q[perform("tea")] == pytest.approx(6.0)  # with ep. 2 it would be 10/3

    def test_other_pairs_keep_their_own_reference(self) -> None:
        learner = hri()
        feed(learner, i2(1, detail="coffee"), i2(2, detail="tea", reward=-2.0))
        view = view_of(learner, 3)
        assert view.kept_visits[perform("coffee")] == 1
        assert view.q[perform("coffee")] == pytest.approx(6.0)
        # infer_type(drink) ran in both: rho = -, the accepted coffee episode is excluded.
        assert view.kept_visits[act(ActionKind.INFER_TYPE, DRINK)] == 1

    def test_a_human_initiated_failure_is_negative_in_mission(self) -> None:
        learner = hri()
        feed(learner, i1(1, reward=-2.0))
        view = view_of(learner, 2)
        respond = act(ActionKind.RESPOND, DRINK)
        # V(TYPE_KNOWN) = max(infer(tea) = 0.9 * -2, the unknown (neutral) actions = 0) = 0.
        assert view.q[respond] == pytest.approx(1.0)
        feed(learner, i1(2))
        view = view_of(learner, 3)
        assert view.kept_visits[respond] == 1  # the + sample of episode 2 only
        assert view.kept_visits[PASS] == 2  # root: both I1, both +
        assert view.q[respond] == pytest.approx(1.0 + G * Q_INFER_TEA)

    def test_samples_count_once_the_episode_closed(self) -> None:
        learner = hri()
        first, *rest = i2(1)
        learner.update([first])
        view = view_of(learner, 1)
        assert view.visits[INITIATE] == 1
        assert view.kept_visits[INITIATE] == 0
        assert view.q[INITIATE] == 0.0
        learner.update(rest)
        assert view_of(learner, 2).q[INITIATE] == pytest.approx(Q_INITIATE_OK, rel=1e-9)

    def test_root_only_exclusion(self) -> None:
        learner = hri(exclusion="root_only")
        feed(learner, i2(1), i2(2, reward=-2.0), i3(3))
        view = view_of(learner, 4)
        assert view.kept_visits[perform("tea")] == 2
        assert view.q[perform("tea")] == pytest.approx((6.0 - 2.0) / 2)
        assert view.kept_visits[INITIATE] == 1

    def test_no_exclusion(self) -> None:
        learner = hri(exclusion="none")
        feed(learner, i2(1), i2(2, reward=-2.0), i3(3))
        view = view_of(learner, 4)
        assert view.kept_visits[perform("tea")] == 2
        assert view.q[perform("tea")] == pytest.approx(2.0)
        assert view.kept_visits[INITIATE] == 3
        # initiate: rewards 1, 1, -2; two of three go to ENGAGED.
        v_tk = G * 2.0  # infer_detail(tea) -> perform(tea) = 2
        v_engaged = G * v_tk  # infer_type(drink) -> TYPE_KNOWN(drink)
        expected = 0.0 + G * (2 / 3) * v_engaged
        assert view.q[INITIATE] == pytest.approx(expected, rel=1e-9)


class TestWeights:
    def test_w_i1(self) -> None:
        learner = hri(w_i1=1.5)
        feed(learner, i1(1, reward=2.0), i2(2, reward=6.0))
        view = view_of(learner, 3)
        assert view.kept_visits[perform("tea")] == pytest.approx(2.5)
        assert view.q[perform("tea")] == pytest.approx((1.5 * 2.0 + 6.0) / 2.5)
        assert view.kept_visits[PASS] == pytest.approx(1.5)
        assert view.kept_visits[INITIATE] == pytest.approx(1.0)
        v_tk = G * 3.6
        assert view.q[PASS] == pytest.approx(G * (1.0 + G * v_tk), rel=1e-9)

    def test_default_weight_is_one(self) -> None:
        learner = hri()
        feed(learner, i1(1, reward=2.0), i2(2, reward=6.0))
        view = view_of(learner, 3)
        assert view.kept_visits[perform("tea")] == 2
        assert view.q[perform("tea")] == pytest.approx(4.0)


class TestModelAndValues:
    def test_unknown_pairs_are_neutral(self) -> None:
        learner = hri()
        assert np.all(view_of(learner, 1).q == 0.0)
        feed(learner, i3(1))
        q = view_of(learner, 2).q
        assert q[INITIATE] == pytest.approx(-2.0)
        assert np.all(np.delete(q, INITIATE) == 0.0)  # not Vmax: no optimism

    def test_m_h_threshold(self) -> None:
        learner = hri(m_h=2.0)
        feed(learner, i2(1))
        # Each pair has n' = 1 < 2: R = 0 and T -> END, so every Q is 0 despite the rewards.
        assert np.all(view_of(learner, 2).q == 0.0)
        feed(learner, i2(2))
        view = view_of(learner, 3)
        assert view.q[perform("tea")] == pytest.approx(6.0)
        assert view.q[INITIATE] == pytest.approx(Q_INITIATE_OK, rel=1e-9)
        feed(learner, i3(3))
        # rho(root) = -: n'(initiate) = 1 < m_h, so initiate is unknown again: Q = 0.
        assert view_of(learner, 4).q[INITIATE] == 0.0

    def test_value_iteration_by_hand(self) -> None:
        learner = hri()
        tk_drink, tk_info = S.type_known_state(DRINK), S.type_known_state(INFO)
        dk_tea, dk_news = S.detail_known_state(DRINK, "tea"), S.detail_known_state(INFO, "news")

        def asked(
            ep: int, service: str, detail: str, tk: int, dk: int, reward: float
        ) -> list[Transition]:
            return [
                Transition(ep, 0, OBS, INITIATE, 1.0, ENGAGED, POS),
                Transition(ep, 0, ENGAGED, QUERY_TYPE, -0.5, tk, POS),
                Transition(ep, 0, tk, act(ActionKind.QUERY_DETAIL, service), -0.5, dk, POS),
                Transition(ep, 0, dk, act(ActionKind.PERFORM, service, detail), reward, END, POS),
            ]

        feed(
            learner,
            asked(1, DRINK, "tea", tk_drink, dk_tea, 6.0),
            asked(2, INFO, "news", tk_info, dk_news, 2.0),
        )
        q = view_of(learner, 3).q
        v_tk_drink = -0.5 + G * 6.0  # 4.9
        v_tk_info = -0.5 + G * 2.0  # 1.3
        q_query_type = -0.5 + G * (0.5 * v_tk_drink + 0.5 * v_tk_info)  # 2.29
        assert q[act(ActionKind.QUERY_DETAIL, DRINK)] == pytest.approx(v_tk_drink)
        assert q[act(ActionKind.QUERY_DETAIL, INFO)] == pytest.approx(v_tk_info)
        assert q[QUERY_TYPE] == pytest.approx(q_query_type)
        assert q[QUERY_TYPE] == pytest.approx(2.29)
        assert q[INITIATE] == pytest.approx(1.0 + G * q_query_type)  # 3.061

    def test_q_is_clipped_to_vmax(self) -> None:
        learner = hri()
        feed(learner, i2(1, reward=500.0), i3(2, c=1))
        learner.update([Transition(3, 1, OBS, INITIATE, -50.0, END, NEG)])
        assert view_of(learner, 4).q[perform("tea")] == pytest.approx(VMAX, rel=1e-12)
        assert view_of(learner, 4).q[infer_detail("tea")] == pytest.approx(VMAX, rel=1e-12)
        assert view_of(learner, 4, c=1).q[INITIATE] == pytest.approx((-2.0 - 50.0) / 2)
        learner.update([Transition(4, 2, OBS, INITIATE, -5000.0, END, NEG)])
        assert view_of(learner, 5, c=2).q[INITIATE] == pytest.approx(-VMAX, rel=1e-12)

    def test_vmax_if_never_tried(self) -> None:
        learner = hri(unknown="vmax_if_never_tried")
        assert view_of(learner, 1).q == pytest.approx(np.full(S.n_actions, VMAX), rel=1e-12)
        feed(learner, i3(1))
        q = view_of(learner, 2).q
        assert q[INITIATE] == pytest.approx(-2.0)
        assert q[PASS] == pytest.approx(VMAX, rel=1e-12)
        feed(learner, i2(2))
        q = view_of(learner, 3).q
        # ENGAGED's best action is the never-tried query_type, pinned at Vmax.
        assert q[QUERY_TYPE] == pytest.approx(VMAX, rel=1e-12)
        assert q[INITIATE] == pytest.approx(1.0 + G * VMAX)


class TestActionSelection:
    def test_measure_is_one_at_t_one_and_moves_with_staleness(self) -> None:
        learner = hri()
        feed(learner, i3(1))
        # Q~ = (-2/60, 0): mean -1/60, dQ~ = (-1/60, +1/60).
        for e in (2, 5, 50, 1000):
            m = view_of(learner, e).measure
            assert m[INITIATE] == pytest.approx((e - 1) ** (-1 / 60), rel=1e-12)
            assert m[PASS] == pytest.approx(e ** (1 / 60), rel=1e-12)  # never run: t = e
        assert view_of(learner, 2).measure[INITIATE] == 1.0
        m_init = [view_of(learner, e).measure[INITIATE] for e in (2, 5, 50, 1000)]
        m_pass = [view_of(learner, e).measure[PASS] for e in (2, 5, 50, 1000)]
        assert m_init == sorted(m_init, reverse=True)
        assert m_init[-1] < 1.0
        assert m_pass == sorted(m_pass)
        assert m_pass[0] > 1.0
        # A pair executed in the previous episode has t = 1, so M = 1.
        feed(learner, i0(2))
        assert view_of(learner, 3).measure[PASS] == 1.0

    def test_equal_q_gives_measure_one(self) -> None:
        m = view_of(hri(), 10**6).measure
        assert np.all(m == 1.0)  # dQ = 0 everywhere: t^0 = 1

    @pytest.mark.parametrize("tau", [0.01, 0.1])
    def test_gibbs_at_observe_by_hand(self, tau: float) -> None:
        learner = hri(tau=tau)
        feed(learner, i3(1))
        e = 50
        pref_init = -2 / 60 + (e - 1) ** (-1 / 60)
        pref_pass = 0.0 + e ** (1 / 60)
        expected = gibbs([pref_init, pref_pass], tau)
        view = view_of(learner, e)
        assert view.probabilities[[INITIATE, PASS]] == pytest.approx(expected, rel=1e-9, abs=1e-300)
        d = learner.select_action(Observation(0, OBS, e), np.random.default_rng(0))
        assert d.probabilities == pytest.approx(expected, rel=1e-9, abs=1e-300)

    def test_gibbs_at_type_known_by_hand(self) -> None:
        learner = hri()
        feed(learner, i2(1, query_detail=True), i2(2, detail="coffee", reward=-2.0))
        tk = S.type_known_state(DRINK)
        actions = list(S.actions_of(tk))
        qd = act(ActionKind.QUERY_DETAIL, DRINK)
        assert actions == [qd, infer_detail("tea"), infer_detail("coffee"), infer_detail("water")]
        q = [-0.5 + G * 6.0, 0.0, G * -2.0, 0.0]  # asked-and-liked, never, failed, never
        e = 10
        t = [e - 1, e, e - 2, e]
        qs = [v / VMAX for v in q]
        mean = sum(qs) / 4
        prefs = [qs[i] + t[i] ** (qs[i] - mean) for i in range(4)]
        expected = gibbs(prefs, 0.01)
        view = view_of(learner, e)
        assert view.q[actions] == pytest.approx(q)
        assert list(view.since_last[actions]) == t
        assert view.measure[actions] == pytest.approx(
            [t[i] ** (qs[i] - mean) for i in range(4)], rel=1e-12
        )
        assert view.probabilities[actions] == pytest.approx(expected, rel=1e-9, abs=1e-300)
        d = learner.select_action(Observation(0, tk, e), np.random.default_rng(1))
        assert d.state == tk and d.chain == () or d.chain[0].state == tk
        probs = d.chain[0].probabilities if d.chain else d.probabilities
        assert probs == pytest.approx(expected, rel=1e-9, abs=1e-300)

    def test_favorable_actions_alternate(self) -> None:
        # Both query_detail and infer(tea) are above the state's mean; the one unused for longer
        # gets the larger measure (docs/method.md §5, "how this behaves").
        learner = hri()
        feed(learner, i2(1, query_detail=True), i2(2))
        tk = S.type_known_state(DRINK)
        p = view_of(learner, 3).probabilities
        qd, tea = act(ActionKind.QUERY_DETAIL, DRINK), infer_detail("tea")
        assert p[qd] > p[tea]  # infer(tea) ran in episode 2, query_detail in episode 1
        feed(learner, i2(3, query_detail=True))
        p = view_of(learner, 4).probabilities
        assert p[tea] > p[qd]
        assert tk == S.pair_state[qd]

    def test_no_measure_is_plain_gibbs_on_q(self) -> None:
        learner = hri(measure=False, tau=0.05)
        feed(learner, i3(1))
        expected = gibbs([-2 / 60, 0.0], 0.05)
        view = view_of(learner, 100)
        assert np.all(view.measure == 0.0)  # M = 0 (ablation)
        assert view.probabilities[[INITIATE, PASS]] == pytest.approx(expected, rel=1e-9)

    def test_raw_pref_scale(self) -> None:
        learner = hri(pref_scale="raw", tau=10.0)
        feed(learner, i3(1))
        e = 3
        # Q raw = (-2, 0): dQ = (-1, +1); t = (2, 3).
        prefs = [-2.0 + 2.0**-1, 0.0 + 3.0**1]
        view = view_of(learner, e)
        assert view.measure[[INITIATE, PASS]] == pytest.approx([0.5, 3.0])
        assert view.probabilities[[INITIATE, PASS]] == pytest.approx(gibbs(prefs, 10.0))

    def test_measure_is_capped(self) -> None:
        learner = hri(pref_scale="raw")
        feed(learner, i3(2))
        m = view_of(learner, 10**12).measure
        # dQ = +1 for pass: (10**12)^1 is capped at 1e6; initiate: (10**12 - 2)^-1.
        assert m[PASS] == pytest.approx(1e6)
        assert m[INITIATE] == pytest.approx(1.0 / (10**12 - 2), rel=1e-9)

    def test_tau_with_kappa(self) -> None:
        adaptive, plain = hri(kappa=1.0), hri()
        feed(adaptive, i3(1))
        feed(plain, i3(1))
        prefs = [-2 / 60 + 1.0, 2 ** (1 / 60)]  # episode 2: t = (1, 2)
        tau_c = 0.01 * (1.0 + 29 / 30)  # U(c): 29 of the 30 pairs of context 0 never ran
        p_adaptive = view_of(adaptive, 2).probabilities[[INITIATE, PASS]]
        p_plain = view_of(plain, 2).probabilities[[INITIATE, PASS]]
        assert p_adaptive == pytest.approx(gibbs(prefs, tau_c), rel=1e-9)
        assert p_plain == pytest.approx(gibbs(prefs, 0.01), rel=1e-9)
        assert 0.5 < p_adaptive[1] < p_plain[1]  # softer in the unfamiliar context
        feed(adaptive, i2(2))
        tau_c = 0.01 * (1.0 + 26 / 30)  # + infer_type, infer_detail and perform ran
        q_init, q_pass = Q_INITIATE_OK / VMAX, 0.0
        mean = (q_init + q_pass) / 2
        prefs = [q_init + 1 ** (q_init - mean), q_pass + 3 ** (q_pass - mean)]  # t = (1, 3)
        assert view_of(adaptive, 3).probabilities[[INITIATE, PASS]] == pytest.approx(
            gibbs(prefs, tau_c), rel=1e-9
        )

    def test_context_staleness(self) -> None:
        glob, ctx = hri(), hri(staleness="context")
        for learner in (glob, ctx):
            feed(learner, i3(1), *(i0(e, c=1) for e in range(2, 10)))
        e = 10
        # Global: t = (9, 10). Per context: context 0 saw one episode, so now = 2: t = (1, 2).
        assert view_of(glob, e).measure[[INITIATE, PASS]] == pytest.approx(
            [9 ** (-1 / 60), 10 ** (1 / 60)], rel=1e-12
        )
        assert view_of(ctx, e).measure[[INITIATE, PASS]] == pytest.approx(
            [1.0, 2 ** (1 / 60)], rel=1e-12
        )
        # The inspection view reports the t the measure used.
        assert list(view_of(glob, e).since_last[[INITIATE, PASS]]) == [9, 10]
        assert list(view_of(ctx, e).since_last[[INITIATE, PASS]]) == [1, 2]

    def test_zero_tau_is_greedy_with_seeded_ties(self) -> None:
        learner = hri(tau=0.0)
        assert list(view_of(learner, 1).probabilities[[INITIATE, PASS]]) == [0.5, 0.5]
        picks = {
            learner.select_action(Observation(0, OBS, 1), np.random.default_rng(s)).action
            for s in range(20)
        }
        assert picks == {INITIATE, PASS}
        feed(learner, i3(1))
        assert list(view_of(learner, 2).probabilities[[INITIATE, PASS]]) == [0.0, 1.0]

    def test_single_action_states_skip_the_draw(self) -> None:
        learner = hri()
        feed(learner, i2(1))
        rng = np.random.default_rng(5)
        before = rng.bit_generator.state
        dk = S.detail_known_state(DRINK, "tea")
        d = learner.select_action(Observation(0, dk, 2), rng)
        assert d.action == perform("tea")
        assert list(d.probabilities) == [1.0]
        assert rng.bit_generator.state == before
        # From REQUEST the silent respond is taken without a draw, then TYPE_KNOWN draws once.
        rq = S.request_state(DRINK)
        d = learner.select_action(Observation(0, rq, 2), rng)
        assert d.chain[0].action == act(ActionKind.RESPOND, DRINK)
        assert list(d.chain[0].probabilities) == [1.0]
        assert d.chain[0].reward == 1.0


class TestExplain:
    def test_fields(self) -> None:
        learner = hri()
        feed(learner, i2(1), i2(2, reward=-2.0), i0(3))
        e = 7
        view = learner.explain(0, e)
        for name in ("q", "visits", "kept_visits", "since_last", "measure", "probabilities"):
            arr = getattr(view, name)
            assert isinstance(arr, np.ndarray), name
            assert arr.shape == (S.n_actions,), name
        assert view.kept_visits is not None
        assert view.measure is not None
        assert view.visits.dtype == np.int64
        assert view.since_last.dtype == np.int64
        assert view.visits[INITIATE] == 2
        assert view.visits[PASS] == 1
        assert view.visits[perform("tea")] == 2
        assert view.visits[perform("coffee")] == 0
        assert view.kept_visits[perform("tea")] == 1
        assert view.since_last[INITIATE] == e - 2
        assert view.since_last[PASS] == e - 3
        assert view.since_last[perform("coffee")] == e  # never executed
        for s in range(S.n_states):
            r = S.actions_of(s)
            assert view.probabilities[r.start : r.stop].sum() == pytest.approx(1.0, abs=1e-12)
        assert np.all(view.measure[list(S.actions_of(S.detail_known_state(DRINK, "tea")))] == 1)
        # explain reads, it does not write
        assert learner.to_state() == learner.to_state()
        before = learner.to_state()
        learner.explain(0, 10**12)
        assert learner.to_state() == before

    def test_other_context_is_untouched(self) -> None:
        learner = hri()
        feed(learner, i2(1, c=4))
        view = learner.explain(5, 2)
        assert np.all(view.visits == 0)
        assert np.all(view.q == 0.0)
        assert np.all(view.since_last == 2)
