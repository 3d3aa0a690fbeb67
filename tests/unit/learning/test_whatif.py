"""What if, in simulation: a logged run earns what the plain run earns, a learner replayed over
its own log is the logger again (weights 1, the same tables), ``distributions`` is what
``select_action`` draws from, prefixes keep each person's first episodes, and the estimates of
a candidate near the logger cover its true value while one far from it is refused."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from app.learning import office_mission
from app.learning.learners import make_learner
from app.learning.offpolicy import estimate, on_policy, point
from app.learning.population import FAMILIES, Person, people, run_learner
from app.learning.space import space_for
from app.learning.types import Observation
from app.learning.whatif import PersonLog, log_person, replay, replay_all, replay_values, steps_of

MISSION = office_mission()
SPACE = space_for(MISSION)
HRI = ("hri", {"tau": 0.01})


def _rng(*words: int) -> np.random.Generator:
    return np.random.default_rng(list(words))


def _fleet(
    family: str, seed: int, persons: int, events: int
) -> tuple[tuple[Person, ...], list[np.ndarray]]:
    return people(FAMILIES[family], MISSION, seed, persons, events)


def _logs(
    algorithm: str,
    params: dict[str, float],
    persons: Sequence[Person],
    flips: Sequence[np.ndarray],
    seed: int,
) -> list[PersonLog]:
    return [
        log_person(make_learner(algorithm, params, MISSION), p, u, _rng(seed, i))
        for i, (p, u) in enumerate(zip(persons, flips, strict=True))
    ]


def test_a_logged_run_earns_what_the_plain_run_earns() -> None:
    persons, flips = _fleet("abrupt", 3, 2, 60)
    for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
        plain = run_learner(make_learner("dts-routine", {}, MISSION), person, u, _rng(3, i))
        log = log_person(make_learner("dts-routine", {}, MISSION), person, u, _rng(3, i))
        assert np.array_equal(np.asarray(log.returns), plain)
        assert {d.event for d in log.decisions} == set(range(60))


def test_the_logger_replayed_over_its_own_log_is_the_logger_again() -> None:
    persons, flips = _fleet("individual", 1, 3, 50)
    logs, learners = [], []
    for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
        learner = make_learner(*HRI, MISSION)
        logs.append(log_person(learner, person, u, _rng(1, i)))
        learners.append(learner)
    replays = []
    for log, logger in zip(logs, learners, strict=True):
        candidate = make_learner(*HRI, MISSION)
        replays.append(replay(log, candidate, _rng(99)))
        assert candidate.to_state() == logger.to_state()  # it learned exactly what the logger did
    steps = steps_of(logs, replays, SPACE.actions_of)
    assert np.allclose(steps.target, steps.logged)  # HRI draws no plan: the same distributions
    assert steps.unsupported.max() == 0.0
    mean_return = float(np.mean([r for log in logs for r in log.returns]))
    for estimator in ("pdis", "wpdis"):
        assert point(steps, estimator) == pytest.approx(mean_return)
    found = estimate(steps, "pdis")
    assert found.ess == pytest.approx(steps.n_episodes)
    assert found.weight_mean == pytest.approx(1.0)
    assert on_policy(steps).value == pytest.approx(mean_return)


@pytest.mark.parametrize("algorithm", ["hri", "dts", "dts-routine", "qlearning", "rmax"])
def test_distributions_are_what_select_action_draws_from(algorithm: str) -> None:
    persons, flips = _fleet("home", 2, 1, 30)
    learner = make_learner(algorithm, {}, MISSION)
    log_person(learner, persons[0], flips[0], _rng(2))  # a learner with some history
    for context in range(SPACE.n_contexts):
        for state in (SPACE.OBSERVE, *range(SPACE.n_states)):
            if state == SPACE.END:
                continue
            obs = Observation(context, state, 31)
            decision = learner.select_action(obs, _rng(context, state))
            states = [step.state for step in decision.chain] + [decision.state]
            mine = learner.distributions(context, states, 31, _rng(context, state))
            drawn = [step.probabilities for step in decision.chain] + [decision.probabilities]
            assert len(mine) == len(drawn)
            for a, b in zip(mine, drawn, strict=True):
                assert np.allclose(a, b)
            q = learner.action_values(context)
            assert q.shape == (SPACE.n_actions,)
            assert np.isfinite(q).all()
            assert np.array_equal(learner.action_values(context, gamma=MISSION.gamma), q)
            assert np.isfinite(learner.action_values(context, gamma=1.0)).all()
    with pytest.raises(ValueError, match="gamma"):
        learner.action_values(0, gamma=1.5)


@pytest.mark.parametrize("algorithm", ["hri", "dts", "dts-routine", "qlearning", "rmax"])
def test_undiscounted_model_values_follow_what_the_learner_learns(algorithm: str) -> None:
    # Asked before and after each decision is learned, as a replay asks: the undiscounted values
    # must be the learner's of the moment, never those of the first time they were asked.
    persons, flips = _fleet("home", 5, 1, 40)
    log = _logs(algorithm, {}, persons, flips, 5)[0]
    learner = make_learner(algorithm, {}, MISSION)
    changed = 0
    for d in log.decisions:
        context = d.transitions[0].context
        before = learner.action_values(context, gamma=1.0)
        learner.update(list(d.transitions))
        after = learner.action_values(context, gamma=1.0)
        fresh = make_learner(algorithm, {}, MISSION)
        fresh.__dict__.update(learner.__dict__)  # the same tables, nothing cached
        fresh._cache = {}
        assert np.array_equal(after, fresh.action_values(context, gamma=1.0))
        changed += not np.array_equal(before, after)
    assert changed > 0


@pytest.mark.parametrize("algorithm", ["hri", "dts"])
def test_undiscounted_model_values_are_in_the_unit_of_a_return(algorithm: str) -> None:
    # What an episode returns is the plain sum of its rewards; the learners plan with a
    # discount. The doubly robust estimate's model (action_values with gamma=1.0) must speak of
    # returns: over the pairs a learner begins its episodes with, its undiscounted values lie
    # closer to the returns that followed them than the discounted ones. (R-MAX's model values
    # what it has not tried yet at its optimistic bound: no unit helps there.)
    persons, flips = _fleet("individual", 4, 3, 120)
    plain_error = discounted_error = 0.0
    for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
        learner = make_learner(algorithm, {}, MISSION)
        log = log_person(learner, person, u, _rng(4, i))
        returns: dict[tuple[int, int], list[float]] = {}
        for d in log.decisions:
            first = d.transitions[0]
            if d.event >= 60 and first.state == SPACE.OBSERVE:  # settled; the episode's start
                returns.setdefault((first.context, first.action), []).append(log.returns[d.event])
        for (context, action), seen in returns.items():
            if len(seen) >= 5:
                mean = float(np.mean(seen))
                plain_error += abs(learner.action_values(context, gamma=1.0)[action] - mean)
                discounted_error += abs(learner.action_values(context)[action] - mean)
    assert plain_error < discounted_error


def test_a_prefix_keeps_each_persons_first_episodes() -> None:
    persons, flips = _fleet("shy", 4, 3, 20)
    logs = _logs(*HRI, persons, flips, 4)
    replays = [replay(log, make_learner(*HRI, MISSION), _rng(5)) for log in logs]
    whole = steps_of(logs, replays, SPACE.actions_of)
    first = steps_of(logs, replays, SPACE.actions_of, events=5)
    assert whole.n_episodes == 60
    assert first.n_episodes == 15
    assert np.array_equal(first.cluster, np.repeat([0, 1, 2], 5))
    for p in range(3):
        assert first.select(first.cluster == p).returns() == pytest.approx(logs[p].returns[:5])


def test_a_near_candidate_is_estimated_and_a_far_one_refused() -> None:
    """Logged under HRI τ=0.01 (every action possible): HRI τ=0.02 is estimated, and its
    interval holds its true value in most fleets; DTS, which mostly does what HRI seldom does,
    has importance weights averaging well under 1 and is refused at a thousand episodes."""
    covered, refused = 0, 0
    near_means: list[float] = []
    far_means: list[float] = []
    fleets = 3
    for seed in range(fleets):
        persons, flips = _fleet(("individual", "abrupt", "home")[seed], seed, 10, 100)
        logs = _logs(*HRI, persons, flips, seed)
        for algorithm, params in (("hri", {"tau": 0.02}), ("dts", {})):
            replays = [
                replay(log, make_learner(algorithm, params, MISSION), _rng(seed, i, 7))
                for i, log in enumerate(logs)
            ]
            found = estimate(steps_of(logs, replays, SPACE.actions_of), rng=_rng(seed))
            if algorithm == "hri":
                truth = np.mean(
                    [
                        run_learner(
                            make_learner(algorithm, params, MISSION), p, u, _rng(seed, i, 8, r)
                        )
                        for i, (p, u) in enumerate(zip(persons, flips, strict=True))
                        for r in range(2)
                    ]
                )
                assert found.enough
                assert found.interval is not None
                covered += int(found.interval.low <= truth <= found.interval.high)
                near_means.append(found.weight_mean)
            else:
                far_means.append(found.weight_mean)
                refused += not found.enough and "rarely show" in found.reason
    assert covered >= fleets - 1
    assert min(near_means) > 0.9
    assert max(far_means) < 0.8
    assert refused == fleets


def test_candidates_that_learn_alike_are_replayed_once_with_the_same_answers() -> None:
    """``replay_all`` answers for each candidate exactly what its own replay answers, whether
    it learns alike with another (HRI at other temperatures, a temporal measure counted per
    context) or not (another algorithm, another m_h); the candidates that only decided are
    left untaught."""
    persons, flips = _fleet("abrupt", 5, 2, 60)
    candidates: list[tuple[str, dict[str, object]]] = [
        ("hri", {"tau": 0.005}),
        ("dts", {}),
        ("hri", {"tau": 0.1, "kappa": 0.5, "staleness": "context"}),
        ("hri", {"m_h": 2.0}),
        ("hri", {"tau": 0.2}),
    ]
    for i, log in enumerate(_logs(*HRI, persons, flips, 5)):
        alone = [
            replay(log, make_learner(a, p, MISSION), _rng(5, i, k))
            for k, (a, p) in enumerate(candidates)
        ]
        learners = [make_learner(a, p, MISSION) for a, p in candidates]
        together = replay_all(log, learners, [_rng(5, i, k) for k in range(len(candidates))])
        for one, other in zip(alone, together, strict=True):
            for name in ("target", "unsupported", "q_hat", "v_hat"):
                assert np.array_equal(getattr(one, name), getattr(other, name)), name
        assert [learner.version for learner in learners] == [
            len(log.decisions),
            len(log.decisions),
            0,
            len(log.decisions),
            0,
        ]


def test_a_learner_decides_as_other_params_only_where_they_do_not_change_what_it_learns() -> None:
    learner = make_learner("hri", {"tau": 0.01}, MISSION)
    hotter = make_learner("hri", {"tau": 0.5}, MISSION).params
    assert learner.learns_as(hotter)
    with learner.deciding_as(hotter) as deciding:
        assert deciding.params.tau == 0.5
    assert learner.params.tau == 0.01
    other = make_learner("hri", {"m_h": 3.0}, MISSION).params
    assert not learner.learns_as(other)
    with pytest.raises(ValueError, match="may differ only in"), learner.deciding_as(other):
        pass
    dts = make_learner("dts", {}, MISSION)
    assert not dts.learns_as(make_learner("dts", {"samples": 4}, MISSION).params)
    assert not learner.learns_as(dts.params)


def test_the_replays_value_is_taught_as_the_replay_teaches_and_near_the_truth_near_the_logger() -> (
    None
):
    """``replay_values`` leaves the candidate taught exactly as ``replay`` teaches it (the
    copies that served are dropped); for a candidate that acts almost as the logger, the
    value of "the candidate learning from these logs" is close to its own on-policy value,
    and a hotter one's is below it, as its truth is."""
    persons, flips = _fleet("home", 2, 6, 60)
    logs = _logs(*HRI, persons, flips, 2)
    near, hot, truth_near, truth_hot = [], [], [], []
    for i, (log, person, u) in enumerate(zip(logs, persons, flips, strict=True)):
        taught = make_learner("hri", {"tau": 0.005}, MISSION)
        values = replay_values(log, taught, person, u, _rng(2, 8, i))
        assert values.shape == (60,)
        replayed = make_learner("hri", {"tau": 0.005}, MISSION)
        replay(log, replayed, _rng(2, 6, i))
        assert taught.version == replayed.version == len(log.decisions)
        for name in ("ns", "rs", "visits", "last"):
            assert np.array_equal(getattr(taught, name), getattr(replayed, name)), name
        near.append(values.mean())
        hot.append(
            replay_values(
                log, make_learner("hri", {"tau": 0.5}, MISSION), person, u, _rng(2, 9, i)
            ).mean()
        )
        truth_near.append(
            run_learner(make_learner("hri", {"tau": 0.005}, MISSION), person, u, _rng(2, 7, i))
        )
        truth_hot.append(
            run_learner(make_learner("hri", {"tau": 0.5}, MISSION), person, u, _rng(2, 10, i))
        )
    assert abs(np.mean(near) - np.mean(truth_near)) < 0.5  # 0.3 apart, at most, in trials
    assert np.mean(hot) < np.mean(near)
    assert np.mean(truth_hot) < np.mean(truth_near)


def test_a_candidate_that_learned_already_is_replayed_on_its_own() -> None:
    """Two HRI candidates that differ only in their temperature, one of them taught a first
    log already: ``replay_all`` does not answer for it through the fresh one's tables, so each
    answers what its own replay answers."""
    persons, flips = _fleet("home", 4, 2, 40)
    first, second = _logs(*HRI, persons, flips, 4)
    taught = make_learner("hri", {"tau": 0.1}, MISSION)
    replay(first, taught, _rng(4, 0))
    again = make_learner("hri", {"tau": 0.1}, MISSION)
    replay(first, again, _rng(4, 0))
    alone = [
        replay(second, make_learner("hri", {"tau": 0.005}, MISSION), _rng(4, 1)),
        replay(second, again, _rng(4, 2)),
    ]
    together = replay_all(
        second, [make_learner("hri", {"tau": 0.005}, MISSION), taught], [_rng(4, 1), _rng(4, 2)]
    )
    for one, other in zip(alone, together, strict=True):
        for name in ("target", "q_hat", "v_hat"):
            assert np.array_equal(getattr(one, name), getattr(other, name)), name
    assert taught.version == again.version
