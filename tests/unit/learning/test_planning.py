"""Value iteration by levels (app.learning.planning) and the DTS learner's decisions.

``value_iteration`` skips, in each sweep, the pairs whose values can no longer change (the
negotiation is acyclic); it must give :func:`sweep_value_iteration`'s result bit for bit, stop
included, whatever the tolerance and the sweep limit. The DTS learner draws its models from the
posterior with fewer numpy calls and solves them only as far as a decision needs; its decisions
must be those of the plain planner kept here as the reference (``reference_plan``): the same
probabilities, the same actions and the same random numbers used.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import time
from typing import Any

import numpy as np
import pytest

from app.learning import (
    Mission,
    Observation,
    Polarity,
    Rewards,
    Service,
    TimeSlot,
    Transition,
    make_learner,
    office_mission,
    space_for,
)
from app.learning.learners import DtsLearner
from app.learning.planning import (
    pair_levels,
    space_levels,
    sweep_value_iteration,
    value_iteration,
)
from app.learning.space import NegotiationSpace, StateKind
from app.learning.types import Decision, FloatArray

OFFICE = office_mission()
# Another shape: other numbers of services and details (so another M), situations and rewards.
WORKSHOP = Mission(
    name="workshop",
    time_slots=(
        TimeSlot("day", time(8, 0), time(20, 0)),
        TimeSlot("night", time(20, 0), time(8, 0)),
    ),
    situations=("bench", "break", "away"),
    services=(
        Service("Fetch", ("screws", "glue", "tape", "clamp", "drill", "saw")),
        Service("Light", ("on",)),
    ),
    rewards=Rewards(positive=2.0, accepted_service=3.0, negative=-1.0, query=-0.25),
    gamma=0.95,
)
MISSIONS = [OFFICE, WORKSHOP]


def identical(a: FloatArray, b: FloatArray) -> bool:
    """The same shape and the same bits (np.array_equal would take -0.0 for 0.0)."""
    return a.shape == b.shape and a.tobytes() == b.tobytes()


# -- the reference: the planner as it was, by full sweeps --------------------------------------


def reference_plan(
    learner: DtsLearner, context: int, rng: np.random.Generator | None
) -> FloatArray:
    """Q (samples, P) of a decision's models: the whole (samples, P, M) Dirichlet table drawn
    at once, every model solved by full sweeps."""
    if rng is None:
        rng = np.random.default_rng([learner.version, context])
    k = learner.params.samples
    space = learner.space
    mean, sd, alpha, known = learner._posterior(context)
    g = rng.standard_gamma(np.broadcast_to(alpha, (k, *alpha.shape)))
    total = g.sum(axis=2, keepdims=True)
    sampled = g / np.maximum(total, 1e-300)
    trans = np.where(space.silent[None, :, None], known[None], sampled)
    reward = mean + sd * rng.standard_normal((k, mean.shape[0]))
    a_mean, a_sd = learner._answer_posterior()
    v_answer = a_mean + a_sd * rng.standard_normal(k)
    folded_reward, folded_trans = learner._fold_answers(
        reward, trans, v_answer, learner.mission.gamma
    )
    q = sweep_value_iteration(
        space,
        folded_reward,
        folded_trans,
        gamma=learner.mission.gamma,
        tol=learner.params.vi_tol,
        max_sweeps=learner.params.vi_max_sweeps,
    )
    out: FloatArray = np.clip(q, -learner.mission.v_max, learner.mission.v_max)
    return out


def reference_policy(learner: DtsLearner, plan: FloatArray, state: int) -> FloatArray:
    actions = learner.space.actions_of(state)
    best = np.argmax(plan[:, actions.start : actions.stop], axis=1)
    counts = np.bincount(best, minlength=len(actions)).astype(np.float64)
    out: FloatArray = counts / counts.sum()
    return out


@contextmanager
def as_reference(learner: DtsLearner) -> Iterator[None]:
    """The learner decides (select_action, explain) with the reference planner meanwhile."""
    methods = vars(learner)  # instance attributes shadow the class's methods
    methods["_plan"] = lambda c, e, rng: reference_plan(learner, c, rng)
    methods["_policy"] = lambda plan, c, s, e: reference_policy(learner, plan, s)
    try:
        yield
    finally:
        del methods["_plan"], methods["_policy"]


# -- random learners ---------------------------------------------------------------------------


def teach(learner: DtsLearner, rng: np.random.Generator, episodes: int) -> None:
    """Random whole episodes (any action, any successor it allows, any reward and signal), with
    now and then explicit feedback on the last pair executed."""
    space = learner.space
    for _ in range(episodes):
        ep = learner.episodes + 1
        context = int(rng.integers(space.n_contexts))
        state, batch = space.OBSERVE, []
        while state != space.END:
            actions = space.actions_of(state)
            action = int(rng.integers(actions.start, actions.stop))
            if space.silent[action]:
                nxt, reward = int(space.silent_next[action]), float(space.silent_reward[action])
            else:
                nxt = int(rng.choice(space.succ[action][space.succ_mask[action]]))
                # Now and then far beyond Vmax: clipped values tie, and the first best wins.
                reward = float(rng.normal(0.0, 3.0)) * (40.0 if rng.random() < 0.1 else 1.0)
            signal = Polarity(int(rng.integers(3)))
            batch.append(Transition(ep, context, state, action, reward, nxt, signal))
            state = nxt
        learner.update(batch)
        if rng.random() < 0.2:
            last = batch[-1]
            learner.feedback(ep, context, last.action, float(rng.normal(0.0, 2.0)))


PARAMS: list[dict[str, Any]] = [
    {},
    {"samples": 1},
    {"samples": 5, "forgetting": 1.0, "prior_count": 0.05},
    {"vi_tol": 0.3},  # stops before every value is final
    {"vi_max_sweeps": 2},  # too few sweeps for the top level
    {"trust_answers": True, "change_alpha": 0.2, "change_on_questions": True},
]


def learners(seed: int) -> Iterator[tuple[str, DtsLearner]]:
    """Learners of both DTS algorithms, several parameter sets and both missions, taught random
    histories of random lengths (a fresh one included)."""
    rng = np.random.default_rng(seed)
    for mission in MISSIONS:
        for algorithm in ("dts", "dts-adapt"):
            for params in PARAMS:
                learner = make_learner(algorithm, params, mission)
                assert isinstance(learner, DtsLearner)
                teach(learner, rng, int(rng.choice([0, 3, 40])))
                yield f"{mission.name}/{algorithm}/{params}", learner


# -- levels ------------------------------------------------------------------------------------


@pytest.mark.parametrize("mission", MISSIONS, ids=lambda m: m.name)
def test_a_negotiation_is_acyclic_by_levels(mission: Mission) -> None:
    space = space_for(mission)
    # Every successor of a pair comes later in the state order, or is END.
    for p in range(space.n_actions):
        nxt = space.succ[p][space.succ_mask[p]]
        assert np.all((nxt > space.pair_state[p]) | (nxt == space.END))
    level = space_levels(space)
    assert level is not None
    expected = {
        StateKind.DETAIL_KNOWN: 0,
        StateKind.TYPE_KNOWN: 1,
        StateKind.ENGAGED: 2,
        StateKind.REQUEST: 2,
        StateKind.OBSERVE: 3,
    }
    kinds = [space.states[int(s)].kind for s in space.pair_state]
    assert level.tolist() == [expected[kind] for kind in kinds]


def test_pair_levels_of_hand_made_spaces() -> None:
    # States 0, 1, 2 (END = 3); pairs: 0 -> {1, END}, 1 -> {2}, 2 -> {END}, 3 (state 2) -> {1}.
    state_start = np.array([0, 1, 2])
    acyclic = np.array([[1, 3], [2, 3], [3, 3], [3, 3]])
    level = pair_levels(acyclic, state_start, 3)
    assert level is not None
    assert level.tolist() == [2, 1, 0, 0]
    cyclic = acyclic.copy()
    cyclic[3] = [1, 3]  # state 2 leads back to state 1
    assert pair_levels(cyclic, state_start, 3) is None
    looping = acyclic.copy()
    looping[2] = [2, 3]  # state 2 leads to itself
    assert pair_levels(looping, state_start, 3) is None
    assert pair_levels(acyclic, np.array([0, 2, 2]), 3) is None  # a state without pairs


# -- value iteration by levels against full sweeps ---------------------------------------------


def random_model(
    space: NegotiationSpace, rng: np.random.Generator, batch: tuple[int, ...]
) -> tuple[FloatArray, FloatArray]:
    """Rewards and transitions; some probabilities tiny, so that sweeps stop before the end."""
    P, M = space.n_actions, space.max_succ
    weights = np.where(space.succ_mask, rng.random((*batch, P, M)) ** rng.choice([1, 12]), 0.0)
    trans = weights / weights.sum(axis=-1, keepdims=True)
    reward = rng.normal(size=(*batch, P)) * rng.choice([1e-9, 1e-3, 0.1, 1.0, 1e3])
    return reward, trans


@pytest.mark.parametrize("mission", MISSIONS, ids=lambda m: m.name)
def test_value_iteration_is_the_full_sweeps_bit_for_bit(mission: Mission) -> None:
    space = space_for(mission)
    level = space_levels(space)
    assert level is not None
    rng = np.random.default_rng(11)
    early = {"by the tolerance": 0, "by the limit": 0}
    for batch in [(), (1,), (16,), (3, 4)]:
        for trial in range(60):
            reward, trans = random_model(space, rng, batch)
            fixed = None
            if trial % 3 == 1:
                fixed = rng.random(space.n_actions) < 0.3  # R-MAX's and HRI's shape
            elif trial % 3 == 2:
                fixed = rng.random((*batch, space.n_actions)) < 0.3
            kw: dict[str, Any] = {
                "gamma": mission.gamma,
                "tol": float(rng.choice([1e-8, 1e-3, 0.5, 1.0])),
                "max_sweeps": int(rng.choice([1, 2, 3, 500, 500])),
                "fixed": fixed,
                "fixed_value": mission.v_max,
            }
            expected = sweep_value_iteration(space, reward, trans, **kw)
            got = value_iteration(space, reward, trans, **kw)
            assert identical(got, expected)
            converged = sweep_value_iteration(
                space, reward, trans, **{**kw, "tol": 0.0, "max_sweeps": 10}
            )
            if not np.array_equal(expected, converged):  # stopped before every value was final
                early["by the tolerance" if kw["max_sweeps"] > 3 else "by the limit"] += 1
            for wanted in range(4):
                part = value_iteration(space, reward, trans, level=wanted, **kw)
                keep = level <= wanted
                assert identical(part[..., keep], expected[..., keep])
    assert min(early.values()) >= 10, early  # both ways of stopping early were exercised


def test_a_cyclic_space_takes_the_full_sweeps() -> None:
    space = copy.copy(space_for(OFFICE))
    succ = space.succ.copy()
    perform = space.n_actions - 1  # the last DETAIL_KNOWN state's service...
    succ[perform, 0] = space.OBSERVE  # ...leads back to the start
    space.succ = succ
    assert space_levels(space) is None
    mask = space.succ_mask.copy()
    mask[perform, :2] = True  # back to the start, or END (a padding column)
    rng = np.random.default_rng(3)
    trans = np.where(mask, rng.random((16, space.n_actions, space.max_succ)), 0.0)
    trans /= trans.sum(axis=-1, keepdims=True)
    reward = rng.normal(size=(16, space.n_actions))
    kw: dict[str, Any] = {"gamma": 0.9, "tol": 1e-10, "max_sweeps": 1000}
    q = value_iteration(space, reward, trans, **kw)
    assert identical(q, sweep_value_iteration(space, reward, trans, **kw))
    v = np.concatenate(
        [np.maximum.reduceat(q, space.state_start, axis=-1), np.zeros((16, 1))], axis=-1
    )
    bellman = reward + 0.9 * np.einsum("kpm,kpm->kp", trans, v[:, succ])
    assert np.allclose(q, bellman, atol=1e-8)  # converged over the cycle


@pytest.mark.parametrize("bad", [np.inf, np.nan, 1e305])
def test_unbounded_rewards_take_the_full_sweeps(bad: float) -> None:
    space = space_for(OFFICE)
    reward, trans = random_model(space, np.random.default_rng(5), (4,))
    reward[1, 3] = bad
    kw: dict[str, Any] = {"gamma": 0.9, "tol": 1e-8, "max_sweeps": 500}
    with np.errstate(all="ignore"):
        got = value_iteration(space, reward, trans, **kw)
        expected = sweep_value_iteration(space, reward, trans, **kw)
    assert np.array_equal(got, expected, equal_nan=True)


# -- the DTS learner's decisions against the reference -----------------------------------------


def test_a_zero_gamma_shape_draws_nothing() -> None:
    """What drawing only the possible successors' gamma variates relies on: a zero shape gives 0
    and leaves the generator as it was, so the other draws are those of the whole table."""
    alpha = np.array([0.25, 0.0, 3.0, 0.0, 1.0, 0.0])
    whole, some = np.random.default_rng(9), np.random.default_rng(9)
    table = whole.standard_gamma(np.broadcast_to(alpha, (5, 6)))
    drawn = some.standard_gamma(np.broadcast_to(alpha[alpha > 0], (5, 3)))
    assert np.array_equal(table[:, alpha > 0], drawn)
    assert np.all(table[:, alpha == 0] == 0.0)
    assert whole.bit_generator.state == some.bit_generator.state


def same_decision(a: Decision, b: Decision) -> bool:
    return (
        (a.context, a.state, a.action) == (b.context, b.state, b.action)
        and np.array_equal(a.probabilities, b.probabilities)
        and len(a.chain) == len(b.chain)
        and all(
            (x.state, x.action, x.next_state, x.reward)
            == (y.state, y.action, y.next_state, y.reward)
            and np.array_equal(x.probabilities, y.probabilities)
            for x, y in zip(a.chain, b.chain, strict=True)
        )
    )


@pytest.mark.parametrize("seed", [1, 2])
def test_decisions_are_the_reference_planners(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    checked = 0
    for name, learner in learners(seed):
        space = learner.space
        contexts = rng.choice(space.n_contexts, size=min(3, space.n_contexts), replace=False)
        for context in (int(c) for c in contexts):
            # The models' Q, solved all the way, and the random numbers they take.
            draw_seed = int(rng.integers(2**32))
            new_rng, old_rng = np.random.default_rng(draw_seed), np.random.default_rng(draw_seed)
            q = learner._solved(learner._plan(context, 1, new_rng), space.OBSERVE)
            assert identical(q, reference_plan(learner, context, old_rng)), name
            assert new_rng.bit_generator.state == old_rng.bit_generator.state, name
            # A decision in every state: probabilities, action, silent steps, random numbers.
            for state in range(space.n_states):
                obs = Observation(context, state, learner.episodes + 1)
                draw_seed = int(rng.integers(2**32))
                new_rng, old_rng = (
                    np.random.default_rng(draw_seed),
                    np.random.default_rng(draw_seed),
                )
                got = learner.select_action(obs, new_rng)
                with as_reference(learner):
                    expected = learner.select_action(obs, old_rng)
                assert same_decision(got, expected), (name, context, space.state_name(state))
                assert new_rng.bit_generator.state == old_rng.bit_generator.state, name
                checked += 1
            view = learner.explain(context, learner.episodes + 1)
            with as_reference(learner):
                reference_view = learner.explain(context, learner.episodes + 1)
            assert np.array_equal(view.probabilities, reference_view.probabilities), name
    assert checked > 900
