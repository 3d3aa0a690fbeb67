"""The negotiation's rules (docs/method.md §2 and §3): the responses each action allows, what a
response means, the interaction class, and an episode's tally. The service, the simulated
people, the experiments and the fleet simulator all use these functions."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from app.learning import ActionKind, Interaction, Polarity
from app.learning.negotiation import (
    EXPECTS,
    INTERACTION_CODE,
    Response,
    Tally,
    feedback_reward,
    interaction,
    interaction_class,
    outcome,
)
from app.learning.types import Transition
from tests.support.office import MISSION, S, act

R = MISSION.rewards
VISIBLE = [a for a in range(S.n_actions) if not S.silent[a]]


class TestExpects:
    def test_every_visible_action_has_its_responses_and_silent_ones_none(self) -> None:
        kinds = {S.actions[a].kind for a in VISIBLE}
        assert kinds == set(EXPECTS)
        silent = {S.actions[a].kind for a in range(S.n_actions) if S.silent[a]}
        assert not silent & set(EXPECTS)

    def test_the_words_are_the_api_s(self) -> None:
        assert EXPECTS[ActionKind.INITIATE] == ("accepted", "rejected", "terminated")
        assert EXPECTS[ActionKind.PASS] == ("human_request", "none")
        assert EXPECTS[ActionKind.QUERY_TYPE] == ("answered", "terminated")
        assert EXPECTS[ActionKind.QUERY_DETAIL] == ("answered", "terminated")
        assert EXPECTS[ActionKind.PERFORM] == ("accepted", "rejected", "terminated")

    @pytest.mark.parametrize("action", VISIBLE)
    def test_a_response_the_action_does_not_allow_is_refused(self, action: int) -> None:
        allowed = EXPECTS[S.actions[action].kind]
        for word in (set(Response) - set(allowed)) | {"maybe"}:
            with pytest.raises(ValueError, match="must be one of"):
                outcome(S, action, word, service="ProvideDrink", detail="tea")

    def test_a_silent_action_takes_no_response(self) -> None:
        with pytest.raises(ValueError, match="silent"):
            outcome(S, act(ActionKind.INFER_TYPE, "ProvideDrink"), "accepted")


class TestOutcome:
    def test_initiate(self) -> None:
        a = act(ActionKind.INITIATE)
        assert outcome(S, a, "accepted") == (R.positive, S.ENGAGED, Polarity.POSITIVE)
        for no in ("rejected", "terminated"):
            assert outcome(S, a, no) == (R.negative, S.END, Polarity.NEGATIVE)

    def test_pass(self) -> None:
        a = act(ActionKind.PASS)
        assert outcome(S, a, "none") == (0.0, S.END, Polarity.NEUTRAL)
        asked = outcome(S, a, "human_request", service="BriefInformation")
        assert asked == (0.0, S.request_state("BriefInformation"), Polarity.POSITIVE)
        # Spoke to the robot without naming a service yet: the type is still to be found.
        assert outcome(S, a, "human_request") == (0.0, S.ENGAGED, Polarity.POSITIVE)

    def test_queries_cost_their_price_whatever_the_answer(self) -> None:
        qt = act(ActionKind.QUERY_TYPE)
        assert outcome(S, qt, "answered", service="ProvideDrink") == (
            R.query,
            S.type_known_state("ProvideDrink"),
            Polarity.POSITIVE,
        )
        assert outcome(S, qt, "terminated") == (R.query + R.negative, S.END, Polarity.NEGATIVE)
        qd = act(ActionKind.QUERY_DETAIL, "ProvideDrink")
        assert outcome(S, qd, "answered", detail="coffee") == (
            R.query,
            S.detail_known_state("ProvideDrink", "coffee"),
            Polarity.POSITIVE,
        )
        assert outcome(S, qd, "terminated") == (R.query + R.negative, S.END, Polarity.NEGATIVE)

    def test_perform(self) -> None:
        a = act(ActionKind.PERFORM, "ProvideDrink", "tea")
        assert outcome(S, a, "accepted") == (
            R.positive + R.accepted_service,
            S.END,
            Polarity.POSITIVE,
        )
        for no in ("rejected", "terminated"):
            assert outcome(S, a, no) == (R.negative, S.END, Polarity.NEGATIVE)

    def test_answers_need_what_was_asked_and_names_of_the_mission(self) -> None:
        with pytest.raises(ValueError, match="names the service"):
            outcome(S, act(ActionKind.QUERY_TYPE), "answered")
        with pytest.raises(ValueError, match="names the detail"):
            outcome(S, act(ActionKind.QUERY_DETAIL, "ProvideDrink"), "answered")
        with pytest.raises(ValueError, match="not in the mission"):
            outcome(S, act(ActionKind.QUERY_TYPE), "answered", service="Massage")
        with pytest.raises(ValueError, match="not in the mission"):
            outcome(S, act(ActionKind.QUERY_DETAIL, "ProvideDrink"), "answered", detail="news")

    @pytest.mark.parametrize("action", VISIBLE)
    def test_every_outcome_is_a_transition_the_space_allows(self, action: int) -> None:
        service = S.actions[action].service or "ProvideDrink"
        detail = MISSION.service(service).details[0]
        for word in EXPECTS[S.actions[action].kind]:
            step = outcome(S, action, word, service=service, detail=detail)
            S.successor_column(action, step.next_state)  # raises if it cannot follow


class TestInteraction:
    def test_the_four_classes_of_eq_1(self) -> None:
        init, pas = S.INITIATE, S.PASS
        assert interaction(S, init, S.ENGAGED) is Interaction.I2
        assert interaction(S, init, S.END) is Interaction.I3
        assert interaction(S, pas, S.request_state("ProvideDrink")) is Interaction.I1
        assert interaction(S, pas, S.END) is Interaction.NONE

    def test_from_an_episode_s_transitions(self) -> None:
        rows = [
            Transition(1, 0, S.OBSERVE, S.INITIATE, R.positive, S.ENGAGED),
            Transition(1, 0, S.ENGAGED, act(ActionKind.QUERY_TYPE), R.query, S.END),
        ]
        assert interaction_class(S, rows) is Interaction.I2
        assert interaction_class(S, rows[1:]) is Interaction.NONE  # no root step: nothing

    def test_codes_are_small_and_distinct_with_none_zero(self) -> None:
        assert INTERACTION_CODE[Interaction.NONE] == 0
        assert sorted(INTERACTION_CODE.values()) == [0, 1, 2, 3]


class TestTally:
    def test_a_robot_initiated_episode_that_succeeds(self) -> None:
        tally = Tally()
        steps = [
            (S.OBSERVE, S.INITIATE, "accepted", {}),
            (S.ENGAGED, act(ActionKind.QUERY_TYPE), "answered", {"service": "ProvideDrink"}),
            (
                S.type_known_state("ProvideDrink"),
                act(ActionKind.QUERY_DETAIL, "ProvideDrink"),
                "answered",
                {"detail": "tea"},
            ),
            (
                S.detail_known_state("ProvideDrink", "tea"),
                act(ActionKind.PERFORM, "ProvideDrink", "tea"),
                "accepted",
                {},
            ),
        ]
        for state, action, word, named in steps:
            o = outcome(S, action, word, **named)
            tally.step(S, state, action, o.reward, o.next_state, o.signal)
        assert tally.initiated
        assert tally.success
        assert tally.interaction is Interaction.I2
        assert tally.queries == 2
        assert tally.reward == pytest.approx(
            R.positive + 2 * R.query + R.positive + R.accepted_service
        )

    def test_a_rejected_service_is_no_success_and_silent_steps_count_their_reward(self) -> None:
        tally = Tally()
        o = outcome(S, S.PASS, "human_request", service="ProvideDrink")
        tally.step(S, S.OBSERVE, S.PASS, o.reward, o.next_state, o.signal)
        respond = act(ActionKind.RESPOND, "ProvideDrink")
        tally.step(
            S, o.next_state, respond, float(S.silent_reward[respond]), int(S.silent_next[respond])
        )
        perform = act(ActionKind.PERFORM, "ProvideDrink", "coffee")
        o = outcome(S, perform, "rejected")
        tally.step(
            S,
            S.detail_known_state("ProvideDrink", "coffee"),
            perform,
            o.reward,
            o.next_state,
            o.signal,
        )
        assert not tally.initiated
        assert not tally.success
        assert tally.interaction is Interaction.I1
        assert tally.reward == pytest.approx(R.positive + R.negative)


def test_feedback_rewards() -> None:
    assert feedback_reward(R, "positive") == R.positive
    assert feedback_reward(R, "negative") == R.negative
    with pytest.raises(ValueError, match="positive or negative"):
        feedback_reward(R, "meh")


def test_the_simulated_people_answer_by_the_same_rules() -> None:
    """A simulated person only chooses the words; the reward and the next state are
    ``outcome``'s, for every action, need and coin flip."""
    from app.learning.simulation import Need, UserProfile, respond

    profile = UserProfile(
        (Need(MISSION.context_index("afternoon", "stretching"), 0, 0),), p_abort=0.3
    )
    for context, action, u in itertools.product(
        range(MISSION.n_contexts), VISIBLE, (0.01, 0.4, 0.99)
    ):
        state = int(S.pair_state[action])
        reaction = respond(S, profile, context, state, action, np.array([u, u]))
        expected = outcome(
            S, action, reaction.response, service=reaction.service, detail=reaction.detail
        )
        assert (reaction.reward, reaction.next_state, reaction.signal) == tuple(expected)
