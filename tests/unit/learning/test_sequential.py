"""Comparing a rollout's arms while it runs (app.learning.sequential), on simulated fleets.

A simulated fleet: ``N_PEOPLE`` people, each assigned to the candidate or the control arm with
chance 1/2 (as a hash would), over ``DAYS`` days, one look at the end of each day. People
differ: in how much they get out of an encounter (their mean reward per step), in how noisy
their rewards are, in how long their episodes are (one to eight steps) and in how often they
meet the robot (a log-normal number of episodes a day, median 3, from 0.5 to 15); three in ten
join late (between day 2 and day 21). An episode's return is the sum of its steps' rewards, each
in [-1, 1]. The candidate's returns are shifted by ``effect`` per encounter (0 in the A/A
fleets).

The A/A false verdict rate (a fleet counts once if *any* of its 30 looks says "better" or
"worse") is printed by ``test_aa_false_verdicts_at_30_looks`` (and recorded as its
``aa_false_verdict_rate`` property); the naive intervals' by
``test_naive_daily_intervals_give_more_false_verdicts``, the guard's power by
``test_the_guard_rolls_back_a_worse_candidate``, and the A/A with the learning core's simulated
people under one learner by ``test_aa_with_simulated_people_under_a_learner``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from statistics import NormalDist
from typing import Any

import numpy as np
import pytest

from app.learning.offpolicy import _t_quantile
from app.learning.sequential import (
    CANDIDATE,
    CONTROL,
    DEFAULT_ALPHA,
    DEFAULT_INTENDED_PEOPLE,
    MIN_EPISODES,
    MIN_PEOPLE,
    Comparison,
    compare,
    guard,
    mixture_radius,
    rho_for,
    student_radius,
)
from app.learning.types import FloatArray, IntArray

BoolArray = np.ndarray[tuple[int], np.dtype[np.bool_]]
StrArray = np.ndarray[tuple[int], np.dtype[np.str_]]

DAYS = 30  # one look a day
N_PEOPLE = 40
AA_FLEETS = 400
HEAVY_FLEETS = 200
POWER_FLEETS = 200
LEARNER_FLEETS = 200
LATE_SHARE = 0.3  # people who join after the first day
MAX_LENGTH = 8  # steps per episode
Z95 = NormalDist().inv_cdf(0.975)


@dataclass(frozen=True)
class Spread:
    """How much the people of a simulated fleet differ: the standard deviation of their mean
    reward per step (around 0.1), and of the logarithm of their number of episodes a day."""

    step_mean: float = 0.08
    log_rate: float = 0.6


DIFFER = Spread()
# Frequent users carry more of the episodes, and the people's means differ more.
HEAVY = Spread(step_mean=0.12, log_rate=0.8)


@dataclass(frozen=True)
class Fleet:
    """One simulated rollout's closed episodes, in no particular order."""

    person: IntArray
    candidate: BoolArray  # the episode's person is in the candidate arm
    day: IntArray  # the day the episode closed, 0 .. DAYS - 1
    returns: FloatArray
    arms: StrArray

    def upto(self, day: int) -> Comparison:
        """The look at the end of ``day``."""
        seen = self.day <= day
        return compare(self.person[seen], self.arms[seen], self.returns[seen])


def fleet_of(person: IntArray, candidate: BoolArray, day: IntArray, returns: FloatArray) -> Fleet:
    arms = np.where(candidate, CANDIDATE, CONTROL)
    return Fleet(person.astype(np.int64), candidate, day.astype(np.int64), returns, arms)


