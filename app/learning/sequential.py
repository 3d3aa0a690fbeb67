"""Comparing a rollout's arms while it runs: an interval for candidate - control that stays valid
however often it is looked at.

A fleet's operator tries a candidate learner as a canary: a share of the fleet's people, chosen
by a salted stable hash of who they are (the assignment stored), are served by the candidate,
the others by the current learner (the *control*). Each closed episode has a person, the
person's arm and a return (the sum of the episode's rewards; one episode is one encounter).
Staff read the comparison every day, and a guard rolls the candidate back on its own when it is
worse.

What is compared
----------------
Per arm, the mean return per encounter: the sum of the arm's returns over its number of
episodes (a person with more episodes counts more, as in ``app.learning.offpolicy``). The
quantity is the difference, candidate - control, of what the two arms would earn across the
population of people the fleet's are drawn from.

Why not a fixed-sample interval
-------------------------------
A 95 % interval computed once, at a sample size fixed in advance, misses the truth 5 % of the
time. Computed again every day and acted on the first day it excludes 0, it misses far more
often: each look is another chance for the noise to cross the line, and over 30 looks the
chances add up. Ignoring that one person's episodes resemble each other makes it worse again:
people differ, so a fleet's thousands of episodes are worth far fewer independent ones, and an
interval that counts episodes as independent is much too narrow. In this module's A/A
simulation (tests/unit/learning/test_sequential.py: two identical arms, 30 daily looks) a
fixed-sample 95 % t-interval on the episodes said "better" or "worse" at some look in 73 % of
the fleets, and a fixed-sample 95 % interval with the per-person standard error below (1.96 of
them) in 28 %.

The method
----------
An *asymptotic confidence sequence* (Waudby-Smith, Arbour, Sinha, Kennedy & Ramdas,
"Time-uniform central limit theory and asymptotic confidence sequences", Annals of Statistics,
2024; arXiv 2103.06476, 2021), in its Gaussian mixture form (Robbins' normal mixture boundary,
with the variance estimated): a sequence of intervals that hold the truth at *every* look at
once, with probability 1 - alpha, so that looking every day, or every hour, costs nothing more.
The unit is the person: people are independent of each other, a person's episodes are not. At a
look with t people (both arms; n_a in arm a), person i having m_i episodes whose returns sum to
S_i:

- each arm's mean is mu_a = sum S_i / sum m_i over its people (M_a = sum m_i);
- each arm's variance is the cluster-robust (per person) one of that ratio,
  V_a = n_a / (n_a - 1) * sum_i (S_i - mu_a m_i)^2 / M_a^2, which counts a person's episodes
  together whatever their correlation and number;
- the difference D = mu_c - mu_0 (candidate - control) has variance V = V_c + V_0. To first
  order D is the mean over the t people of one value per person (as in the paper's randomised
  experiments: a person's deviation from their arm's mean, over the arm's share of the people),
  whose variance is sigma^2 = t V;
- the paper's interval is D +/- sigma * sqrt(2 (t rho^2 + 1) / (t^2 rho^2) *
  ln(sqrt(t rho^2 + 1) / alpha)), that is D +/- c(t) sqrt(V) with
  c(t) = sqrt((1 + 1 / (t rho^2)) * (ln(1 + t rho^2) + 2 ln(1 / alpha)))
  (:func:`mixture_radius`).

``rho`` is the mixture's tuning parameter: it sets the number of people at which the interval
is narrowest, and the choice costs little elsewhere. :func:`rho_for` gives the paper's choice
for an intended number of people t*, rho^2 = (-2 ln alpha + ln(-2 ln alpha + 1)) / t*; the
default is for ``DEFAULT_INTENDED_PEOPLE`` (40) people and alpha = 0.05: rho = 0.445, and
c = 3.04 at 40 people (3.26 at 10, 3.08 at 100, 3.24 at 400), where a fixed-sample 95 %
interval uses 1.96. That factor is the price of looking whenever one likes.

Few people: Student's t (ours)
------------------------------
c(t) is a normal quantile: the normal's chance of lying beyond it is p(t) = 2 (1 - Phi(c(t))),
0.0024 at 40 people. The variance, though, is estimated from the people, and with few of them,
or when a few frequent users carry most of the episodes, the standardised difference has heavier
tails than the normal's. Measured on the A/A simulation: a single fixed 95 % look at the end,
with the per-person standard error, said "better" or "worse" in 6-9 % of fleets instead of 5 %;
the 30 looks with plain c(t), in 3-5 % (at the bound). So the interval uses Student's t
quantile at the same p(t), D +/- t_df(1 - p(t) / 2) sqrt(V): the chance of crossing at each look
is then what the boundary allows, if the standardised difference is t-distributed. The degrees
of freedom are Welch and Satterthwaite's, df = V^2 / (V_c^2 / f_c + V_0^2 / f_0), from each arm's
*effective number of people* minus one, f_a = (sum m_i)^2 / sum m_i^2 - 1 (Kish's: a person with
ten times the episodes counts ten times in the mean, so the mean rests on fewer people than it
has; with equal numbers of episodes it is n_a - 1), rounded down. As people accrue, df grows and
t_df -> the normal: the interval becomes the paper's, and keeps its asymptotic guarantee. With
20 people of equal activity per arm the factor is 3.25 instead of 3.04; with 5 per arm, 4.97
instead of 3.26.

The error bound
---------------
With ``alpha`` = 0.05 (the default), the probability that the interval misses the true
difference at *any* look, however many, is at most 5 % asymptotically (as the number of people
grows): lim_{m -> oo} P(there is a look with t >= m people whose interval misses) <= alpha. In
particular, when the two arms are the same, the probability of *ever* reading "better" or
"worse" is at most 5 %. The bound is two-sided: alpha covers both directions together.

Its assumptions:

- people are independent of each other, and drawn from one population whatever their arm:
  the arms are assigned by a stable hash of the person (not by anything about them), and a
  person stays in one arm (``compare`` refuses a person found in both);
- asymptotic: the normal approximation (with Student's correction) must be good for the people
  seen, which is why no verdict is given under ``MIN_PEOPLE`` (5) people or ``MIN_EPISODES``
  (20) episodes in either arm;
- the paper's setting is a stream of independent people; here a person's episodes also keep
  arriving between looks, and a person who uses the robot more weighs more. Those departures
  are not covered by the theorem; the A/A simulation (people who differ in what they earn, how
  noisy and how long their episodes are, how often they meet the robot and when they join; 30
  looks) is the check that they do not break the bound. It said "better" or "worse" at some
  look in 1.5 % of 400 fleets (1.3-2.8 % with other seeds), 0.5 % when frequent users carry
  more of the episodes, and 2.5 % with the learning core's simulated people under one learner
  in both arms (``dts-routine``; 2.5-3.5 % with other seeds). The tests print the figures.

The verdict and the guard
-------------------------
``better`` when the interval lies above 0, ``worse`` when below, else ``no difference yet``
(also whenever there is not enough evidence). The guard (:func:`guard`) is the automatic
rollback's condition: the candidate is worse with the method's confidence, the interval's high
end below 0 (or below ``-margin`` when a practical margin is given: worse by more than the
margin per encounter). Because the interval is valid at every look, a guard checked every day
rolls back an equal candidate in at most alpha of rollouts (asymptotically), and a worse one as
soon as the evidence allows. In the simulated fleets of 40 people (returns averaging about 0.3
per encounter, with a spread of 1.0), a candidate worse by 0.5 per encounter was rolled back
within 30 daily looks in 89.5 % of 200 fleets (half of them by the fourth look); one worse by
1.0, in all of them, mostly at the first look with enough evidence.

``compare`` is stateless: it is computed from all the episodes up to the look, so the service
recomputes it at each look from its database. The intervals of successive looks are not
intersected (that would need the earlier looks); an interval may therefore widen a little from
one look to the next when the spread between people grows.

Pure: stdlib and numpy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .offpolicy import _t_quantile
from .types import FloatArray, IntArray

__all__ = [
    "ARMS",
    "CANDIDATE",
    "CONTROL",
    "DEFAULT_ALPHA",
    "DEFAULT_INTENDED_PEOPLE",
    "MIN_EPISODES",
    "MIN_PEOPLE",
    "VERDICTS",
    "Arm",
    "Comparison",
    "compare",
    "guard",
    "mixture_radius",
    "rho_for",
    "student_radius",
]

CANDIDATE = "candidate"
CONTROL = "control"
ARMS: tuple[str, ...] = (CANDIDATE, CONTROL)
BETTER, WORSE, UNDECIDED = "better", "worse", "no difference yet"
VERDICTS: tuple[str, ...] = (BETTER, WORSE, UNDECIDED)
DEFAULT_ALPHA = 0.05
# The number of people (both arms) at which the default rho makes the interval narrowest.
DEFAULT_INTENDED_PEOPLE = 40
# Per arm; under either no verdict is given (the normal approximation needs people).
MIN_PEOPLE = 5
MIN_EPISODES = 20


def _check_alpha(alpha: float) -> None:
    if isinstance(alpha, bool) or not isinstance(alpha, int | float) or not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be strictly between 0 and 1, got {alpha!r}.")


def _check_positive(name: str, value: float) -> None:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value <= 0
    ):
        raise ValueError(f"{name} must be a finite number above 0, got {value!r}.")


def rho_for(people: float, alpha: float = DEFAULT_ALPHA) -> float:
    """The mixture's tuning parameter that makes the interval narrowest at ``people`` people
    (Waudby-Smith et al.: rho^2 = (-2 ln alpha + ln(-2 ln alpha + 1)) / people)."""
    _check_positive("people", people)
    _check_alpha(alpha)
    log_term = -2.0 * math.log(alpha)
    return math.sqrt((log_term + math.log(log_term + 1.0)) / float(people))


def mixture_radius(t: int, rho: float, alpha: float = DEFAULT_ALPHA) -> float:
    """c(t): the paper's half-width over the difference's standard error at a look with ``t``
    people, sqrt((1 + 1 / (t rho^2)) (ln(1 + t rho^2) + 2 ln(1 / alpha))) (Robbins' normal
    mixture boundary, two-sided)."""
    if isinstance(t, bool) or not isinstance(t, int | np.integer) or t < 1:
        raise ValueError(f"t must be a whole number of people, at least 1, got {t!r}.")
    _check_positive("rho", rho)
    _check_alpha(alpha)
    x = float(t) * rho * rho
    return math.sqrt((1.0 + 1.0 / x) * (math.log1p(x) + 2.0 * math.log(1.0 / alpha)))


def student_radius(c: float, df: float) -> float:
    """Student's t quantile with ``df`` degrees of freedom (rounded down, at least 1) at the
    level of the normal quantile ``c``: t_df(1 - p / 2) with p = 2 (1 - Phi(c)). At least ``c``;
    it tends to ``c`` as ``df`` grows."""
    _check_positive("c", c)
    if isinstance(df, bool) or not isinstance(df, int | float | np.integer | np.floating):
        raise ValueError(f"df must be a number, got {df!r}.")
    if math.isnan(df) or df <= 0:
        raise ValueError(f"df must be above 0, got {df!r}.")
    if math.isinf(df):
        return c
    return _student(float(c), max(1, math.floor(df)))


@lru_cache(maxsize=4096)
def _student(c: float, df: int) -> float:
    """student_radius for whole degrees of freedom (cached: a look's bisection is the costly
    part of ``compare``, and c and df repeat from look to look)."""
    tail = NormalDist().cdf(-c)  # p / 2
    return max(c, _t_quantile(1.0 - tail, df))


@dataclass(frozen=True)
class Arm:
    """One arm at a look: its people and episodes so far; its mean return per encounter (None
    without episodes) with its cluster-robust standard error (None under 2 people); and its
    effective number of people, (sum m_i)^2 / sum m_i^2 for people with m_i episodes."""

    name: str
    n_people: int
    n_episodes: int
    mean: float | None
    std_error: float | None
    effective_people: float

    def to_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "n_people": int(self.n_people),
            "n_episodes": int(self.n_episodes),
            "mean": self.mean,
            "std_error": self.std_error,
            "effective_people": float(self.effective_people),
        }


@dataclass(frozen=True)
class Comparison:
    """A look at a rollout: candidate - control in mean return per encounter, with an interval
    valid at every look at once (``1 - alpha``, see the module's docstring) and its verdict.

    ``difference`` is given whenever both arms have episodes; ``low``, ``high`` and a verdict
    other than "no difference yet" only when there is enough evidence (``enough``; otherwise
    ``reason`` says what is missing). ``radius`` is the interval's half-width over
    ``std_error``: Student's t on ``df`` degrees of freedom at the level of ``mixture``, the
    paper's c(t)."""

    candidate: Arm
    control: Arm
    difference: float | None
    low: float | None
    high: float | None
    std_error: float | None
    df: float | None
    mixture: float | None
    radius: float | None
    verdict: str
    enough: bool
    reason: str  # "" when enough
    alpha: float
    rho: float

    @property
    def n_people(self) -> int:
        """t: the people of both arms."""
        return self.candidate.n_people + self.control.n_people

    @property
    def interval(self) -> tuple[float, float] | None:
        """(low, high), or None when there is not enough evidence."""
        if self.low is None or self.high is None:
            return None
        return (self.low, self.high)

    def to_dict(self) -> dict[str, object]:
        """Plain JSON types (an infinite df becomes None)."""
        df = self.df if self.df is None or math.isfinite(self.df) else None
        return {
            "candidate": self.candidate.to_dict(),
            "control": self.control.to_dict(),
            "difference": self.difference,
            "low": self.low,
            "high": self.high,
            "std_error": self.std_error,
            "df": df,
            "mixture": self.mixture,
            "radius": self.radius,
            "verdict": self.verdict,
            "enough": bool(self.enough),
            "reason": self.reason,
            "alpha": float(self.alpha),
            "rho": float(self.rho),
            "n_people": int(self.n_people),
        }


def _inputs(
    cluster_ids: ArrayLike, arms: ArrayLike, returns: ArrayLike
) -> tuple[IntArray, NDArray[np.bool_], FloatArray]:
    """(person index per episode, whether each episode is the candidate's, returns), checked."""
    people = np.asarray(cluster_ids)
    arm = np.asarray(arms)
    try:
        values = np.asarray(returns, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"returns must hold numbers: {error}") from None
    for name, array in (("cluster_ids", people), ("arms", arm), ("returns", values)):
        if array.ndim != 1:
            raise ValueError(f"{name} must be one-dimensional, got shape {array.shape}.")
    if not people.size == arm.size == values.size:
        raise ValueError(
            f"cluster_ids, arms and returns must have one entry per episode, got "
            f"{people.size}, {arm.size} and {values.size}."
        )
    if not np.all(np.isfinite(values)):
        raise ValueError(f"returns must be finite (episode {int(np.argmin(np.isfinite(values)))}).")
    if people.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.bool_), values
    is_candidate = np.asarray(arm == CANDIDATE, dtype=np.bool_)
    unknown = ~(is_candidate | (arm == CONTROL))
    if np.any(unknown):
        raise ValueError(
            f"arms must be {CANDIDATE!r} or {CONTROL!r}: episode {int(np.argmax(unknown))} has "
            f"{arm[unknown][0]!r}."
        )
    try:
        labels, index = np.unique(people, return_inverse=True)
    except TypeError as error:
        raise ValueError(f"cluster_ids must be all integers or all strings: {error}") from None
    index = index.reshape(-1).astype(np.int64)
    episodes = np.bincount(index, minlength=labels.size)
    theirs = np.bincount(index, weights=is_candidate.astype(np.float64), minlength=labels.size)
    mixed = (theirs > 0) & (theirs < episodes)
    if np.any(mixed):
        raise ValueError(
            f"person {labels[mixed][0].item()!r} has episodes in both arms: a person is "
            f"assigned to one arm."
        )
    return index, is_candidate, values


