"""DTS's per-context change test (docs/method.md §8, "Adapting after a change"): it fires when a
simulated person's wish switches and seldom on a steady noisy one, touches only the context that
changed, lives in the exported tables (round trip, replay) and helps after a change."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from app.learning import StateFormatError, Transition, learner_from_state, make_learner, space_for
from app.learning.learners import DtsLearner
from app.learning.population import (
    FAMILIES,
    Person,
    change_event,
    people,
    run_learner,
    run_oracle,
    uniforms_for,
)
from app.learning.simulation import Need, UserProfile
from tests.support.office import (
    DK,
    END,
    ENGAGED,
    INFER_DRINK,
    INFER_TEA,
    INITIATE,
    MISSION,
    NEG,
    OBS,
    PERFORM_TEA,
    POS,
    TK,
    S,
)

ON = {"change_alpha": 0.01}
SEEDS = range(6)
EVENTS, SWITCH = 120, 60


def dts(**params: Any) -> DtsLearner:
    learner = make_learner("dts", params, MISSION)
    assert isinstance(learner, DtsLearner)
    return learner


def spy(learner: DtsLearner) -> list[tuple[int, int]]:
    """(context, episode) of every restart the change test makes."""
    fired: list[tuple[int, int]] = []
    test = learner._test_change

    def recording(c: int, *, accepted: bool) -> None:
        test(c, accepted=accepted)
        if not accepted and not learner.change[c].any():  # a rejection leaves a run unless reset
            fired.append((c, learner.episodes))

    learner._test_change = recording  # type: ignore[method-assign]
    return fired


def person(seed: int, *, switch: bool, p_random: float = 0.0) -> tuple[Person, np.ndarray]:
    """Two routines (contexts 0 and 1); with ``switch`` the drink in context 0 changes from tea
    to coffee at event SWITCH."""
    rng = np.random.default_rng(seed)
    before = UserProfile(needs=(Need(0, 0, 0), Need(1, 1, 1)))
    after = UserProfile(needs=(Need(0, 0, 1), Need(1, 1, 1))) if switch else before
    schedule = (np.arange(EVENTS) >= SWITCH).astype(np.int64)
    contexts = rng.choice([0, 1], size=EVENTS).astype(np.int64)
    return Person((before, after), schedule, contexts, p_random=p_random), uniforms_for(rng, EVENTS)


def restarts(seed: int, **kwargs: Any) -> list[tuple[int, int]]:
    learner = dts(**ON)
    fired = spy(learner)
    who, flips = person(seed, **kwargs)
    run_learner(learner, who, flips, np.random.default_rng([seed, 7]))
    return fired


def test_the_test_fires_soon_after_a_switch_and_only_where_it_happened() -> None:
    delays, kept = [], 0
    for seed in SEEDS:
        fired = restarts(seed, switch=True)
        after = [ep for c, ep in fired if c == 0 and ep > SWITCH]
        assert after, f"seed {seed}: no restart after the switch"
        # Events of context 0 from the switch to the first restart after it.
        who, _ = person(seed, switch=True)
        delays.append(int(np.sum(who.contexts[SWITCH : after[0]] == 0)))
        kept += len([ep for c, ep in fired if c == 1 and ep > SWITCH])  # its wish stayed
    assert np.mean(delays) <= 4.0  # a few rejections, not a slow drift of the counts
    assert kept <= 1  # a rare run of the person's own noise (5 % of right services refused)


def test_a_steady_noisy_person_restarts_less_than_a_switching_one() -> None:
    steady = [
        len([ep for _, ep in restarts(s, switch=False, p_random=0.1) if ep > 40]) for s in SEEDS
    ]
    switching = [
        len([ep for c, ep in restarts(s, switch=True) if c == 0 and ep > SWITCH]) for s in SEEDS
    ]
    assert np.mean(steady) < np.mean(switching)
    assert np.mean(steady) <= 1.0  # seldom, once learned, in 80 events of 10 % random answers


def test_off_by_default_and_off_changes_nothing() -> None:
    assert dts().params.change_alpha == 0.0
    learner = dts()
    who, flips = person(0, switch=True)
    run_learner(learner, who, flips, np.random.default_rng(1))
    assert not learner.change.any()


def accepted_tea(ep: int, c: int) -> list[Transition]:
    return [
        Transition(ep, c, OBS, INITIATE, 1.0, ENGAGED, POS),
        Transition(ep, c, ENGAGED, INFER_DRINK, 0.0, TK),
        Transition(ep, c, TK, INFER_TEA, 0.0, DK),
        Transition(ep, c, DK, PERFORM_TEA, 6.0, END, POS),
    ]


def rejected_tea(ep: int, c: int) -> list[Transition]:
    return [*accepted_tea(ep, c)[:3], Transition(ep, c, DK, PERFORM_TEA, -6.0, END, NEG)]


def test_a_restart_touches_only_the_changed_context_and_keeps_its_offers() -> None:
    learner, plain = dts(**ON), dts()  # plain: the same learner without the test
    fired = spy(learner)
    ep = 0
    for _ in range(10):
        for c in (0, 1):
            ep += 1
            learner.update(accepted_tea(ep, c))
            plain.update(accepted_tea(ep, c))
    before = learner.change.copy()
    while not fired:
        ep += 1
        learner.update(rejected_tea(ep, 0))
        plain.update(rejected_tea(ep, 0))
        assert ep < 40, "ten acceptances, then rejections, and the test never fired"
    assert fired == [(0, ep)]
    for table in ("dn", "dr", "dns"):
        mine, theirs = getattr(learner, table), getattr(plain, table)
        assert np.array_equal(mine[1], theirs[1])  # the other context: untouched
        roots = list(S.root_actions)
        assert np.array_equal(mine[0, roots], theirs[0, roots])  # the offers: kept
    mask = np.ones(S.n_actions, dtype=bool)
    mask[list(S.root_actions)] = False
    mask[PERFORM_TEA] = False
    # The context's service-facing counts start over; the rejection that set it off is kept.
    assert not learner.dn[0, mask].any()
    assert not learner.dns[0, mask].any()
    assert learner.dn[0, PERFORM_TEA] == 1.0
    assert learner.dr[0, PERFORM_TEA] == -6.0
    assert plain.dn[0, PERFORM_TEA] > 1.0
    assert not learner.change[0].any()
    assert np.array_equal(learner.change[1], before[1])
    assert before[1, 0] == 10


@pytest.mark.parametrize("accepted", [2, 5, 20])
def test_it_fires_at_the_run_the_beta_predictive_makes_unlikely(accepted: int) -> None:
    """After n accepted services and no rejection, k rejections in a row have the predictive
    chance prod_{i<k} (1 + i) / (n + 2 + i) = 1 / C(n + 1 + k, k): the test fires at the first k
    where that is below alpha."""
    expected = next(k for k in range(1, 1000) if 1 / math.comb(accepted + 1 + k, k) < 0.01)
    learner = dts(**ON)
    fired = spy(learner)
    for ep in range(1, accepted + 1):
        learner.update(accepted_tea(ep, 0))
    ep = accepted
    while not fired:
        ep += 1
        learner.update(rejected_tea(ep, 0))
    assert ep - accepted == expected


def snapshot(learner: Any) -> str:
    return json.dumps(learner.to_state(), sort_keys=True)


def test_state_round_trip_and_replay_are_exact() -> None:
    who, flips = person(3, switch=True)
    a, b = dts(**ON), dts(**ON)
    run_learner(a, who, flips, np.random.default_rng(5))
    assert a.change.any()
    restored = learner_from_state(json.loads(snapshot(a)), MISSION)
    assert snapshot(restored) == snapshot(a)
    assert np.array_equal(restored.change, a.change)  # type: ignore[attr-defined]
    # Replay: the same transitions, in the same batches, give the same state.
    batches: list[list[Transition]] = []
    recorder = dts(**ON)
    update = recorder.update

    def record(trs: Any) -> None:
        batches.append(list(trs))
        update(trs)

    recorder.update = record  # type: ignore[method-assign,assignment]
    run_learner(recorder, who, flips, np.random.default_rng(5))
    for batch in batches:
        b.update(batch)
    assert snapshot(b) == snapshot(recorder)
    # Stopping half-way through the journal, exporting and going on changes nothing.
    c = dts(**ON)
    half = len(batches) // 2
    for batch in batches[:half]:
        c.update(batch)
    c = learner_from_state(json.loads(snapshot(c)), MISSION)  # type: ignore[assignment]
    for batch in batches[half:]:
        c.update(batch)
    assert snapshot(c) == snapshot(recorder)


def test_a_state_from_before_the_test_existed_still_loads() -> None:
    learner = dts()
    learner.update(accepted_tea(1, 0))
    doc = json.loads(snapshot(learner))
    del doc["arrays"]["change"]
    doc["params"] = {k: v for k, v in doc["params"].items() if not k.startswith("change_")}
    restored = learner_from_state(doc, MISSION)
    assert np.array_equal(restored.dn, learner.dn)  # type: ignore[attr-defined]
    assert not restored.change.any()  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    "bad",
    [{"change_alpha": -0.1}, {"change_alpha": 0.6}, {"change_keep": 1.0}, {"change_keep": -1.0}],
)
def test_bad_change_parameters_are_refused(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(bad))):
        dts(**bad)


def test_after_a_change_the_test_earns_more_than_forgetting_alone() -> None:
    """On the suite's abrupt family (a few seeds, common random numbers: both learners draw from
    the same generator, so only the test makes them differ): the share of the oracle's reward
    in the events after the change, summed over seeds, is higher with the test, and the share
    before the change is the same."""
    family, events = FAMILIES["abrupt"], 130
    space = space_for(MISSION)
    at = change_event(events)
    windows = {"before": slice(at - 30, at), "after": slice(at, at + 15)}
    earned = {(v, w): 0.0 for v in ("off", "on") for w in windows}
    oracle = dict.fromkeys(windows, 0.0)
    for seed in range(4):
        persons, flips = people(family, MISSION, seed, 2, events)
        for i, (who, u) in enumerate(zip(persons, flips, strict=True)):
            best = run_oracle(space, who, u)
            for w, span in windows.items():
                oracle[w] += float(best[span].sum())
            for v, params in (("off", {}), ("on", ON)):
                got = run_learner(dts(**params), who, u, np.random.default_rng([seed, i]))
                for w, span in windows.items():
                    earned[v, w] += float(got[span].sum())
    share = {k: x / oracle[k[1]] for k, x in earned.items()}
    assert share["on", "after"] > share["off", "after"]
    assert share["on", "before"] >= share["off", "before"] - 0.02


def test_a_state_with_an_impossible_run_chance_is_refused() -> None:
    learner = dts(**ON)
    learner.update(rejected_tea(1, 0))
    assert 0.0 < learner.change[0, 3] <= 1.0
    learner.change[0, 3] = 2.0
    with pytest.raises(StateFormatError, match="change"):
        learner_from_state(json.loads(snapshot(learner)), MISSION)