def simulate(
    rng: np.random.Generator,
    *,
    effect: float = 0.0,
    spread: Spread = DIFFER,
    n_people: int = N_PEOPLE,
) -> Fleet:
    """A fleet of people who differ (see the module's docstring); the candidate's returns are
    ``effect`` per encounter apart from the control's."""
    step_mean = rng.normal(0.1, spread.step_mean, n_people)
    noise = rng.uniform(0.2, 0.9, n_people)  # the spread of one step's reward
    mean_length = rng.uniform(1.5, 5.0, n_people)  # the person's typical episode length
    rate = np.exp(rng.normal(math.log(3.0), spread.log_rate, n_people)).clip(0.5, 15.0)
    join = np.where(rng.random(n_people) < LATE_SHARE, rng.integers(1, 21, n_people), 0)
    in_candidate = rng.random(n_people) < 0.5
    days = np.arange(DAYS)
    counts = rng.poisson(rate[:, None] * (days[None, :] >= join[:, None]))  # (person, day)
    person = np.repeat(np.arange(n_people), counts.sum(axis=1))
    day = np.concatenate([np.repeat(days, row) for row in counts])
    p_longer = (mean_length[person] - 1.0) / (MAX_LENGTH - 1)
    length = 1 + rng.binomial(MAX_LENGTH - 1, p_longer)
    owner = np.repeat(person, length)
    rewards = np.clip(step_mean[owner] + noise[owner] * rng.standard_normal(owner.size), -1, 1)
    starts = np.concatenate(([0], np.cumsum(length)[:-1]))
    candidate = in_candidate[person]
    returns = np.add.reduceat(rewards, starts) + effect * candidate
    return fleet_of(person, candidate, day, returns)


def naive_verdict(fleet: Fleet, day: int) -> int:
    """A fixed-sample 95 % Welch t-interval on the episodes up to ``day``, as if they were
    independent: +1 better, -1 worse, 0 neither."""
    seen = fleet.day <= day
    a = fleet.returns[seen & fleet.candidate]
    b = fleet.returns[seen & ~fleet.candidate]
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    half = _t_quantile(0.975, max(1, int(df))) * math.sqrt(va + vb)
    difference = a.mean() - b.mean()
    return int(difference - half > 0) - int(difference + half < 0)


CODES = {"better": 1, "worse": -1, "no difference yet": 0}


@dataclass(frozen=True)
class Looks:
    """Verdicts of many fleets at each of their looks, (fleet, look): +1 better, -1 worse, 0
    neither (or not enough evidence)."""

    method: IntArray
    clustered_fixed: IntArray  # the per-person standard error, 1.96 of them: not time-uniform
    naive: IntArray  # episodes as if independent, fixed-sample t: neither
    guard_day: IntArray  # (fleet,) the first look at which the guard fires, DAYS if never
    enough_day: IntArray  # (fleet,) the first look with enough evidence


def run_looks(fleets: list[Fleet], *, naive: bool) -> Looks:
    n = len(fleets)
    method = np.zeros((n, DAYS), dtype=np.int64)
    clustered = np.zeros_like(method)
    naive_codes = np.zeros_like(method)
    guard_day = np.full(n, DAYS, dtype=np.int64)
    enough_day = np.full(n, DAYS, dtype=np.int64)
    for f, fleet in enumerate(fleets):
        for day in range(DAYS):
            look = fleet.upto(day)
            if not look.enough:
                continue
            enough_day[f] = min(enough_day[f], day)
            method[f, day] = CODES[look.verdict]
            if guard(look) and guard_day[f] == DAYS:
                guard_day[f] = day
            if naive:
                assert look.difference is not None
                assert look.std_error is not None
                half = Z95 * look.std_error
                clustered[f, day] = int(look.difference - half > 0) - int(
                    look.difference + half < 0
                )
                naive_codes[f, day] = naive_verdict(fleet, day)
    return Looks(method, clustered, naive_codes, guard_day, enough_day)


@cache
def aa_looks() -> Looks:
    fleets = [simulate(np.random.default_rng([2024, f])) for f in range(AA_FLEETS)]
    return run_looks(fleets, naive=True)


@cache
def power_looks(effect: float) -> Looks:
    fleets = [simulate(np.random.default_rng([7, f]), effect=effect) for f in range(POWER_FLEETS)]
    return run_looks(fleets, naive=False)


def ever(codes: IntArray) -> float:
    """The share of fleets with a "better" or "worse" verdict at any look."""
    return float(np.mean(np.any(codes != 0, axis=1)))