def _arm(name: str, episodes: FloatArray, sums: FloatArray) -> tuple[Arm, float | None]:
    """An arm from its people's numbers of episodes and sums of returns; and its variance (None
    under 2 people)."""
    n_people = int(episodes.size)
    total = float(episodes.sum())
    if total == 0:
        return Arm(name, 0, 0, None, None, 0.0), None
    mean = float(sums.sum()) / total
    effective = total * total / float(episodes @ episodes)
    variance: float | None = None
    if n_people >= 2:
        residuals = sums - mean * episodes
        variance = n_people / (n_people - 1) * float(residuals @ residuals) / (total * total)
    std_error = None if variance is None else math.sqrt(variance)
    return Arm(name, n_people, int(total), mean, std_error, effective), variance


def _degrees_of_freedom(arms: Sequence[tuple[Arm, float]]) -> float:
    """Welch and Satterthwaite's degrees of freedom of the summed variances, each arm's on its
    effective number of people minus one (infinite when every variance is 0)."""
    total = sum(variance for _, variance in arms)
    if total == 0.0:
        return math.inf
    parts = 0.0
    for arm, variance in arms:
        f = arm.effective_people - 1.0
        if variance > 0.0:
            parts += variance * variance / max(f, 1e-12)
    return total * total / parts


