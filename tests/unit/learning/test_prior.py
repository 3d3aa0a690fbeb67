"""A fleet's prior for newcomers (``app.learning.prior``, docs/method.md §16): what it takes from
the contributors (per pair rates, each contributor once, only pairs with enough contributors, at
a bounded weight), that it is an ordinary learner, and that it helps a newcomer of a home whose
residents share routines (a seeded ordering, not numbers)."""

from __future__ import annotations

import zlib
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.learning import Mission, Observation, learner_from_state, load_mission, make_learner
from app.learning import office_mission as _office
from app.learning.learners import QLearner
from app.learning.learners.base import TabularLearner
from app.learning.population import FAMILIES, people, run_learner
from app.learning.prior import (
    DEFAULT_STRENGTH,
    MIN_SUPPORT,
    PRIOR_TABLES,
    population_prior,
)

ROOT = Path(__file__).resolve().parents[3]
ALGORITHMS = tuple(PRIOR_TABLES)
COUNTING = tuple(a for a in ALGORITHMS if PRIOR_TABLES[a].counts is not None)


@cache
def office() -> Mission:
    return _office()


def rng(*words: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(list(words)))


@cache
def served(
    algorithm: str, seed: int = 0, n: int = 5, n_events: int = 60
) -> tuple[TabularLearner[Any], ...]:
    """``n`` residents of one home (family ``home``), each served by a fresh learner."""
    family = FAMILIES["home"]
    persons, flips = people(family, office(), seed, n, n_events)
    out = []
    for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
        learner = make_learner(algorithm, None, office())
        run_learner(learner, person, u, rng(seed, i, zlib.crc32(algorithm.encode())))
        out.append(learner)
    return tuple(out)


def tables(learner: TabularLearner[Any]) -> dict[str, np.ndarray]:
    """Every table a prior may fill, by name."""
    spec = PRIOR_TABLES[learner.algorithm]
    names = [spec.counts, spec.sums, *spec.derived, *spec.values, *spec.pooled]
    return {n: np.array(getattr(learner, n)) for n in names if n is not None}


def pair_weight(learner: TabularLearner[Any]) -> np.ndarray:
    """(C, P): the pseudo-samples the prior puts on each pair (its counts over the other axes)."""
    counts = np.asarray(getattr(learner, PRIOR_TABLES[learner.algorithm].counts or ""))
    weight: np.ndarray = counts.reshape(*counts.shape[:2], -1).sum(axis=-1)
    return weight


def assert_fresh(learner: TabularLearner[Any]) -> None:
    fresh = make_learner(learner.algorithm, None, learner.mission)
    for name, table in tables(learner).items():
        np.testing.assert_array_equal(table, getattr(fresh, name), err_msg=name)


class TestSupport:
    @pytest.mark.parametrize("algorithm", ALGORITHMS)
    def test_fewer_contributors_than_min_support_give_a_fresh_learner(self, algorithm: str) -> None:
        few = served(algorithm)[: MIN_SUPPORT - 1]
        prior = population_prior(algorithm, None, office(), few)
        assert_fresh(prior)
        assert prior.to_state() == make_learner(algorithm, None, office()).to_state()

    @pytest.mark.parametrize("algorithm", COUNTING)
    def test_a_pair_known_to_too_few_contributors_stays_fresh(self, algorithm: str) -> None:
        spec = PRIOR_TABLES[algorithm]
        assert spec.counts is not None
        contributors = [make_learner(algorithm, None, office()) for _ in range(5)]
        c, a = 3, office_pair(contributors[0])
        column = first_column(contributors[0], a)
        rare, common = (c, a), (c + 1, a)
        for i, learner in enumerate(contributors):
            counts = getattr(learner, spec.counts)
            if i < MIN_SUPPORT - 1:  # one contributor short of the support
                counts[rare][..., column] += 2.0
            counts[common][..., column] += 1.0 + i
        prior = population_prior(algorithm, None, office(), contributors)
        weight = pair_weight(prior)
        assert weight[rare] == 0.0
        assert weight[common] == pytest.approx(DEFAULT_STRENGTH)
        assert np.count_nonzero(weight) == 1  # nothing anywhere else

    def test_q_values_of_a_pair_visited_by_too_few_contributors_stay_initial(self) -> None:
        contributors = [QLearner(office()) for _ in range(5)]
        initial = np.array(contributors[0].q)
        for i, learner in enumerate(contributors):
            if i < MIN_SUPPORT - 1:
                learner.visits[2, 1] = 3
                learner.q[2, 1] = 5.0
            learner.visits[4, 1] = 1
            learner.q[4, 1] = float(i)
        prior = population_prior("qlearning", None, office(), contributors)
        assert isinstance(prior, QLearner)
        q = prior.q
        assert q[2, 1] == initial[2, 1]
        assert q[4, 1] == pytest.approx(np.mean(range(5)))
        assert prior.visits.sum() == 0  # no counts of episodes are taken

    def test_a_value_found_worse_than_a_fresh_start_stays_at_the_start(self) -> None:
        """Q-learning has no posterior: a pair the contributors found bad would never be tried
        again by a greedy newcomer, so the prior never starts a value below a fresh one."""
        contributors = [QLearner(office()) for _ in range(4)]
        initial = float(contributors[0].q[5, 1])
        for i, learner in enumerate(contributors):
            learner.visits[5, 1:3] = 2
            learner.q[5, 1] = initial - 3.0 - i  # refused by everyone
            learner.q[5, 2] = initial + 1.0 + i  # welcome
        prior = population_prior("qlearning", None, office(), contributors)
        assert isinstance(prior, QLearner)
        assert prior.q[5, 1] == initial
        assert prior.q[5, 2] == pytest.approx(initial + 2.5)