def show(capsys: pytest.CaptureFixture[str], line: str) -> None:
    """Print past pytest's capture: the suite's output shows the figure."""
    with capsys.disabled():
        print(f"\n[sequential] {line}")


# ---------------------------------------------------------------------------------------------
# The simulated fleets are what the docstring says


def test_the_simulated_people_differ_and_cluster() -> None:
    fleet = simulate(np.random.default_rng(1))
    people, counts = np.unique(fleet.person, return_counts=True)
    assert people.size >= 35
    assert counts.max() > 5 * counts.min()  # unequal episode rates
    first_day = np.array([fleet.day[fleet.person == p].min() for p in people])
    assert np.sum(first_day > 1) >= 5  # some join late
    assert np.all(np.abs(fleet.returns) <= MAX_LENGTH)
    # The people differ: their mean returns spread far more than their episodes' noise would
    # make them (the intraclass correlation is well above 0; with 100 episodes a person, an
    # intraclass correlation of 0.05 makes 2,000 episodes worth about 330 independent ones).
    means = np.array([fleet.returns[fleet.person == p].mean() for p in people])
    within = np.mean([fleet.returns[fleet.person == p].var(ddof=1) for p in people])
    between = means.var(ddof=1) - np.mean(within / counts)
    assert between / (between + within) > 0.05


# ---------------------------------------------------------------------------------------------
# Properties of one look


def test_a_hand_computed_look() -> None:
    # Candidate: person 1 (returns 1, 2), 2 (3), 3 (0, 0, 3); control: 4 (1), 5 (0, 2), 6 (1).
    people = [1, 1, 2, 3, 3, 3, 4, 5, 5, 6]
    arms = [CANDIDATE] * 6 + [CONTROL] * 4
    returns = [1.0, 2.0, 3.0, 0.0, 0.0, 3.0, 1.0, 0.0, 2.0, 1.0]
    look = compare(people, arms, returns, min_people=3, min_episodes=4)
    assert look.candidate.mean == pytest.approx(9 / 6)
    assert look.control.mean == pytest.approx(1.0)
    assert look.difference == pytest.approx(0.5)
    # Residuals S_i - mean * m_i: candidate (0, 1.5, -1.5), control (0, 0, 0).
    v_candidate = 3 / 2 * (0 + 1.5**2 + 1.5**2) / 6**2
    assert look.candidate.std_error == pytest.approx(math.sqrt(v_candidate))
    assert look.control.std_error == pytest.approx(0.0)
    assert look.std_error == pytest.approx(math.sqrt(v_candidate))
    # Effective people: 6^2 / (2^2 + 1 + 3^2) and 4^2 / (1 + 2^2 + 1).
    assert look.candidate.effective_people == pytest.approx(36 / 14)
    assert look.control.effective_people == pytest.approx(16 / 6)
    # The control's variance is 0: the degrees of freedom are the candidate's, 36/14 - 1.
    assert look.df == pytest.approx(36 / 14 - 1)
    rho = rho_for(DEFAULT_INTENDED_PEOPLE)
    x = 6 * rho**2
    c = math.sqrt((1 + 1 / x) * (math.log(1 + x) + 2 * math.log(1 / DEFAULT_ALPHA)))
    assert look.mixture == pytest.approx(c)
    # 1 degree of freedom (rounded down): Cauchy's quantile, tan(pi (q - 1/2)).
    q = 1 - NormalDist().cdf(-c)
    assert look.radius is not None
    assert look.std_error is not None
    assert look.radius == pytest.approx(math.tan(math.pi * (q - 0.5)), rel=1e-9)
    assert look.low == pytest.approx(0.5 - look.radius * math.sqrt(v_candidate))
    assert look.high == pytest.approx(0.5 + look.radius * math.sqrt(v_candidate))
    assert look.n_people == 6
    assert look.enough
    assert look.reason == ""
    # The paper's form of the normal half-width: sigma sqrt(2 (t rho^2 + 1) / (t^2 rho^2)
    # ln(sqrt(t rho^2 + 1) / alpha)), sigma^2 = t V.
    sigma = math.sqrt(6 * v_candidate)
    half = sigma * math.sqrt(2 * (x + 1) / (36 * rho**2) * math.log(math.sqrt(x + 1) / 0.05))
    assert c * look.std_error == pytest.approx(half)


