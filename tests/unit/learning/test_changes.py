"""The changes a learner decided, after each update (docs/method.md §8, "Changes detected"): the
records are small and JSON-serialisable; DTS's change test reports its restarts; the profile's
belief reports its changes for learners without a mechanism of their own; ChangeWatch picks."""

from __future__ import annotations

import json

import pytest

from app.learning import Transition, make_learner
from app.learning.changes import ChangeWatch, ProfileWatch, item_doc, step_of
from app.learning.space import ActionKind
from tests.support.office import (
    DK,
    DRINK,
    END,
    ENGAGED,
    INFER_DRINK,
    INFER_TEA,
    INITIATE,
    MISSION,
    NEG,
    OBS,
    PASS,
    PERFORM_TEA,
    POS,
    QUERY_TYPE,
    REQ,
    RESPOND,
    TEA,
    TK,
    S,
    act,
)

HERE = 0
QUERY_DRINK = act(ActionKind.QUERY_DETAIL, DRINK)
COFFEE_DK = S.detail_known_state(DRINK, "coffee")
PERFORM_COFFEE = act(ActionKind.PERFORM, DRINK, "coffee")


def tea(episode: int, *, accepted: bool = True) -> list[Transition]:
    return [
        Transition(episode, HERE, OBS, INITIATE, 1.0, ENGAGED, POS),
        Transition(episode, HERE, ENGAGED, INFER_DRINK, 0.0, TK),
        Transition(episode, HERE, TK, INFER_TEA, 0.0, DK),
        Transition(
            episode, HERE, DK, PERFORM_TEA, 6.0 if accepted else -2.0, END, POS if accepted else NEG
        ),
    ]


def coffee(episode: int) -> list[Transition]:
    return [
        Transition(episode, HERE, OBS, INITIATE, 1.0, ENGAGED, POS),
        Transition(episode, HERE, ENGAGED, QUERY_TYPE, -0.5, TK, POS),
        Transition(episode, HERE, TK, QUERY_DRINK, -0.5, COFFEE_DK, POS),
        Transition(episode, HERE, COFFEE_DK, PERFORM_COFFEE, 6.0, END, POS),
    ]


class TestSteps:
    def test_responses_are_read_back_from_the_transitions(self) -> None:
        steps = [step_of(S, t) for t in coffee(3)]
        assert [(s.response, s.service, s.detail) for s in steps] == [
            ("accepted", None, None),
            ("answered", DRINK, None),
            ("answered", None, "coffee"),
            ("accepted", None, None),
        ]
        assert steps[3].action == S.action_name(PERFORM_COFFEE)
        assert step_of(S, Transition(1, HERE, OBS, INITIATE, -2.0, END, NEG)).response == "rejected"
        assert step_of(S, Transition(1, HERE, OBS, PASS, 0.0, END)).response == "none"
        request = step_of(S, Transition(1, HERE, OBS, PASS, 0.0, REQ, POS))
        assert (request.response, request.service) == ("human_request", DRINK)


class TestProfile:
    def test_two_contradicting_episodes_change_the_belief(self) -> None:
        watch = ProfileWatch(S)
        for e in range(1, 5):
            assert watch.observe(tea(e)) == []
        assert watch.observe(tea(5, accepted=False)) == []  # one contradiction: not yet
        (change,) = watch.observe(coffee(6))
        assert change.source == "profile"
        assert item_doc(change.before) == {"service": DRINK, "detail": TEA}
        assert item_doc(change.now) == {"service": DRINK, "detail": "coffee"}
        assert {s.episode for s in change.evidence} == {5, 6}
        assert change.episode == 6
        assert json.loads(json.dumps(change.to_dict())) == change.to_dict()

    def test_a_contradiction_followed_by_support_changes_nothing(self) -> None:
        watch = ProfileWatch(S)
        out = []
        for batch in (tea(1), tea(2), tea(3, accepted=False), tea(4), coffee(5), tea(6)):
            out += watch.observe(batch)
        assert out == []

    def test_open_episodes_wait_for_their_end(self) -> None:
        watch = ProfileWatch(S)
        for e in range(1, 4):
            watch.observe(tea(e))
        watch.observe(tea(4, accepted=False))
        rows = coffee(5)
        assert watch.observe(rows[:2]) == []
        assert len(watch.observe(rows[2:])) == 1


class TestLearners:
    def test_dts_change_test_reports_its_restart(self) -> None:
        learner = make_learner("dts", {"change_alpha": 0.05}, MISSION)
        assert learner.decides_changes
        for e in range(1, 21):
            learner.update(tea(e))
            assert learner.changes == ()
        learner.update(tea(21, accepted=False))
        (change,) = learner.changes
        assert change.source == "change_test"
        assert item_doc(change.before) == {"service": DRINK, "detail": TEA}
        assert change.now is None
        assert change.figures["p"] < 0.05
        assert change.figures["accepted"] == 20
        assert change.evidence[-1].response == "rejected"
        assert json.loads(json.dumps(change.to_dict())) == change.to_dict()

    @pytest.mark.parametrize("algorithm", ["hri", "rmax", "qlearning", "dts"])
    def test_learners_without_a_mechanism_leave_it_to_the_profile(self, algorithm: str) -> None:
        learner = make_learner(algorithm, {}, MISSION)
        assert not learner.decides_changes
        watch = ChangeWatch(learner)
        assert watch.profile is not None
        decided = []
        for batch in (*(tea(e) for e in range(1, 5)), tea(5, accepted=False), coffee(6)):
            learner.update(batch)
            assert learner.changes == ()
            decided += watch.observe(batch)
        assert [c.source for c in decided] == ["profile"]

    def test_a_learner_with_a_mechanism_reports_its_own_and_the_profile_on_request(self) -> None:
        learner = make_learner("dts-routine", {}, MISSION)
        own, both = ChangeWatch(learner), ChangeWatch(learner, profile=True)
        assert own.profile is None
        assert both.profile is not None
        decided_own, decided_both = [], []
        for batch in (*(tea(e) for e in range(1, 5)), tea(5, accepted=False), coffee(6)):
            learner.update(batch)
            decided_own += own.observe(batch)
            decided_both += both.observe(batch)
        assert [c.source for c in decided_own] == ["routine"]
        assert sorted(c.source for c in decided_both) == ["profile", "routine"]

    def test_a_request_and_a_named_detail_count_as_the_persons_choice(self) -> None:
        learner = make_learner("dts-routine", {}, MISSION)
        for e in range(1, 4):
            learner.update(tea(e))
        learner.update(tea(4, accepted=False))
        # the person asks for a drink, names coffee, takes it
        learner.update([Transition(5, HERE, OBS, PASS, 0.0, REQ, POS)])
        learner.update([Transition(5, HERE, REQ, RESPOND, 1.0, TK)])
        learner.update([Transition(5, HERE, TK, QUERY_DRINK, -0.5, COFFEE_DK, POS)])
        assert not learner.changes  # named, not yet taken
        learner.update([Transition(5, HERE, COFFEE_DK, PERFORM_COFFEE, 6.0, END, POS)])
        assert len(learner.changes) == 1
        change = learner.changes[0]
        assert [s.response for s in change.evidence] == [
            "rejected",
            "human_request",
            "answered",
            "accepted",
        ]
