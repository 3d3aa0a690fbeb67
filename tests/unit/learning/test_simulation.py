"""Simulated users (docs/method.md §2 and §11): profiles, drift, streams, responses."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from app.learning import (
    ActionKind,
    Mission,
    Polarity,
    evaluation,
)
from app.learning.simulation import (
    Need,
    UserProfile,
    drift,
    event_stream,
    random_profile,
    respond,
)
from tests.support.office import MISSION, S, act

R = MISSION.rewards
BUSY = {c for c in range(MISSION.n_contexts) if MISSION.context_names(c)[1] == "busy"}
DRINK, INFO = 0, 1  # service indices of the office mission
TEA, COFFEE = 0, 1


def rng(*words: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(list(words)))


class TestProfiles:
    @pytest.mark.parametrize("seed", range(40))
    def test_three_to_five_needs_in_distinct_available_contexts(self, seed: int) -> None:
        profile = random_profile(MISSION, rng(seed))
        assert 3 <= len(profile.needs) <= 5
        contexts = [n.context for n in profile.needs]
        assert len(set(contexts)) == len(contexts)
        assert not set(contexts) & BUSY
        for need in profile.needs:
            assert 0 <= need.service < len(MISSION.services)
            assert 0 <= need.detail < len(MISSION.services[need.service].details)

    def test_every_size_occurs(self) -> None:
        sizes = {len(random_profile(MISSION, rng(seed)).needs) for seed in range(60)}
        assert sizes == {3, 4, 5}

    def test_defaults_of_section_7(self) -> None:
        p = random_profile(MISSION, rng(0))
        assert (p.p_acc, p.p_self, p.eps_fb, p.p_abort, p.p_idle_acc) == (0.95, 0.5, 0.05, 0.0, 0.0)

    def test_same_seed_same_profile(self) -> None:
        assert random_profile(MISSION, rng(5)) == random_profile(MISSION, rng(5))

    def test_validation(self) -> None:
        with pytest.raises(ValueError, match="p_acc"):
            UserProfile((), p_acc=1.5)
        with pytest.raises(ValueError, match="eps_fb"):
            UserProfile((), eps_fb=-0.1)
        with pytest.raises(ValueError, match="distinct contexts"):
            UserProfile((Need(0, 0, 0), Need(0, 1, 1)))


class TestDrift:
    @pytest.mark.parametrize("seed", range(40))
    def test_changes_half_the_rules(self, seed: int) -> None:
        before = random_profile(MISSION, rng(seed, 0))
        after = drift(before, MISSION, rng(seed, 1))
        changed = [
            i for i, (a, b) in enumerate(zip(before.needs, after.needs, strict=True)) if a != b
        ]
        assert len(changed) == math.ceil(len(before.needs) / 2)
        contexts = [n.context for n in after.needs]
        assert len(set(contexts)) == len(contexts)
        assert not set(contexts) & BUSY
        for i in changed:
            a, b = before.needs[i], after.needs[i]
            kinds = (a.context != b.context, a.service != b.service, a.detail != b.detail)
            if a.context != b.context:  # a move keeps the wish
                assert (a.service, a.detail) == (b.service, b.detail)
            elif a.service == b.service:  # a new detail of the same service
                assert a.detail != b.detail
            assert any(kinds)
        assert (after.p_acc, after.eps_fb) == (before.p_acc, before.eps_fb)

    def test_all_three_kinds_of_change_occur(self) -> None:
        kinds = set()
        for seed in range(60):
            before = random_profile(MISSION, rng(seed, 0))
            after = drift(before, MISSION, rng(seed, 1))
            for a, b in zip(before.needs, after.needs, strict=True):
                if a.context != b.context:
                    kinds.add("context")
                elif a.service != b.service:
                    kinds.add("service")
                elif a.detail != b.detail:
                    kinds.add("detail")
        assert kinds == {"context", "service", "detail"}

    def test_same_seed_same_drift(self) -> None:
        before = random_profile(MISSION, rng(1))
        assert drift(before, MISSION, rng(2)) == drift(before, MISSION, rng(2))


class TestEventStream:
    def test_same_seed_same_stream(self) -> None:
        p = random_profile(MISSION, rng(0))
        a = event_stream([p], [0], MISSION, 200, rng(9))
        b = event_stream([p], [0], MISSION, 200, rng(9))
        c = event_stream([p], [0], MISSION, 200, rng(10))
        assert np.array_equal(a, b)
        assert not np.array_equal(a, c)

    def test_need_share_and_other_contexts(self) -> None:
        p = random_profile(MISSION, rng(0))
        needs = {n.context for n in p.needs}
        stream = event_stream([p], [0], MISSION, 20_000, rng(1))
        share = np.isin(stream, list(needs)).mean()
        assert share == pytest.approx(0.7, abs=0.02)
        others = set(stream.tolist()) - needs
        assert others == set(range(MISSION.n_contexts)) - needs  # busy contexts included
        assert others & BUSY

    def test_profiles_switch_at_the_change_point(self) -> None:
        before = UserProfile((Need(0, 0, 0),))
        after = UserProfile((Need(5, 0, 0),))
        stream = event_stream([before, after], [0, 100], MISSION, 200, rng(2), p_need=1.0)
        assert set(stream[:100].tolist()) == {0}
        assert set(stream[100:].tolist()) == {5}

    def test_mission_where_every_context_has_a_need(self) -> None:
        tiny = Mission.from_dict(
            {
                "name": "tiny",
                "situations": ["here"],
                "time_slots": [
                    {"name": "am", "start": "00:00", "end": "12:00"},
                    {"name": "pm", "start": "12:00", "end": "00:00"},
                ],
                "services": [{"name": "Hug", "details": ["short"]}],
            }
        )
        profile = random_profile(tiny, rng(0))
        assert {n.context for n in profile.needs} == {0, 1}
        stream = event_stream([profile], [0], tiny, 500, rng(1))
        assert set(stream.tolist()) == {0, 1}


def test_experiment_methods_share_contexts_and_coin_flips(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: dict[str, list[tuple[np.ndarray, np.ndarray, list[UserProfile]]]] = {}
    real = evaluation.run_user

    def spy(
        learner: Any,
        profiles: Any,
        points: Any,
        contexts: np.ndarray,
        uniforms: np.ndarray,
        agent: np.random.Generator,
    ) -> dict[str, np.ndarray]:
        seen.setdefault(learner.algorithm, []).append(
            (contexts.copy(), uniforms.copy(), list(profiles))
        )
        return real(learner, profiles, points, contexts, uniforms, agent)

    monkeypatch.setattr(evaluation, "run_user", spy)
    methods = [evaluation.Method("R-MAX", "rmax"), evaluation.Method("HRI", "hri")]
    runs = [evaluation.run(m, evaluation.E1E2, 11, MISSION, n_users=3) for m in methods]
    assert len(seen["rmax"]) == len(seen["hri"]) == 3
    for (ca, ua, pa), (cb, ub, pb) in zip(seen["rmax"], seen["hri"], strict=True):
        assert np.array_equal(ca, cb)
        assert np.array_equal(ua, ub)
        assert pa == pb
    assert not np.array_equal(seen["rmax"][0][0], seen["rmax"][1][0])  # users differ
    # Different protocols draw other streams, but the users' needs are the same.
    e3 = evaluation.run(methods[0], evaluation.E3, 11, MISSION, n_users=1)
    assert not np.array_equal(seen["rmax"][-1][0], seen["rmax"][0][0])
    assert seen["rmax"][-1][2] == seen["rmax"][0][2]
    assert e3.reward.shape == (1, 100)
    assert runs[0].reward.shape == (3, 100)


def profile_with(need: Need | None, **params: Any) -> UserProfile:
    return dataclasses.replace(UserProfile(() if need is None else (need,)), **params)


C = MISSION.context_index("afternoon", "stretching")
C_BUSY = MISSION.context_index("afternoon", "busy")
TEA_NEED = Need(C, DRINK, TEA)
TK_DRINK = S.type_known_state("ProvideDrink")
TK_INFO = S.type_known_state("BriefInformation")
DK_TEA = S.detail_known_state("ProvideDrink", "tea")
DK_COFFEE = S.detail_known_state("ProvideDrink", "coffee")


def reply(
    profile: UserProfile, context: int, state: int, action: int, u: float, abort: float = 0.99
) -> tuple[str, float, int, Polarity]:
    r = respond(S, profile, context, state, action, np.array([u, abort]))
    return r.response, r.reward, r.next_state, r.signal


class TestResponses:
    def test_initiate_accepted_only_with_a_need_and_not_busy(self) -> None:
        p = profile_with(TEA_NEED)
        assert reply(p, C, S.OBSERVE, S.INITIATE, 0.0) == (
            "accepted",
            R.positive,
            S.ENGAGED,
            Polarity.POSITIVE,
        )
        assert reply(p, C, S.OBSERVE, S.INITIATE, 0.949)[0] == "accepted"
        assert reply(p, C, S.OBSERVE, S.INITIATE, 0.95) == (
            "rejected",
            R.negative,
            S.END,
            Polarity.NEGATIVE,
        )  # 1 - p_acc
        no_need = profile_with(None)
        assert reply(no_need, C, S.OBSERVE, S.INITIATE, 0.0)[0] == "rejected"
        busy = profile_with(Need(C_BUSY, DRINK, TEA))
        assert reply(busy, C_BUSY, S.OBSERVE, S.INITIATE, 0.0)[0] == "rejected"
        idle = profile_with(None, p_idle_acc=0.5)
        assert reply(idle, C, S.OBSERVE, S.INITIATE, 0.4)[0] == "accepted"
        assert reply(idle, C_BUSY, S.OBSERVE, S.INITIATE, 0.4)[0] == "rejected"

    def test_pass(self) -> None:
        p = profile_with(TEA_NEED)
        assert reply(p, C, S.OBSERVE, S.PASS, 0.49) == (
            "human_request",
            0.0,
            S.request_state("ProvideDrink"),
            Polarity.POSITIVE,
        )
        assert reply(p, C, S.OBSERVE, S.PASS, 0.5) == ("none", 0.0, S.END, Polarity.NEUTRAL)
        assert reply(profile_with(None), C, S.OBSERVE, S.PASS, 0.0) == (
            "none",
            0.0,
            S.END,
            Polarity.NEUTRAL,
        )
        busy = profile_with(Need(C_BUSY, DRINK, TEA))  # busy: the person never initiates
        assert reply(busy, C_BUSY, S.OBSERVE, S.PASS, 0.0) == ("none", 0.0, S.END, Polarity.NEUTRAL)

    def test_queries_are_answered_truthfully(self) -> None:
        p = profile_with(Need(C, DRINK, COFFEE))
        qt = act(ActionKind.QUERY_TYPE)
        assert reply(p, C, S.ENGAGED, qt, 0.99) == (
            "answered",
            R.query,
            TK_DRINK,
            Polarity.POSITIVE,
        )
        qd = act(ActionKind.QUERY_DETAIL, "ProvideDrink")
        assert reply(p, C, TK_DRINK, qd, 0.99) == (
            "answered",
            R.query,
            DK_COFFEE,
            Polarity.POSITIVE,
        )

    def test_query_detail_on_a_wrong_type_ends_the_dialog(self) -> None:
        p = profile_with(TEA_NEED)
        qd = act(ActionKind.QUERY_DETAIL, "BriefInformation")
        assert reply(p, C, TK_INFO, qd, 0.0) == (
            "terminated",
            R.query + R.negative,
            S.END,
            Polarity.NEGATIVE,
        )
        assert R.query + R.negative == -2.5

    def test_perform(self) -> None:
        p = profile_with(TEA_NEED)
        tea = act(ActionKind.PERFORM, "ProvideDrink", "tea")
        coffee = act(ActionKind.PERFORM, "ProvideDrink", "coffee")
        assert reply(p, C, DK_TEA, tea, 0.05) == (
            "accepted",
            R.positive + R.accepted_service,
            S.END,
            Polarity.POSITIVE,
        )
        assert R.positive + R.accepted_service == 6.0
        assert reply(p, C, DK_TEA, tea, 0.049) == (  # the eps_fb noise draw
            "rejected",
            R.negative,
            S.END,
            Polarity.NEGATIVE,
        )
        assert reply(p, C, DK_COFFEE, coffee, 0.99) == (
            "rejected",
            R.negative,
            S.END,
            Polarity.NEGATIVE,
        )
        assert reply(profile_with(None), C, DK_TEA, tea, 0.99)[0] == "rejected"

    def test_abort(self) -> None:
        p = profile_with(TEA_NEED, p_abort=0.3)
        tea = act(ActionKind.PERFORM, "ProvideDrink", "tea")
        assert reply(p, C, DK_TEA, tea, 0.99, abort=0.29) == (
            "terminated",
            R.negative,
            S.END,
            Polarity.NEGATIVE,
        )
        assert reply(p, C, DK_TEA, tea, 0.99, abort=0.3)[0] == "accepted"
        assert reply(p, C, S.OBSERVE, S.INITIATE, 0.0, abort=0.0)[0] == "terminated"

    def test_silent_actions_get_no_response(self) -> None:
        p = profile_with(TEA_NEED)
        with pytest.raises(ValueError, match="silent"):
            respond(
                S,
                p,
                C,
                TK_DRINK,
                act(ActionKind.INFER_DETAIL, "ProvideDrink", "tea"),
                np.array([0.0, 0.0]),
            )