def test_the_boundary_and_students_correction() -> None:
    best = mixture_radius(DEFAULT_INTENDED_PEOPLE, rho_for(DEFAULT_INTENDED_PEOPLE))
    assert best == pytest.approx(3.035, abs=1e-3)
    # rho_for makes the interval narrowest at the intended number of people.
    for rho in (0.1, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0, 2.0):
        assert mixture_radius(DEFAULT_INTENDED_PEOPLE, rho) >= best - 1e-12
    # Wider for more looks' worth of people, never narrower than a fixed-sample interval.
    assert mixture_radius(1000, rho_for(40)) > mixture_radius(100, rho_for(40)) > best > 1.5 * Z95
    # Student's t at the same level: wider with few degrees of freedom, the normal's with many.
    radii = [student_radius(best, df) for df in (1, 2, 5, 10, 38, 100, 1000)]
    assert all(a > b for a, b in zip(radii, radii[1:], strict=False))
    assert student_radius(best, math.inf) == best
    assert student_radius(best, 1e6) == pytest.approx(best, abs=1e-4)
    assert student_radius(best, 38) == pytest.approx(3.25, abs=0.01)
    assert student_radius(best, 2.9) == student_radius(best, 2)  # rounded down


def test_the_interval_holds_the_difference_and_narrows_with_data() -> None:
    widths = []
    for seed in range(10):
        fleet = simulate(np.random.default_rng([3, seed]))
        early, late = fleet.upto(4), fleet.upto(DAYS - 1)
        for look in (early, late):
            assert look.enough
            assert look.low is not None
            assert look.high is not None
            assert look.difference is not None
            assert look.low < look.difference < look.high
            assert look.interval == (look.low, look.high)
            assert look.radius is not None
            assert look.mixture is not None
            assert look.radius >= look.mixture
        assert early.high is not None
        assert early.low is not None
        assert late.high is not None
        assert late.low is not None
        widths.append((early.high - early.low, late.high - late.low))
    early_widths, late_widths = np.array(widths).T
    assert np.all(late_widths < early_widths)
    assert np.median(late_widths / early_widths) < 0.85
    # Most of the width is the spread between people: four times the people, half the width.
    many = [
        simulate(np.random.default_rng([3, seed]), n_people=4 * N_PEOPLE).upto(DAYS - 1)
        for seed in range(10)
    ]
    many_widths = np.array([look.high - look.low for look in many if look.high and look.low])
    assert many_widths.size == 10
    assert np.median(many_widths) < 0.6 * np.median(late_widths)


def test_clear_differences_get_the_right_verdict() -> None:
    for seed in range(5):
        better = simulate(np.random.default_rng([4, seed]), effect=2.0).upto(DAYS - 1)
        worse = simulate(np.random.default_rng([4, seed]), effect=-2.0).upto(DAYS - 1)
        assert better.verdict == "better"
        assert not guard(better)
        assert worse.verdict == "worse"
        assert guard(worse)
        assert better.low is not None
        assert better.low > 0
        assert worse.high is not None
        assert worse.high < 0
        assert better.difference == pytest.approx(2.0, abs=0.6)
        assert worse.difference == pytest.approx(-2.0, abs=0.6)


def test_the_guard_with_a_margin() -> None:
    people = np.repeat(np.arange(20), 5)
    arms = np.where(people < 10, CANDIDATE, CONTROL)
    rng = np.random.default_rng(6)
    returns = rng.normal(0.0, 0.3, people.size) - 1.0 * (people < 10)
    look = compare(people, arms, returns)
    assert look.verdict == "worse"
    assert look.high is not None
    assert -1.0 < look.high < -0.3
    assert guard(look)
    assert guard(look, margin=0.2)
    assert not guard(look, margin=1.5)
    with pytest.raises(ValueError, match="margin"):
        guard(look, margin=-0.1)


