"""``dts-routine`` (docs/method.md §8): DTS with the person's routine per context. It follows a
trusted routine, asks once the routine was refused (there only) or where none is held, offers
where it trusts one; the changes it decides are reported after the update. Orderings and bounds
on seeded runs; the conformance, export and replay checks run it with every learner."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from app.learning import DtsAdaptParams, DtsRoutineParams, Observation, Transition, make_learner
from app.learning.changes import ContextChange, item_doc
from app.learning.learners import DtsRoutineLearner, learner_from_state
from app.learning.population import FAMILIES, people, run_family, run_learner
from app.learning.prior import population_prior
from app.learning.space import ActionKind
from app.learning.state import StateFormatError
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
    TEA,
    TK,
    S,
    act,
)

QUERY_DRINK = act(ActionKind.QUERY_DETAIL, DRINK)
COFFEE_DK = S.detail_known_state(DRINK, "coffee")
PERFORM_COFFEE = act(ActionKind.PERFORM, DRINK, "coffee")
HERE, THERE = 0, 5  # two contexts where service is welcome


def routine(**params: Any) -> DtsRoutineLearner:
    learner = make_learner("dts-routine", params, MISSION)
    assert isinstance(learner, DtsRoutineLearner)
    return learner


def served(
    learner: DtsRoutineLearner, episode: int, context: int, *, accepted: bool = True
) -> None:
    """An offer taken, the robot infers tea, performs it; accepted or refused."""
    learner.update(
        [
            Transition(episode, context, OBS, INITIATE, 1.0, ENGAGED, POS),
            Transition(episode, context, ENGAGED, INFER_DRINK, 0.0, TK),
            Transition(episode, context, TK, INFER_TEA, 0.0, DK),
            Transition(
                episode,
                context,
                DK,
                PERFORM_TEA,
                6.0 if accepted else -2.0,
                END,
                POS if accepted else NEG,
            ),
        ]
    )


def asked_for_coffee(learner: DtsRoutineLearner, episode: int, context: int) -> None:
    """An offer taken, which service (drink), which detail (coffee), coffee performed and
    accepted."""
    learner.update([Transition(episode, context, OBS, INITIATE, 1.0, ENGAGED, POS)])
    learner.update([Transition(episode, context, ENGAGED, QUERY_TYPE, -0.5, TK, POS)])
    learner.update([Transition(episode, context, TK, QUERY_DRINK, -0.5, COFFEE_DK, POS)])
    learner.update([Transition(episode, context, COFFEE_DK, PERFORM_COFFEE, 6.0, END, POS)])


def probabilities(learner: DtsRoutineLearner, context: int, state: int, episode: int) -> np.ndarray:
    view = learner.explain(context, episode)
    actions = S.actions_of(state)
    return view.probabilities[actions.start : actions.stop]


def test_its_defaults_and_its_own_name() -> None:
    params = DtsRoutineParams()
    assert params.algorithm == "dts-routine"
    assert (params.routine, params.ask_in_doubt, params.ask_unknown, params.routine_offers) == (
        True,
        True,
        True,
        True,
    )
    # dts-adapt's slower forgetting and trusted answers, without its change test
    assert params.forgetting == DtsAdaptParams().forgetting
    assert params.trust_answers
    assert params.change_alpha == 0.0
    # dts-adapt keeps its parameters and its behaviour: a stored dts-adapt stays dts-adapt
    assert not hasattr(DtsAdaptParams(), "routine")
    with pytest.raises(ValueError, match="routine"):
        make_learner("dts-adapt", {"routine": True}, MISSION)


def test_a_context_never_served_is_asked_about() -> None:
    learner = routine()
    assert probabilities(learner, HERE, ENGAGED, 1)[0] == 1.0  # query_type
    assert probabilities(learner, HERE, TK, 1)[0] == 1.0  # query_detail


def test_a_trusted_routine_is_followed_and_offered() -> None:
    learner = routine()
    served(learner, 1, HERE)
    assert learner.held(HERE) == (PERFORM_TEA, 1.0)
    obs, engaged, tk = (probabilities(learner, HERE, s, 2) for s in (OBS, ENGAGED, TK))
    assert obs[0] == 1.0  # initiate
    assert engaged[INFER_DRINK - S.actions_of(ENGAGED).start] == 1.0
    assert tk[INFER_TEA - S.actions_of(TK).start] == 1.0
    served(learner, 2, HERE)
    assert learner.held(HERE) == (PERFORM_TEA, 2.0)


def test_a_refused_routine_is_asked_about_there_only() -> None:
    learner = routine()
    for e in range(1, 6):
        served(learner, 2 * e - 1, HERE)
        served(learner, 2 * e, THERE)
    served(learner, 11, HERE, accepted=False)
    assert learner.held(HERE) == (PERFORM_TEA, -1.0)
    assert probabilities(learner, HERE, ENGAGED, 12)[0] == 1.0  # asks which service
    assert probabilities(learner, HERE, TK, 12)[0] == 1.0  # and which detail
    # the other context keeps its routine
    assert (
        probabilities(learner, THERE, ENGAGED, 12)[INFER_DRINK - S.actions_of(ENGAGED).start] == 1.0
    )
    assert learner.changes == ()  # a refusal alone decides no change


def test_another_service_taken_is_a_change_reported_after_the_update() -> None:
    learner = routine()
    for e in range(1, 4):
        served(learner, e, HERE)
    served(learner, 4, HERE, accepted=False)
    asked_for_coffee(learner, 5, HERE)
    assert learner.decides_changes
    (change,) = learner.changes
    assert (change.episode, change.context, change.source) == (5, HERE, "routine")
    assert item_doc(change.before) == {"service": DRINK, "detail": TEA}
    assert item_doc(change.now) == {"service": DRINK, "detail": "coffee"}
    responses = [(s.episode, s.response) for s in change.evidence]
    assert responses[0] == (4, "rejected")  # the refusal of the routine
    assert (5, "answered") in responses
    assert responses[-1] == (5, "accepted")
    doc = change.to_dict()
    assert json.loads(json.dumps(doc)) == doc
    assert doc["before"] == {"service": DRINK, "detail": TEA}
    assert doc["time_slot"], doc["situation"]
    assert learner.held(HERE) == (PERFORM_COFFEE, 1.0)
    # the next update decides nothing: changes are those of the latest update only
    served(learner, 6, THERE)
    assert learner.changes == ()


def test_offers_turned_down_again_and_again_drop_the_routine() -> None:
    learner = routine()
    for e in range(1, 21):
        served(learner, e, HERE)
    decided: list[ContextChange] = []
    for e in range(21, 30):
        learner.update([Transition(e, HERE, OBS, INITIATE, -2.0, END, NEG)])
        decided += learner.changes
        if learner.held(HERE) is None:
            break
    assert learner.held(HERE) is None
    (change,) = decided
    assert change.now is None
    assert change.figures["p"] < DtsRoutineParams().offer_alpha
    assert change.figures["run"] >= 2  # one turned-down offer is not enough
    # while the latest offer was turned down, the routine does not force an offer
    other = routine()
    served(other, 1, HERE)
    other.update([Transition(2, HERE, OBS, INITIATE, -2.0, END, NEG)])
    assert other.held(HERE) == (PERFORM_TEA, 1.0)
    assert probabilities(other, HERE, OBS, 3)[0] < 1.0 or other.offers[HERE, 2] == 0.0


def test_a_request_resets_the_run_of_refused_offers() -> None:
    learner = routine()
    served(learner, 1, HERE)
    learner.update([Transition(2, HERE, OBS, INITIATE, -2.0, END, NEG)])
    assert learner.offers[HERE, 2] == 1.0
    request = S.request_state(DRINK)
    learner.update([Transition(3, HERE, OBS, PASS, 0.0, request, POS)])
    assert learner.offers[HERE, 2] == 0.0


def test_its_state_round_trips_with_the_routine() -> None:
    learner = routine()
    served(learner, 1, HERE)
    served(learner, 2, THERE, accepted=False)
    learner.update([Transition(3, THERE, OBS, INITIATE, -2.0, END, NEG)])
    doc = json.loads(json.dumps(learner.to_state()))
    assert doc["algorithm"] == "dts-routine"
    copy = learner_from_state(doc, MISSION)
    assert isinstance(copy, DtsRoutineLearner)
    np.testing.assert_array_equal(copy.routine, learner.routine)
    np.testing.assert_array_equal(copy.offers, learner.offers)
    for c in (HERE, THERE):
        for s in (OBS, ENGAGED, TK):
            np.testing.assert_array_equal(
                probabilities(copy, c, s, 4), probabilities(learner, c, s, 4)
            )
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    for e in range(4, 10):
        a = learner.select_action(Observation(THERE, OBS, e), rng_a)
        b = copy.select_action(Observation(THERE, OBS, e), rng_b)
        assert (a.action, list(a.probabilities)) == (b.action, list(b.probabilities))


def test_a_routine_table_no_learner_could_make_is_refused() -> None:
    learner = routine()
    served(learner, 1, HERE)
    doc = learner.to_state()
    bad = routine()
    bad.routine[HERE, PERFORM_TEA] = 1.0
    bad.routine[HERE, PERFORM_COFFEE] = 1.0
    doc["arrays"]["routine"] = bad.to_state()["arrays"]["routine"]
    with pytest.raises(StateFormatError, match="routine"):
        learner_from_state(doc, MISSION)


@pytest.mark.parametrize("name", ["abrupt", "paper"])
def test_it_adapts_near_the_one_miss_oracle_after_a_switch(name: str) -> None:
    methods: list[tuple[str, str, dict[str, Any]]] = [
        ("routine", "dts-routine", {}),
        ("adapt", "dts-adapt", {}),
    ]
    shares: dict[str, list[float]] = {"routine": [], "adapt": []}
    caught: list[int] = []
    missed = 0
    for seed in range(3):
        run = family_run(name, seed, methods)
        assert run.bound is not None
        assert run.change_at is not None
        window = slice(run.change_at, run.change_at + 15)
        for label in shares:
            shares[label].append(run.learners[label][:, window].sum() / run.bound[:, window].sum())
        det = run.detection["routine"]
        caught += [visits for _, visits in det.caught]
        missed += det.missed
    assert np.mean(shares["routine"]) > np.mean(shares["adapt"])
    assert np.mean(shares["routine"]) > 0.75
    assert len(caught) >= 2 * missed  # an ended routine needs turned-down offers to be seen
    assert caught
    assert np.median(caught) <= 3


def test_it_keeps_the_lead_where_nothing_changes() -> None:
    methods: list[tuple[str, str, dict[str, Any]]] = [
        ("routine", "dts-routine", {}),
        ("adapt", "dts-adapt", {}),
    ]
    for name in ("individual", "many"):
        totals = {"routine": 0.0, "adapt": 0.0, "oracle": 0.0}
        alarms = 0
        for seed in range(2):
            run = family_run(name, seed, methods)
            totals["oracle"] += run.oracle.sum()
            for label in ("routine", "adapt"):
                totals[label] += run.learners[label].sum()
            alarms += run.detection["routine"].false_alarms
        assert totals["routine"] > totals["adapt"]
        assert totals["routine"] > 0.8 * totals["oracle"]
        assert alarms <= 2  # 6 persons x 120 events


def family_run(name: str, seed: int, methods: list[tuple[str, str, dict[str, Any]]]) -> Any:
    return run_family(FAMILIES[name], seed, methods, MISSION, n_persons=3, n_events=120)


def test_the_prior_shares_the_routines_a_home_agrees_on_and_leaves_offers_fresh() -> None:
    def contributors(name: str) -> tuple[list[DtsRoutineLearner], list[Any]]:
        persons, flips = people(FAMILIES[name], MISSION, 2, 5, 100)
        out = []
        for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
            learner = routine()
            run_learner(learner, person, u, np.random.default_rng(i))
            out.append(learner)
        return out, list(persons)

    home, residents = contributors("home")
    prior = population_prior("dts-routine", None, MISSION, home)
    assert isinstance(prior, DtsRoutineLearner)
    shared = set(residents[0].profiles[0].needs)
    for person in residents[1:]:
        shared &= set(person.profiles[0].needs)
    seeded = [(c, prior.held(c)) for c in range(MISSION.n_contexts) if prior.held(c) is not None]
    assert seeded
    for c, held in seeded:
        assert held is not None
        need = next(n for n in shared if n.context == c)  # only routines all residents share
        act_ = S.actions[held[0]]
        assert act_.service == MISSION.services[need.service].name
        assert act_.detail == MISSION.services[need.service].details[need.detail]
        assert held[1] == 1.0
    root = list(S.root_actions)
    assert not prior.dns[:, root].any()  # whether to offer is the newcomer's own
    assert not prior.offers.any()
    strangers, _ = contributors("individual")
    alone = population_prior("dts-routine", None, MISSION, strangers)
    assert isinstance(alone, DtsRoutineLearner)
    assert sum(alone.held(c) is not None for c in range(MISSION.n_contexts)) <= 1