def _not_enough(candidate: Arm, control: Arm, min_people: int, min_episodes: int) -> str:
    missing = []
    for arm in (candidate, control):
        if arm.n_people < min_people:
            missing.append(f"{arm.n_people} people in the {arm.name} arm ({min_people} needed)")
        elif arm.n_episodes < min_episodes:
            missing.append(
                f"{arm.n_episodes} episodes in the {arm.name} arm ({min_episodes} needed)"
            )
    return "not enough evidence: " + "; ".join(missing) if missing else ""


def compare(
    cluster_ids: Sequence[int] | Sequence[str] | ArrayLike,
    arms: Sequence[str] | ArrayLike,
    returns: Sequence[float] | ArrayLike,
    *,
    alpha: float = DEFAULT_ALPHA,
    rho: float | None = None,
    min_people: int = MIN_PEOPLE,
    min_episodes: int = MIN_EPISODES,
) -> Comparison:
    """Candidate - control in mean return per encounter, from every closed episode up to the
    look: ``cluster_ids[i]`` is episode i's person (integers or strings), ``arms[i]`` its arm
    (``CANDIDATE`` or ``CONTROL``; a person's episodes all in one arm) and ``returns[i]`` its
    return. The interval holds the truth at every look at once with probability ``1 - alpha``
    (asymptotically; see the module's docstring). ``rho`` is the mixture's tuning parameter
    (default: :func:`rho_for` ``DEFAULT_INTENDED_PEOPLE`` people at ``alpha``). No interval and
    no verdict under ``min_people`` people or ``min_episodes`` episodes in either arm (at least
    2 people, whatever is asked: the variance needs them)."""
    _check_alpha(alpha)
    if rho is None:
        rho = rho_for(DEFAULT_INTENDED_PEOPLE, alpha)
    _check_positive("rho", rho)
    for name, value in (("min_people", min_people), ("min_episodes", min_episodes)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
            raise ValueError(f"{name} must be a whole number, 0 or more, got {value!r}.")
    index, is_candidate, values = _inputs(cluster_ids, arms, returns)
    n = int(index.max()) + 1 if index.size else 0
    episodes = np.bincount(index, minlength=n).astype(np.float64)
    sums = np.bincount(index, weights=values, minlength=n).astype(np.float64)
    theirs = np.zeros(n, dtype=np.bool_)
    theirs[index[is_candidate]] = True
    candidate, v_candidate = _arm(CANDIDATE, episodes[theirs], sums[theirs])
    control, v_control = _arm(CONTROL, episodes[~theirs], sums[~theirs])
    difference = (
        None if candidate.mean is None or control.mean is None else candidate.mean - control.mean
    )
    reason = _not_enough(candidate, control, max(int(min_people), 2), int(min_episodes))
    low = high = std_error = df = mixture = radius = None
    verdict = UNDECIDED
    if not reason:
        assert difference is not None
        assert v_candidate is not None
        assert v_control is not None
        std_error = math.sqrt(v_candidate + v_control)
        df = _degrees_of_freedom(((candidate, v_candidate), (control, v_control)))
        mixture = mixture_radius(candidate.n_people + control.n_people, rho, alpha)
        radius = student_radius(mixture, df)
        low, high = difference - radius * std_error, difference + radius * std_error
        if low > 0.0:
            verdict = BETTER
        elif high < 0.0:
            verdict = WORSE
    return Comparison(
        candidate=candidate,
        control=control,
        difference=difference,
        low=low,
        high=high,
        std_error=std_error,
        df=df,
        mixture=mixture,
        radius=radius,
        verdict=verdict,
        enough=not reason,
        reason=reason,
        alpha=float(alpha),
        rho=float(rho),
    )


def guard(comparison: Comparison, *, margin: float = 0.0) -> bool:
    """The automatic rollback's condition: True when the candidate is worse with the method's
    confidence, the interval's high end below ``-margin`` (with the default margin 0: below 0,
    the verdict "worse"). A ``margin`` above 0 rolls back only a candidate worse by more than
    the margin per encounter. False when there is not enough evidence."""
    if (
        isinstance(margin, bool)
        or not isinstance(margin, int | float)
        or not math.isfinite(margin)
        or margin < 0
    ):
        raise ValueError(f"margin must be a finite number, 0 or more, got {margin!r}.")
    return comparison.enough and comparison.high is not None and comparison.high < -margin
