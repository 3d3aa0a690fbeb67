"""``dts-adapt`` (docs/method.md §8, "Adapting after a change"): DTS with trusted answers, slower
forgetting and a change test that also counts ended detail questions. Orderings and bounds on
seeded runs; the conformance, export and replay checks run it with every learner."""

from __future__ import annotations

from typing import Any

import numpy as np

from app.learning import DtsAdaptParams, DtsParams, Observation, Transition, make_learner
from app.learning.learners import DtsAdaptLearner, DtsLearner, learner_from_state
from app.learning.population import FAMILIES, change_event, people, run_learner, run_oracle
from app.learning.space import ActionKind
from tests.support.office import (
    END,
    ENGAGED,
    INFER_DRINK,
    INITIATE,
    MISSION,
    NEG,
    OBS,
    POS,
    QUERY_TYPE,
    TK,
    S,
    act,
)

QUERY_DRINK = act(ActionKind.QUERY_DETAIL, "ProvideDrink")


def adapt(**params: Any) -> DtsAdaptLearner:
    learner = make_learner("dts-adapt", params, MISSION)
    assert isinstance(learner, DtsAdaptLearner)
    return learner


def test_its_defaults_are_dts_with_the_adapting_options_on() -> None:
    params = DtsAdaptParams()
    assert params.algorithm == "dts-adapt"
    assert (params.trust_answers, params.change_on_questions) == (True, True)
    assert params.forgetting > DtsParams().forgetting
    assert params.change_alpha > 0.0
    # dts keeps its behaviour: the options are off there, also for a document that lacks them.
    plain = DtsParams()
    assert (plain.trust_answers, plain.change_on_questions, plain.change_alpha) == (
        False,
        False,
        0.0,
    )
    old = {
        k: v
        for k, v in plain.to_dict().items()
        if k not in ("trust_answers", "change_on_questions")
    }
    assert DtsParams.from_dict(old) == plain


def test_a_state_keeps_its_algorithm_name() -> None:
    learner = adapt()
    doc = learner.to_state()
    assert doc["algorithm"] == "dts-adapt"
    again = learner_from_state(doc, MISSION)
    assert isinstance(again, DtsAdaptLearner)
    assert again.params == learner.params
    assert (
        type(learner_from_state(make_learner("dts", {}, MISSION).to_state(), MISSION)) is DtsLearner
    )


def share(state: int, action: int, learner: DtsLearner, context: int = 3) -> float:
    """The chance of ``action`` in ``state`` of a fresh context, over many draws."""
    rng = np.random.default_rng(5)
    hits = sum(
        learner.select_action(Observation(context, state, 1), rng).action == action
        for _ in range(200)
    )
    return hits / 200


def test_trusted_answers_ask_the_service_first_in_an_unknown_context() -> None:
    # A new context's engaged robot asks which service more often than plain DTS, rather than
    # guessing one and asking its detail (which a person ends 2 times in 3).
    trusting, plain = adapt(), make_learner("dts", {}, MISSION)
    assert isinstance(plain, DtsLearner)
    ask_trusting = share(ENGAGED, QUERY_TYPE, trusting)
    ask_plain = share(ENGAGED, QUERY_TYPE, plain)
    assert ask_trusting > ask_plain + 0.2, (ask_trusting, ask_plain)


def test_an_ended_detail_question_counts_in_the_change_test() -> None:
    ep = 0
    learners = [adapt(), adapt(change_on_questions=False)]
    for learner in learners:
        ep = 0
        for _ in range(25):  # the detail question about drinks is answered, time after time
            ep += 1
            learner.update(
                [
                    Transition(ep, 0, OBS, INITIATE, 1.0, ENGAGED, POS),
                    Transition(ep, 0, ENGAGED, INFER_DRINK, 0.0, TK),
                    Transition(
                        ep,
                        0,
                        TK,
                        QUERY_DRINK,
                        -0.5,
                        S.detail_known_state("ProvideDrink", "tea"),
                        POS,
                    ),
                ]
            )
            perform = S.actions_of(S.detail_known_state("ProvideDrink", "tea")).start
            learner.update(
                [
                    Transition(
                        ep, 0, S.detail_known_state("ProvideDrink", "tea"), perform, 6.0, END, POS
                    )
                ]
            )
        ep += 1  # then the person ends the question: they no longer want a drink there
        learner.update(
            [
                Transition(ep, 0, OBS, INITIATE, 1.0, ENGAGED, POS),
                Transition(ep, 0, ENGAGED, INFER_DRINK, 0.0, TK),
                Transition(ep, 0, TK, QUERY_DRINK, -2.5, END, NEG),
            ]
        )
    counting, ignoring = learners
    assert counting.change[0, 0] == 0.0
    assert counting.dn[0, QUERY_DRINK] == 1.0
    assert ignoring.change[0, 0] == 25.0
    assert ignoring.dn[0, QUERY_DRINK] > 5.0


def shares(algorithm: str, family: str, window: tuple[int, int], seeds: range) -> float:
    mission, total, oracle = MISSION, 0.0, 0.0
    for seed in seeds:
        persons, flips = people(FAMILIES[family], mission, seed, 2, 120)
        for i, (who, u) in enumerate(zip(persons, flips, strict=True)):
            rewards = run_learner(
                make_learner(algorithm, {}, mission), who, u, np.random.default_rng([seed, i])
            )
            total += float(rewards[window[0] : window[1]].sum())
            oracle += float(run_oracle(S, who, u)[window[0] : window[1]].sum())
    return total / oracle


def test_it_learns_faster_and_recovers_sooner_than_dts() -> None:
    at = change_event(120)
    first = (0, 20)
    after = (at, at + 15)
    assert (
        shares("dts-adapt", "individual", first, range(3))
        > shares("dts", "individual", first, range(3)) + 0.05
    )
    assert shares("dts-adapt", "abrupt", after, range(3)) > shares("dts", "abrupt", after, range(3))