def test_few_people_is_not_enough_evidence() -> None:
    people = np.repeat(np.arange(9), 10)
    arms = np.where(people < 4, CANDIDATE, CONTROL)  # 4 candidate people, 5 control
    returns = np.where(people < 4, -5.0, 5.0) + 0.01 * people
    look = compare(people, arms, returns)
    assert not look.enough
    assert look.reason == "not enough evidence: 4 people in the candidate arm (5 needed)"
    assert look.verdict == "no difference yet"
    assert look.interval is None
    assert look.low is None
    assert look.high is None
    assert look.difference == pytest.approx(-10.0, abs=0.2)  # the means are still shown
    assert look.candidate.n_people == 4
    assert look.control.n_people == 5
    assert look.candidate.n_episodes == 40
    assert look.control.n_episodes == 50
    assert not guard(look)
    assert MIN_PEOPLE == 5


def test_few_episodes_is_not_enough_evidence() -> None:
    people = np.concatenate([np.arange(6), np.repeat(np.arange(6, 12), 4)])
    arms = np.where(people < 6, CANDIDATE, CONTROL)
    look = compare(people, arms, np.zeros(people.size))
    assert look.reason == (
        f"not enough evidence: 6 episodes in the candidate arm ({MIN_EPISODES} needed)"
    )
    assert not look.enough
    assert not guard(look)


def test_one_arm_empty() -> None:
    look = compare([1, 2, 3], [CONTROL] * 3, [0.0, 1.0, 2.0])
    assert look.candidate.n_people == 0
    assert look.candidate.mean is None
    assert look.difference is None
    assert not look.enough
    assert "0 people in the candidate arm" in look.reason
    nothing = compare([], [], [])
    assert not nothing.enough
    assert nothing.difference is None


def test_identical_returns_give_a_point() -> None:
    people = np.repeat(np.arange(10), 5)
    look = compare(people, np.where(people < 5, CANDIDATE, CONTROL), np.ones(people.size))
    assert look.enough
    assert look.std_error == 0.0
    assert look.df == math.inf
    assert look.interval == (0.0, 0.0)
    assert look.verdict == "no difference yet"
    assert json.loads(json.dumps(look.to_dict()))["df"] is None


def test_order_and_labels_do_not_matter() -> None:
    fleet = simulate(np.random.default_rng(8))
    look = fleet.upto(DAYS - 1)
    order = np.random.default_rng(9).permutation(fleet.person.size)
    names = np.array([f"person-{p:03d}" for p in fleet.person])
    again = compare(names[order], fleet.arms[order], fleet.returns[order])
    assert again.difference == pytest.approx(look.difference)
    assert again.low == pytest.approx(look.low)
    assert again.high == pytest.approx(look.high)
    assert again.verdict == look.verdict


def test_to_dict_is_plain_json() -> None:
    look = simulate(np.random.default_rng(10)).upto(DAYS - 1)
    doc = json.loads(json.dumps(look.to_dict()))
    assert doc["verdict"] == look.verdict
    assert doc["candidate"]["n_people"] + doc["control"]["n_people"] == doc["n_people"]
    assert doc["alpha"] == DEFAULT_ALPHA
    assert doc["low"] == look.low
    assert doc["df"] == look.df