class TestWeights:
    @pytest.mark.parametrize("algorithm", COUNTING)
    def test_a_contributor_served_ten_times_as_much_weighs_the_same(self, algorithm: str) -> None:
        spec = PRIOR_TABLES[algorithm]
        contributors = served(algorithm)
        before = population_prior(algorithm, None, office(), contributors)
        heavy = learner_from_state(contributors[0].to_state(), office())
        for name in (spec.counts, spec.sums, *spec.derived, *spec.pooled):
            if name is not None:
                getattr(heavy, name)[...] *= 10.0  # the same rates, ten times the evidence
        after = population_prior(algorithm, None, office(), [heavy, *contributors[1:]])
        for name, table in tables(after).items():
            np.testing.assert_allclose(table, getattr(before, name), atol=1e-9, err_msg=name)

    @pytest.mark.parametrize("algorithm", COUNTING)
    @pytest.mark.parametrize("strength", [0.5, DEFAULT_STRENGTH, 25.0])
    def test_every_pair_weighs_at_most_strength(self, algorithm: str, strength: float) -> None:
        contributors = served(algorithm)
        prior = population_prior(algorithm, None, office(), contributors, strength=strength)
        weight = pair_weight(prior)
        assert weight.max() <= strength + 1e-9
        assert weight.max() == pytest.approx(strength)  # a pair every contributor knows
        for name in PRIOR_TABLES[algorithm].pooled:
            assert 0.0 < getattr(prior, name)[0] <= strength + 1e-9

    @pytest.mark.parametrize("algorithm", COUNTING)
    def test_the_weight_is_the_share_of_contributors_with_evidence(self, algorithm: str) -> None:
        contributors = served(algorithm)
        counts = PRIOR_TABLES[algorithm].counts or ""
        support = np.stack(
            [
                np.asarray(getattr(o, counts)).reshape(*pair_weight(o).shape, -1).sum(axis=-1) > 0
                for o in contributors
            ]
        ).sum(axis=0)
        expected = np.where(
            support >= MIN_SUPPORT, DEFAULT_STRENGTH * support / len(contributors), 0.0
        )
        if PRIOR_TABLES[algorithm].fresh_offers:  # the offers start fresh
            expected[:, list(contributors[0].space.root_actions)] = 0.0
        np.testing.assert_allclose(
            pair_weight(population_prior(algorithm, None, office(), contributors)),
            expected,
            atol=1e-9,
        )


class TestLearner:
    @pytest.mark.parametrize("algorithm", ALGORITHMS)
    def test_the_prior_round_trips_through_its_state(self, algorithm: str) -> None:
        prior = population_prior(algorithm, None, office(), served(algorithm))
        again = learner_from_state(prior.to_state(), office())
        assert again.algorithm == algorithm
        for name, table in tables(prior).items():
            np.testing.assert_array_equal(table, getattr(again, name), err_msg=name)
        for context in range(office().n_contexts):
            obs = Observation(context, prior.space.OBSERVE, 1)
            first = prior.select_action(obs, rng(context))
            second = again.select_action(obs, rng(context))
            assert (first.state, first.action) == (second.state, second.action)

    def test_a_contributor_of_another_algorithm_is_refused(self) -> None:
        with pytest.raises(ValueError, match="'hri'"):
            population_prior("dts", None, office(), [*served("dts")[:3], served("hri")[0]])

    def test_a_contributor_of_another_mission_is_refused(self) -> None:
        care_home = load_mission(ROOT / "docs/examples/care-home-mission.json")
        other = make_learner("dts", None, care_home)
        with pytest.raises(ValueError, match="another mission"):
            population_prior("dts", None, office(), [*served("dts")[:3], other])

    @pytest.mark.parametrize(
        ("strength", "min_support"), [(0.0, 3), (float("nan"), 3), (-1.0, 3), (4.0, 0)]
    )
    def test_bad_settings_are_refused(self, strength: float, min_support: int) -> None:
        with pytest.raises(ValueError, match="must be"):
            population_prior(
                "dts", None, office(), served("dts"), strength=strength, min_support=min_support
            )


class TestNewcomers:
    def test_a_home_newcomer_earns_more_from_the_prior_in_the_first_20_events(self) -> None:
        """Seeded ordering, over a few homes: DTS from the prior of five residents earns more
        in a newcomer's first 20 events than a fresh DTS on the same events and flips."""
        family = FAMILIES["home"]
        fresh_total = prior_total = 0.0
        for seed in range(3):
            persons, flips = people(family, office(), seed, 6, 100)
            contributors = []
            for i in range(1, 6):
                learner = make_learner("dts", None, office())
                run_learner(learner, persons[i], flips[i], rng(seed, i))
                contributors.append(learner)
            newcomer, u = persons[0], flips[0]
            fresh = run_learner(make_learner("dts", None, office()), newcomer, u, rng(seed, 0))
            prior = run_learner(
                population_prior("dts", None, office(), contributors), newcomer, u, rng(seed, 0)
            )
            fresh_total += float(fresh[:20].sum())
            prior_total += float(prior[:20].sum())
        assert prior_total > fresh_total


def office_pair(learner: TabularLearner[Any]) -> int:
    """A human-facing pair the prior carries: the offer at OBSERVE, or the question "which
    service?" for a learner whose offers start fresh."""
    if PRIOR_TABLES[learner.algorithm].fresh_offers:
        return int(learner.space.actions_of(learner.space.ENGAGED).start)
    return int(learner.space.INITIATE)


def first_column(learner: TabularLearner[Any], action: int) -> int:
    """A successor column the pair can reach."""
    return int(np.flatnonzero(learner.space.succ_mask[action])[0])
