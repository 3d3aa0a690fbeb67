"""Do not disturb: in a context of the mission's unavailable situations the robot never
initiates, for every learner, whatever its tables say; a staff ``quiet`` correction gives the
same guarantee for one person and one context (app.learning.masks)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from app.learning import (
    ALGORITHMS,
    Mission,
    Observation,
    learner_from_state,
    make_learner,
    office_mission,
    remap_learner,
)
from app.learning.guidance import Rule, RuleKind
from app.learning.learners import TabularLearner
from app.learning.masks import initiates_never
from app.learning.population import Person, run_learner, uniforms_for
from app.learning.simulation import Need, UserProfile

OFFICE = office_mission()
SLOT, BUSY = "afternoon", "busy"


def _open_office() -> Mission:
    """The office mission with no unavailable situation: a person may welcome the robot while
    busy."""
    doc = OFFICE.to_dict()
    doc["unavailable_situations"] = []
    return Mission.from_dict(doc)


def _eager(algorithm: str, mission: Mission, context: int, n: int = 60) -> TabularLearner[Any]:
    """A learner of ``mission`` that served, ``n`` times, a person who wants tea in ``context``
    and accepts every offer there."""
    learner = make_learner(algorithm, None, mission)
    profile = UserProfile((Need(context, 0, 0),), p_acc=1.0, p_self=0.0)
    person = Person(
        profiles=(profile,),
        schedule=np.zeros(n, dtype=np.int64),
        contexts=np.full(n, context, dtype=np.int64),
    )
    rng = np.random.default_rng(7)
    run_learner(learner, person, uniforms_for(rng, n), rng)
    return learner


def _p_initiate(learner: TabularLearner[Any], context: int) -> float:
    return float(learner.explain(context, learner.episodes + 1).probabilities[0])


def _drawn_initiations(learner: TabularLearner[Any], context: int, draws: int = 300) -> int:
    rng = np.random.default_rng(11)
    space = learner.space
    out = 0
    for _ in range(draws):
        d = learner.select_action(Observation(context, space.OBSERVE, learner.episodes + 1), rng)
        out += int(d.action == space.INITIATE)
        if space.unavailable[context] and d.state == space.OBSERVE:
            assert d.probabilities.tolist() == [0.0, 1.0]
    return out


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_a_fresh_learner_never_initiates_in_an_unavailable_situation(algorithm: str) -> None:
    learner = make_learner(algorithm, None, OFFICE)
    space = learner.space
    rng = np.random.default_rng(3)
    for c in range(space.n_contexts):
        d = learner.select_action(Observation(c, space.OBSERVE, 1), rng)
        if space.unavailable[c]:
            assert OFFICE.context_names(c)[1] == BUSY
            assert d.action == space.PASS
            assert d.probabilities.tolist() == [0.0, 1.0]
            assert learner.explain(c, 1).probabilities[space.INITIATE] == 0.0
        else:
            assert learner.explain(c, 1).probabilities[space.INITIATE] > 0.0


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_a_mission_that_adds_the_situation_stops_what_was_learned(algorithm: str) -> None:
    open_office = _open_office()
    c = open_office.context_index(SLOT, BUSY)
    learner = _eager(algorithm, open_office, c)
    # Under the open mission the learner has learned to offer here: the rule has work to do.
    assert _p_initiate(learner, c) > 0.5
    assert _drawn_initiations(learner, c) > 100

    moved = remap_learner(learner, OFFICE)  # the mission change that adds "busy"
    space = moved.space
    assert space.unavailable[c]
    assert _p_initiate(moved, c) == 0.0
    assert _drawn_initiations(moved, c) == 0
    # Everything else stays the learner's own: the tables, and every other state's choice.
    for name, (table, _) in learner._exported().items():
        assert np.array_equal(table, moved._exported()[name][0]), name
    own, masked = learner.explain(c, 61).probabilities, moved.explain(c, 61).probabilities
    rest = slice(space.actions_of(space.OBSERVE).stop, None)
    assert np.array_equal(own[rest], masked[rest])
    # An import of that model, and a correction that prefers to offer, change nothing.
    imported = learner_from_state(moved.to_state(), OFFICE)
    assert _drawn_initiations(imported, c) == 0
    imported.correct(Rule("p", RuleKind.PREFERS, SLOT, BUSY, "ProvideDrink", "tea"))
    assert _p_initiate(imported, c) == 0.0
    assert _drawn_initiations(imported, c) == 0

    back = remap_learner(moved, open_office)  # the change that removes it: learning resumes
    assert np.array_equal(back.explain(c, 61).probabilities, own)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_a_person_who_asks_is_served_as_usual(algorithm: str) -> None:
    """What follows pass is the person's: a request in an unavailable situation is answered by
    the learner's own choices, exactly as without the rule."""
    open_office = _open_office()
    c = open_office.context_index(SLOT, BUSY)
    learner = _eager(algorithm, open_office, c)
    moved = remap_learner(learner, OFFICE)
    space = moved.space
    for state in (space.request_state("ProvideDrink"), space.ENGAGED):
        for seed in range(20):
            a = learner.select_action(Observation(c, state, 61), np.random.default_rng(seed))
            b = moved.select_action(Observation(c, state, 61), np.random.default_rng(seed))
            assert (a.state, a.action) == (b.state, b.action)
            assert np.array_equal(a.probabilities, b.probabilities)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_a_quiet_correction_gives_the_same_guarantee(algorithm: str) -> None:
    c = OFFICE.context_index(SLOT, "stretching")
    learner = _eager(algorithm, OFFICE, c)
    assert _p_initiate(learner, c) > 0.5
    assert not initiates_never(learner.space, learner.guidance, c)
    learner.correct(Rule("q", RuleKind.QUIET, SLOT, "stretching"))
    learner.correct(Rule("p", RuleKind.PREFERS, SLOT, "stretching", "ProvideDrink", "tea"))
    assert initiates_never(learner.space, learner.guidance, c)
    assert _p_initiate(learner, c) == 0.0
    assert _drawn_initiations(learner, c) == 0
    learner.lift("q")
    assert _p_initiate(learner, c) > 0.9  # the prefers rule steers again


def test_the_unavailable_contexts_are_the_missions() -> None:
    space = make_learner("hri", None, OFFICE).space
    busy = [c for c in range(space.n_contexts) if OFFICE.context_names(c)[1] == BUSY]
    assert np.flatnonzero(space.unavailable).tolist() == busy
    assert not make_learner("hri", None, _open_office()).space.unavailable.any()