@pytest.mark.parametrize(
    ("people", "arms", "returns", "message"),
    [
        ([1, 1], [CANDIDATE, CONTROL], [0.0, 0.0], "person 1 has episodes in both arms"),
        ([1, 2], [CANDIDATE, "canary"], [0.0, 0.0], "arms must be"),
        ([1, 2], [CANDIDATE, CONTROL], [0.0], "one entry per episode"),
        ([1, 2], [CANDIDATE, CONTROL], [0.0, math.nan], "finite"),
        ([[1, 2]], [[CANDIDATE, CONTROL]], [[0.0, 0.0]], "one-dimensional"),
    ],
)
def test_bad_episodes_are_refused(
    people: list[Any], arms: list[Any], returns: list[Any], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        compare(people, arms, returns)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"alpha": 0.0}, "alpha"),
        ({"alpha": 1.5}, "alpha"),
        ({"rho": 0.0}, "rho"),
        ({"rho": math.inf}, "rho"),
        ({"min_people": -1}, "min_people"),
        ({"min_episodes": 2.5}, "min_episodes"),
    ],
)
def test_bad_options_are_refused(options: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        compare([1, 2], [CANDIDATE, CONTROL], [0.0, 1.0], **options)  # type: ignore[arg-type]


def test_bad_boundary_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="people"):
        rho_for(0)
    with pytest.raises(ValueError, match="t must be"):
        mixture_radius(0, 0.4)
    with pytest.raises(ValueError, match="rho"):
        mixture_radius(10, -0.4)
    with pytest.raises(ValueError, match="df"):
        student_radius(3.0, 0)
    with pytest.raises(ValueError, match="df"):
        student_radius(3.0, math.nan)


# ---------------------------------------------------------------------------------------------
# Looking every day: the A/A simulation, and the power of the guard


def test_aa_false_verdicts_at_30_looks(
    capsys: pytest.CaptureFixture[str], record_property: Callable[[str, object], None]
) -> None:
    looks = aa_looks()
    rate = ever(looks.method)
    heavy = run_looks(
        [simulate(np.random.default_rng([99, f]), spread=HEAVY) for f in range(HEAVY_FLEETS)],
        naive=False,
    )
    heavy_rate = ever(heavy.method)
    record_property("aa_false_verdict_rate", rate)
    record_property("aa_false_verdict_rate_heavy_users", heavy_rate)
    show(
        capsys,
        f"A/A, {AA_FLEETS} fleets of {N_PEOPLE} people, {DAYS} daily looks: "
        f"{rate:.1%} of fleets read 'better' or 'worse' at some look (confidence sequence, "
        f"alpha {DEFAULT_ALPHA}; the guard fired in {np.mean(looks.guard_day < DAYS):.1%}); "
        f"with frequent users carrying more of the episodes ({HEAVY_FLEETS} fleets): "
        f"{heavy_rate:.1%}",
    )
    assert rate <= 0.05
    assert heavy_rate <= 0.05
    # The looks were there to be read: every fleet had enough evidence within its first week.
    assert np.all(looks.enough_day < 7)
    assert np.all(heavy.enough_day < 7)


def test_naive_daily_intervals_give_more_false_verdicts(
    capsys: pytest.CaptureFixture[str], record_property: Callable[[str, object], None]
) -> None:
    looks = aa_looks()
    method, naive, clustered = ever(looks.method), ever(looks.naive), ever(looks.clustered_fixed)
    naive_last = float(np.mean(looks.naive[:, -1] != 0))
    clustered_last = float(np.mean(looks.clustered_fixed[:, -1] != 0))
    record_property("aa_naive_false_verdict_rate", naive)
    record_property("aa_clustered_fixed_false_verdict_rate", clustered)
    show(
        capsys,
        f"A/A, the same fleets: a fixed-sample 95 % t-interval on the episodes at each look: "
        f"{naive:.1%} (at the last look alone {naive_last:.1%}); with the per-person standard "
        f"error, 1.96 of them, at each look: {clustered:.1%} (last look alone "
        f"{clustered_last:.1%}); the confidence sequence: {method:.1%}",
    )
    assert naive > 0.5 > 0.05 >= method
    assert naive > clustered > method
    assert clustered > 2 * clustered_last  # looking daily multiplies the false alarms


def test_the_guard_rolls_back_a_worse_candidate(
    capsys: pytest.CaptureFixture[str], record_property: Callable[[str, object], None]
) -> None:
    half, one = power_looks(-0.5), power_looks(-1.0)
    fired_half = float(np.mean(half.guard_day < DAYS))
    fired_one = float(np.mean(one.guard_day < DAYS))
    record_property("guard_rolled_back_at_minus_0.5", fired_half)
    record_property("guard_rolled_back_at_minus_1", fired_one)
    show(
        capsys,
        f"candidate worse by 0.5 per encounter, {POWER_FLEETS} fleets of {N_PEOPLE} people: "
        f"the guard rolled back {fired_half:.1%} within {DAYS} looks (median look "
        f"{np.median(half.guard_day) + 1:.0f}); worse by 1.0: {fired_one:.1%} (median look "
        f"{np.median(one.guard_day) + 1:.0f})",
    )
    assert fired_half >= 0.8
    # Never "better" for a worse candidate.
    assert not np.any(half.method == 1)
    assert not np.any(one.method == 1)
    # A larger difference is caught sooner.
    assert fired_one >= fired_half
    assert np.median(one.guard_day) < np.median(half.guard_day)
    assert np.mean(one.guard_day) < np.mean(half.guard_day)


# ---------------------------------------------------------------------------------------------
# The A/A with the learning core's simulated people, one learner in both arms

LEARNER = "dts-routine"  # the service's default learner
POOL_FAMILIES = ("individual", "home", "noisy", "refusing")
POOL_PER_FAMILY = 15
POOL_EVENTS = 160


@cache
def learner_rewards() -> list[FloatArray]:
    """Each pooled person's reward per episode, in order, under one fresh ``LEARNER``: people of
    four robustness families (docs/method.md §12), the learner learning them as it goes."""
    from app.learning.learners import make_learner
    from app.learning.mission import office_mission
    from app.learning.population import FAMILIES, people, run_learner

    mission = office_mission()
    rewards = []
    for k, name in enumerate(POOL_FAMILIES):
        persons, flips = people(FAMILIES[name], mission, 11, POOL_PER_FAMILY, POOL_EVENTS)
        for i, (person, uniforms) in enumerate(zip(persons, flips, strict=True)):
            learner = make_learner(LEARNER, {}, mission)
            rng = np.random.default_rng([11, k, i])
            rewards.append(run_learner(learner, person, uniforms, rng))
    return rewards


def learner_fleet(rng: np.random.Generator, pool: list[FloatArray]) -> Fleet:
    """40 of the pooled people, each in an arm with chance 1/2, joining on day 0 or (three in
    ten) on a day from 1 to 20, each with their own number of episodes (30 to 160, their
    first ones, spread at random over their days)."""
    chosen = rng.choice(len(pool), size=N_PEOPLE, replace=False)
    in_candidate = rng.random(N_PEOPLE) < 0.5
    join = np.where(rng.random(N_PEOPLE) < LATE_SHARE, rng.integers(1, 21, N_PEOPLE), 0)
    counts = rng.integers(30, POOL_EVENTS + 1, N_PEOPLE)
    person = np.repeat(np.arange(N_PEOPLE), counts)
    day = np.concatenate(
        [np.sort(rng.integers(j, DAYS, n)) for j, n in zip(join, counts, strict=True)]
    )
    returns = np.concatenate([pool[p][:n] for p, n in zip(chosen, counts, strict=True)])
    return fleet_of(person, in_candidate[person], day, returns)


def test_aa_with_simulated_people_under_a_learner(
    capsys: pytest.CaptureFixture[str], record_property: Callable[[str, object], None]
) -> None:
    pool = learner_rewards()
    assert len(pool) == len(POOL_FAMILIES) * POOL_PER_FAMILY
    # The people differ under the learner, and it learns them: later episodes earn more.
    means = np.array([r.mean() for r in pool])
    assert means.std() > 0.2
    assert np.mean([r[-40:].mean() - r[:20].mean() for r in pool]) > 0
    fleets = [learner_fleet(np.random.default_rng([12, f]), pool) for f in range(LEARNER_FLEETS)]
    looks = run_looks(fleets, naive=False)
    rate = ever(looks.method)
    record_property("aa_false_verdict_rate_learner", rate)
    show(
        capsys,
        f"A/A with the learning core's simulated people ({len(pool)} of 4 families, "
        f"{LEARNER} in both arms), {LEARNER_FLEETS} fleets of {N_PEOPLE}, {DAYS} daily looks: "
        f"{rate:.1%} of fleets read 'better' or 'worse' at some look",
    )
    assert rate <= 0.05
