"""Off-policy evaluation: what a candidate learner would have earned, read from the logs of another.

The robot's negotiations with people are logged as *episodes* of one to about eight steps. At each
step the log holds the probability the logging learner gave the action it took (``logged``), the
probability the candidate learner gives the same action in the same state (``target``) and the
step's reward. An episode's value is the sum of its rewards (no discounting). The question is the
candidate's expected value per episode, had it been in charge, without letting it act.

Importance weights
------------------
An episode the candidate would have been more likely to produce counts more: the *cumulative
weight* at step t is the product, over the steps up to and including t, of target / logged. A
step's reward is weighted by the weight of the actions that led to it and no later one
(per-decision weighting). If the candidate never takes a logged action, the weight is 0 from
there on.

The weights are *clipped*: a cumulative weight above ``clip`` counts as ``clip``
(``DEFAULT_CLIP`` unless told). One unlikely episode can otherwise carry a weight of thousands
and decide the estimate alone. Clipping lowers the variance at the price of a bias (for
rewards of one sign, toward 0); ``clipped_share`` reports the share of steps whose weight the clip
cut, so a reader can see whether it bit. Every result states the clip it used.

The estimators
--------------
``pdis`` (per-decision importance sampling): the mean over episodes of the sum over steps of
weight x reward. Unbiased when the clip never binds and the candidate puts no probability on
actions the logger never takes; its variance grows quickly as the two learners part.

``wpdis`` (weighted, self-normalised): at each step index t, the weighted mean of the step-t
rewards, sum_i w_it r_it / sum_i w_it, summed over t. Episodes have different lengths: an episode
that has ended is treated as sitting in an absorbing state with reward 0, its weight held at its
last value, so it still counts in the step-t denominator. (Normalising only over the episodes
still running would count a long episode's late rewards as if every episode lasted that long.)
With the candidate equal to the logger it is exactly the mean return. It is biased for small
samples (the bias vanishes as the logs grow) but much less variable than pdis, and a step's term
always lies between the smallest and the largest of the step-t rewards and 0.

``dr`` (doubly robust, Jiang & Li 2016, per-decision, no discount): pdis with the candidate's own
model as a control variate. Per episode, the sum over steps of
``w_t (r_t - q_hat_t) + w_(t-1) v_hat_t`` with w_(-1) = 1, where ``q_hat`` is the model's return
to go after the logged action and ``v_hat`` the model's value of the state under the candidate.
With an exact model the only noise left is the world's; with a wrong model it is still unbiased
(as pdis, when the clip does not bind and ``v_hat`` is the candidate's average of ``q_hat``), only
noisier. With ``q_hat = v_hat = 0`` it is pdis. The model must speak in the unit of the
estimate: ``q_hat`` and ``v_hat`` are returns to go, undiscounted (a learner plans with a
discount; :meth:`TabularLearner.action_values` with ``gamma=1.0`` gives its model's plain sums).

``wdr`` (weighted doubly robust, Thomas & Brunskill 2016): dr's terms, self-normalised as wpdis
is, per step index: sum_t [sum_i w_it (r_it - q_hat_it) / sum_i w_it + sum_i w_i(t-1) v_hat_it /
sum_i w_i(t-1)] (the first step's v_hat simply averaged; ended episodes hold their last weight
and add 0). Biased for small samples as wpdis is, usually less variable than dr. With
``q_hat = v_hat = 0`` it is wpdis. Where the logs seldom show what the candidate does (weights
averaging below 1), wpdis spreads the missing share over what the logs show and pdis counts it
as 0; dr and wdr let the candidate's own model speak for it (the first step's ``v_hat`` is not
weighted, and no correction reaches what the logs do not hold), which is right when the model
is, and as wrong as the model otherwise: an optimistic model (R-MAX values what it has not
tried at its bound) makes an optimistic estimate. Without a model, dr counts it as 0 as pdis
does.

The unbiasedness claims need every action the candidate may take to have been possible under the
logger. ``unsupported`` is the candidate's probability, in each logged state, of actions the
logger gave probability exactly 0; no estimator can see what those actions would have earned.
Its mean and maximum are reported; above a mean of ``UNSUPPORTED_LIMIT`` (0.1: a tenth of the
candidate's choices are actions the logs cannot show) no value is given.

How much to believe an estimate
-------------------------------
The *effective sample size* (ESS) of the episodes' final weights, (sum w)^2 / sum w^2, is the
number of equally weighted episodes the logs are worth for this candidate: the number of
episodes when the candidate is the logger, and small when a few episodes carry all the weight.
Under ``DEFAULT_MIN_EPISODES`` (20) episodes or an ESS under ``DEFAULT_MIN_ESS`` (10), no value
is given: the result says "not enough evidence" with both figures. With fewer episodes an
interval is mostly noise; an ESS under 10 means a handful of episodes decide everything.

Every episode's final weight (unclipped) averages 1 in expectation when the logs show the
candidate's behaviour: for each state, the logged actions' ratios target / logged average the
candidate's probability of actions the logger can take, which is 1 when it takes nothing else.
Heavy-tailed weights make the mean of a sample wander (a rare large weight lifts it above 1; its
absence leaves it below), but a mean far *below* 1 says that much of what the candidate does is
what the logger (almost) never does: what it would earn there is not in the logs, and every
estimator underestimates. When the mean plus twice its standard error is below
1 - ``WEIGHT_TOLERANCE`` (0.75), no value is given; the reason gives the mean (``weight_mean``).
On simulated fleets (docs/method.md §17) the candidates whose estimates missed the truth far
beyond their intervals had means of 0.5-0.7, those that covered it 0.98-1.01; the tests' far
candidate, whose intervals cover, 0.7-1.4 with standard errors of 0.1 and more.

``dr`` and ``wdr`` lean on the candidate's model where the logs are silent; a model is the
learner's belief, and some beliefs are bounds, not estimates (R-MAX values what it has not
tried at an optimistic bound, ten times the best step's reward). When the model's value of
the logged episodes' first states, on average, lies outside the range of the returns the logs
show (0 included), they give no value and say so, with both figures; wpdis, which uses no
model, may still answer. (On simulated fleets, R-MAX's dr estimates were otherwise 14 to 33
rewards per encounter too high.)

What the logs do not show
-------------------------
A mean weight below 1 is also a measure: 1 - ``weight_mean`` is the share of the candidate's
episodes that the logs, in effect, do not hold. ``wpdis`` spreads that share over what the logs
show (as if it earned what the rest earns), ``pdis`` counts it as earning 0, ``dr`` and ``wdr``
as the candidate's model says (``dr`` without a model: 0); none is known. Every interval
therefore reaches further, by :func:`unseen_margins`: that share may earn anything from the
lowest to the highest return the logs show (0 included), so the interval's low end moves down
by u x (value - lowest) and its high end up by u x (highest - value) for ``wpdis``, ``wdr`` and
``dr`` with a model (u x -lowest and u x highest for ``pdis`` and ``dr`` without one),
u = 1 - ``weight_mean``. Where
the logs show the candidate (weights averaging 1 or more) nothing changes; the further it
strays, the wider its interval, instead of a narrow interval around a biased value. On
simulated fleets (docs/method.md §17) this took the bootstrap's coverage of a candidate that
strays from the logger (DTS under HRI's logs at 200 episodes, weights averaging 0.88) from
78 % to 98 %, and of three candidates together to 94-97 % at every size. It assumes the
unseen share earns within what the logs show; a candidate whose unseen choices earn more than
anything logged can still be underestimated.

Intervals
---------
People differ, and one person's episodes are not independent of each other; different people
are. The ``bootstrap`` interval (the default) therefore resamples *people*, with replacement,
recomputes the estimator on each resample (for wpdis, the ratio itself) and takes the middle
share of the recomputed values (percentile bootstrap). It describes the spread across the
population of people the logged ones were drawn from. A plain percentile interval is too narrow
when few people are resampled (a 95% interval covered the truth in 83-85% of simulated logs of 5
people, 89-91% with 10, 93% with 20), so the share is widened as in Hesterberg's (2015) *expanded
percentile* interval: for n people, the quantiles at the normal level matching sqrt(n / (n - 1))
times Student's t quantile on n - 1 degrees of freedom (for 20 people and 95%: the 1.6% and 98.4%
quantiles instead of 2.5% and 97.5%). The same simulations then covered in 91-93%, 93-96% and
94-95%. With fewer than ``MIN_CLUSTERS`` (5) people, resampling people is meaningless; the
episodes are resampled instead and the interval's method says ``bootstrap-episodes``: it then
speaks only for these people and assumes their episodes independent. The bootstrap remains an
approximation: with a small ESS, or a heavily clipped candidate, it can be too narrow.

The ``bernstein`` interval holds without the bootstrap's approximations: the empirical Bernstein
bound of Maurer & Pontil (2009), mean +/- (sqrt(2 V ln(4/delta) / n) + 7 b ln(4/delta) /
(3 (n - 1))) over the n per-episode values, with V their sample variance, b the width of the
range they are known to lie in and delta = 1 - confidence (each side at delta / 2, hence
ln(4/delta)). It needs ``reward_range`` = (lo, hi): every episode's negative rewards sum to at
least lo and its positive rewards to at most hi (when an episode's rewards share one sign, simply
the range of its return). Then, with weights in [0, clip]:

- a pdis per-episode value lies in clip x [min(lo, 0), max(hi, 0)];
- a dr per-episode value adds 2T - 1 model terms, T the longest logged episode: v_hat at the
  first step (weight 1) and, for each later step, weight x v_hat, and for each step, -weight x
  q_hat; with the model's values in [m_lo, m_hi] (the smallest range holding ``reward_range`` and
  every logged q_hat and v_hat), each term lies in clip x [min(m_lo, 0), max(m_hi, 0)] or its
  negative. This takes the logs' longest episode and the model's logged values as the limits of
  all episodes and of the model, and it is wide: the dr bound is loose;
- wpdis has no per-episode values; its bernstein interval is the pdis one (method
  ``bernstein-pdis``) around the pdis mean; nor has wdr, whose bernstein interval is the dr one
  (``bernstein-dr``) around the dr mean.

The bound is conservative (wide) and assumes the episodes independent, which people's repeated
episodes are not; it covers the expectation of the *clipped* estimator, which is the candidate's
value only when the clip does not bind. Whichever the method, when ``reward_range`` is given the
interval is cut to it (any policy's value lies in it), and it is checked against the logs.

Which estimator, which clip
---------------------------
The default is ``wpdis``. On the learners' own logs it was the most trustworthy: over 200
simulated fleets logged under HRI (docs/method.md §17), at 1,000 episodes per fleet its 95 %
intervals held the truth of a candidate at a third of a reward per encounter below the logger in
90 % of the fleets with no bias, where dr and pdis were biased by a third of a reward (their
intervals covered in 44 % and 51 %): that candidate often does what the logger seldom does
(its weights average 0.8), and pdis counts the part the logs do not show as earning nothing
(dr then, with a model in discounted values, little more), while the self-normalisation of
wpdis spreads it over what they do show. Where the
logs show the candidate well (weights averaging 1) the three agree. In the tests' simulated
negotiation (tests/unit/learning/test_offpolicy.py: 300 episodes from 20 people, a candidate
with an ESS of about 50), dr had the smallest error (RMSE 0.08 against 0.11 for wpdis and 0.13
for pdis) with the candidate's model knowing only the average person, and stayed unbiased with
a badly wrong model: with a good model and logs that show the candidate, dr is the better
choice, and it is offered. Without a model (``q_hat`` and ``v_hat`` all 0) dr *is* pdis.

``wdr`` is offered for a candidate whose model deserves trust. Over the same 200 fleets, DTS
(weights averaging 0.64 at 1,000 episodes) was underestimated by 0.13 with wdr and 0.17 with
dr, against 0.94 with wpdis, and ranked above the logger in about three fleets in four of those
answered where wpdis almost never did; HRI at tau = 0.1, whose model is HRI's tables where it
wanders, was underestimated by 0.43 with wdr, where wpdis has no bias. wpdis stays the
default: it never credits a candidate with more than the logs show, which is the safe side for
a rollout (it may keep a better learner out, never let a worse one in on its own word).

The default clip, 20, was hardly ever reached by the weights of the tests' candidates (ESS 50
or more, three steps at most); a clip of 10 lowered the error of pdis and wpdis a little there,
but biased dr with a wrong model (by a third of its error). Longer episodes reach a given clip
more often: read ``clipped_share``.

The value is a mean over episodes: a person with more episodes counts more.

Pure: stdlib and numpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
from numpy.typing import NDArray

from .types import FloatArray, IntArray

__all__ = [
    "DEFAULT_CLIP",
    "DEFAULT_ESTIMATOR",
    "DEFAULT_MIN_EPISODES",
    "DEFAULT_MIN_ESS",
    "ESTIMATORS",
    "INTERVALS",
    "MIN_CLUSTERS",
    "MODEL_ESTIMATORS",
    "UNSUPPORTED_LIMIT",
    "WEIGHT_TOLERANCE",
    "Estimate",
    "Interval",
    "Steps",
    "estimate",
    "expanded_level",
    "on_policy",
    "per_cluster",
    "point",
    "resampled",
    "unseen_margins",
]

BoolArray = NDArray[np.bool_]

ESTIMATORS: tuple[str, ...] = ("pdis", "wpdis", "dr", "wdr")
INTERVALS: tuple[str, ...] = ("bootstrap", "bernstein")
# See "Which estimator, which clip" in the module's docstring.
DEFAULT_ESTIMATOR = "wpdis"
# An episode counts at most as much as 20 ordinary ones; see "Which estimator, which clip".
DEFAULT_CLIP = 20.0
DEFAULT_MIN_EPISODES = 20
DEFAULT_MIN_ESS = 10.0
# With fewer people than this the bootstrap resamples episodes instead (``bootstrap-episodes``).
MIN_CLUSTERS = 5
WEIGHT_TOLERANCE = 0.25
UNSUPPORTED_LIMIT = 0.1
# Estimators that use the candidate's model (``q_hat``, ``v_hat``): ask the replay for it.
MODEL_ESTIMATORS = frozenset(("dr", "wdr"))
# Estimators whose value is a ratio over episodes (no per-episode values).
_SELF_NORMALISED = frozenset(("wpdis", "wdr"))

_STEP_FIELDS: tuple[str, ...] = (
    "logged",
    "target",
    "reward",
    "q_hat",
    "v_hat",
    "unsupported",
)
_REQUIRED_KEYS = frozenset(("logged", "target", "reward"))
_OPTIONAL_KEYS = frozenset(("q_hat", "v_hat", "unsupported"))
_TOLERANCE = 1e-9
# The bootstrap's count matrix is drawn in blocks of at most this many entries.
_BLOCK = 1 << 21


def _int_vector(name: str, value: object) -> IntArray:
    array = np.asarray(value)
    if array.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {array.shape}.")
    if array.size == 0:
        return np.zeros(0, dtype=np.int64)
    if array.dtype.kind not in "iu":
        raise ValueError(f"{name} must hold integers, got dtype {array.dtype}.")
    return array.astype(np.int64)


def _float_vector(name: str, value: object, size: int) -> FloatArray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must hold numbers: {error}") from None
    if array.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},) (one per step), got {array.shape}.")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite (step {int(np.argmin(np.isfinite(array)))}).")
    return array


def _first(mask: BoolArray) -> int:
    return int(np.argmax(mask))


@dataclass(frozen=True, eq=False)
class Steps:
    """Logged episodes, flattened: episode i's steps are rows ``offsets[i]:offsets[i+1]``, in
    order. Arrays are copied and read-only; ``cluster`` labels are any non-negative integers
    (a subset keeps the original labels)."""

    cluster: IntArray  # (E,) the person of each episode
    offsets: IntArray  # (E+1,) offsets[0] == 0, strictly increasing
    logged: FloatArray  # (N,) the logger's probability of the logged action, in (0, 1]
    target: FloatArray  # (N,) the candidate's probability of the same action, in [0, 1]
    reward: FloatArray  # (N,) the step's reward
    q_hat: FloatArray  # (N,) the candidate's model: return to go after the logged action
    v_hat: FloatArray  # (N,) the candidate's model: the state's value under the candidate
    unsupported: FloatArray  # (N,) the candidate's mass on actions the logger never takes

    def __post_init__(self) -> None:
        cluster = _int_vector("cluster", self.cluster)
        offsets = _int_vector("offsets", self.offsets)
        if offsets.size != cluster.size + 1:
            raise ValueError(
                f"offsets must have n_episodes + 1 = {cluster.size + 1} entries, "
                f"got {offsets.size}."
            )
        if offsets[0] != 0:
            raise ValueError(f"offsets[0] must be 0, got {int(offsets[0])}.")
        empty = np.diff(offsets) <= 0
        if np.any(empty):
            raise ValueError(
                f"offsets must be strictly increasing: episode {_first(empty)} has no steps."
            )
        if np.any(cluster < 0):
            raise ValueError(f"cluster labels must be 0 or more, got {int(cluster.min())}.")
        n = int(offsets[-1])
        arrays = {name: _float_vector(name, getattr(self, name), n) for name in _STEP_FIELDS}
        logged, target, unsupported = arrays["logged"], arrays["target"], arrays["unsupported"]
        bad = (logged <= 0.0) | (logged > 1.0)
        if np.any(bad):
            raise ValueError(
                f"logged probabilities must be in (0, 1]: step {_first(bad)} has "
                f"{float(logged[bad][0])!r} (a logged action had a chance to be taken)."
            )
        for name, values in (("target", target), ("unsupported", unsupported)):
            bad = (values < 0.0) | (values > 1.0)
            if np.any(bad):
                raise ValueError(
                    f"{name} must be in [0, 1]: step {_first(bad)} has {float(values[bad][0])!r}."
                )
        bad = target + unsupported > 1.0 + _TOLERANCE
        if np.any(bad):
            raise ValueError(
                f"target + unsupported must be at most 1 (they are probabilities of different "
                f"actions): step {_first(bad)} sums to {float((target + unsupported)[bad][0])!r}."
            )
        for name, array in (("cluster", cluster), ("offsets", offsets), *arrays.items()):
            array = array.copy()
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    @classmethod
    def from_episodes(
        cls,
        episodes: Sequence[Mapping[str, Sequence[float]]],
        clusters: Sequence[int],
    ) -> Steps:
        """Steps from one mapping per episode, with keys ``logged``, ``target``, ``reward`` and
        optionally ``q_hat``, ``v_hat``, ``unsupported`` (0.0 when absent), each a sequence of
        one number per step; ``clusters[i]`` is episode i's person."""
        if len(episodes) != len(clusters):
            raise ValueError(
                f"{len(episodes)} episodes but {len(clusters)} clusters: one person per episode."
            )
        columns: dict[str, list[FloatArray]] = {name: [] for name in _STEP_FIELDS}
        lengths = []
        for i, episode in enumerate(episodes):
            keys = set(episode)
            if missing := _REQUIRED_KEYS - keys:
                raise ValueError(f"episode {i} lacks {', '.join(sorted(missing))}.")
            if unknown := keys - _REQUIRED_KEYS - _OPTIONAL_KEYS:
                raise ValueError(f"episode {i} has unknown keys: {', '.join(sorted(unknown))}.")
            length = len(episode["logged"])
            if length == 0:
                raise ValueError(f"episode {i} has no steps.")
            for name in _STEP_FIELDS:
                values = episode.get(name)
                if values is None:
                    columns[name].append(np.zeros(length))
                    continue
                if len(values) != length:
                    raise ValueError(
                        f"episode {i}: {name} has {len(values)} values, logged has {length}."
                    )
                columns[name].append(_float_vector(f"episode {i}: {name}", values, length))
            lengths.append(length)
        offsets = np.concatenate(([0], np.cumsum(np.asarray(lengths, dtype=np.int64))))

        def column(name: str) -> FloatArray:
            parts = columns[name]
            return np.concatenate(parts) if parts else np.zeros(0)

        return cls(
            cluster=np.asarray(clusters, dtype=np.int64),
            offsets=offsets.astype(np.int64),
            logged=column("logged"),
            target=column("target"),
            reward=column("reward"),
            q_hat=column("q_hat"),
            v_hat=column("v_hat"),
            unsupported=column("unsupported"),
        )

    @property
    def n_episodes(self) -> int:
        return int(self.cluster.size)

    @property
    def n_clusters(self) -> int:
        """The number of distinct people."""
        return int(np.unique(self.cluster).size)

    @property
    def n_steps(self) -> int:
        return int(self.offsets[-1])

    @property
    def lengths(self) -> IntArray:
        """The number of steps of each episode."""
        return np.diff(self.offsets)

    def returns(self) -> FloatArray:
        """Each episode's return: the sum of its rewards."""
        if self.n_episodes == 0:
            return np.zeros(0)
        return np.add.reduceat(self.reward, self.offsets[:-1])

    def select(self, mask: BoolArray) -> Steps:
        """The episodes where ``mask`` (one boolean per episode) is true, in order."""
        keep = np.asarray(mask)
        if keep.dtype != np.bool_ or keep.shape != (self.n_episodes,):
            raise ValueError(
                f"mask must be booleans of shape ({self.n_episodes},) (one per episode), "
                f"got {keep.dtype} {keep.shape}."
            )
        lengths = self.lengths[keep]
        rows = np.repeat(keep, self.lengths)
        offsets = np.concatenate(([0], np.cumsum(lengths))).astype(np.int64)
        return Steps(
            cluster=self.cluster[keep],
            offsets=offsets,
            logged=self.logged[rows],
            target=self.target[rows],
            reward=self.reward[rows],
            q_hat=self.q_hat[rows],
            v_hat=self.v_hat[rows],
            unsupported=self.unsupported[rows],
        )


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


@dataclass(frozen=True)
class Interval:
    """A ``confidence`` interval; ``method`` says how it was made: ``bootstrap`` (people
    resampled), ``bootstrap-episodes`` (too few people: episodes resampled), ``bernstein``,
    ``bernstein-pdis`` (wpdis: the bound on the pdis values) or ``bernstein-dr`` (wdr: the bound
    on the dr values)."""

    low: float
    high: float
    method: str
    confidence: float

    def to_dict(self) -> dict[str, object]:
        return {
            "low": float(self.low),
            "high": float(self.high),
            "method": self.method,
            "confidence": float(self.confidence),
        }


@dataclass(frozen=True)
class Estimate:
    """One estimate of a policy's value per episode, with what it rests on."""

    estimator: str
    value: float | None  # None when not enough evidence
    interval: Interval | None  # None when not enough evidence
    n_episodes: int
    n_clusters: int
    ess: float  # (sum w)^2 / sum w^2 of the episodes' final (clipped) weights
    clip: float
    clipped_share: float  # share of steps whose cumulative weight the clip cut
    unsupported_mean: float
    unsupported_max: float
    enough: bool
    reason: str  # "" when enough
    weight_mean: float = 1.0  # mean of the episodes' final weights, unclipped (1 when the logs
    # show the candidate's behaviour; see "How much to believe an estimate")

    def to_dict(self) -> dict[str, object]:
        """Plain JSON types (a non-finite number becomes None)."""
        return {
            "estimator": self.estimator,
            "value": None if self.value is None else _finite_or_none(self.value),
            "interval": None if self.interval is None else self.interval.to_dict(),
            "n_episodes": int(self.n_episodes),
            "n_clusters": int(self.n_clusters),
            "ess": _finite_or_none(self.ess),
            "clip": _finite_or_none(self.clip),
            "clipped_share": float(self.clipped_share),
            "unsupported_mean": float(self.unsupported_mean),
            "unsupported_max": float(self.unsupported_max),
            "enough": bool(self.enough),
            "reason": self.reason,
            "weight_mean": _finite_or_none(self.weight_mean),
        }


# ---------------------------------------------------------------------------------------------
# Checks of the options


def _check_estimator(estimator: str) -> None:
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}: one of {', '.join(ESTIMATORS)}.")


def _check_clip(clip: float) -> None:
    if not isinstance(clip, int | float) or isinstance(clip, bool) or not math.isfinite(clip):
        raise ValueError(f"clip must be a finite number, got {clip!r}.")
    if clip <= 0:
        raise ValueError(f"clip must be above 0, got {clip!r}.")


def _check_interval(interval: str, confidence: float, n_boot: int) -> None:
    if interval not in INTERVALS:
        raise ValueError(f"unknown interval {interval!r}: one of {', '.join(INTERVALS)}.")
    if not isinstance(confidence, int | float) or not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be strictly between 0 and 1, got {confidence!r}.")
    if isinstance(n_boot, bool) or not isinstance(n_boot, int | np.integer) or n_boot < 100:
        raise ValueError(f"n_boot must be an integer of at least 100, got {n_boot!r}.")


def _check_minimums(min_episodes: int, min_ess: float) -> None:
    if (
        isinstance(min_episodes, bool)
        or not isinstance(min_episodes, int | np.integer)
        or min_episodes < 2
    ):
        raise ValueError(f"min_episodes must be an integer of at least 2, got {min_episodes!r}.")
    if not isinstance(min_ess, int | float) or not 0.0 <= min_ess < math.inf:
        raise ValueError(f"min_ess must be a finite number of at least 0, got {min_ess!r}.")


def _check_range(steps: Steps, reward_range: tuple[float, float] | None) -> None:
    """``reward_range`` is well formed and holds for every logged episode."""
    if reward_range is None:
        return
    try:
        lo, hi = (float(bound) for bound in reward_range)
    except (TypeError, ValueError):
        raise ValueError(f"reward_range must be (lo, hi), got {reward_range!r}.") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise ValueError(f"reward_range must be finite with lo <= hi, got {reward_range!r}.")
    if steps.n_episodes == 0:
        return
    starts = steps.offsets[:-1]
    gains = np.add.reduceat(np.maximum(steps.reward, 0.0), starts)
    losses = np.add.reduceat(np.minimum(steps.reward, 0.0), starts)
    slack = _TOLERANCE * max(1.0, abs(lo), abs(hi))
    if np.any(gains > hi + slack) or np.any(losses < lo - slack):
        bad = (gains > hi + slack) | (losses < lo - slack)
        i = _first(bad)
        raise ValueError(
            f"reward_range {reward_range!r} does not hold: episode {i}'s positive rewards sum to "
            f"{float(gains[i])!r} and its negative rewards to {float(losses[i])!r}."
        )


def _make_rng(rng: np.random.Generator | None) -> np.random.Generator:
    if rng is None:
        return np.random.default_rng(0)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator or None, got {type(rng).__name__}.")
    return rng


# ---------------------------------------------------------------------------------------------
# The computation


@dataclass(frozen=True)
class _Weighted:
    """The episodes laid out as an (E, H) grid, H the longest episode's length."""

    weight: FloatArray  # clipped cumulative weights; after an episode's end, held at its last
    reward: FloatArray  # 0 after the end
    final: FloatArray  # (E,) each episode's last (clipped) weight
    clipped_share: float


def _grid(steps: Steps, values: FloatArray) -> FloatArray:
    lengths = steps.lengths
    episode = np.repeat(np.arange(steps.n_episodes), lengths)
    step = np.arange(steps.n_steps) - steps.offsets[:-1][episode]
    out = np.zeros((steps.n_episodes, int(lengths.max())))
    out[episode, step] = values
    return out


def _weighted(steps: Steps, clip: float) -> _Weighted:
    """Cumulative products of target / logged, summed as logarithms (no overflow, and a ratio of
    0 stays 0 for the rest of the episode), then clipped."""
    log_ratio = np.full(steps.n_steps, -np.inf)
    np.log(steps.target, out=log_ratio, where=steps.target > 0.0)
    log_ratio -= np.log(steps.logged)
    cumulative = np.cumsum(_grid(steps, log_ratio), axis=1)  # padded with 0: held after the end
    log_clip = math.log(clip)
    weight = np.exp(np.minimum(cumulative, log_clip))
    cut = _grid(steps, np.ones(steps.n_steps)) * (cumulative > log_clip)
    return _Weighted(
        weight=weight,
        reward=_grid(steps, steps.reward),
        final=weight[:, -1],
        clipped_share=float(cut.sum() / steps.n_steps),
    )


def _ess(final: FloatArray) -> float:
    square = float(np.sum(final * final))
    return float(np.sum(final)) ** 2 / square if square > 0.0 else 0.0


def _episode_values(steps: Steps, estimator: str, weighted: _Weighted) -> FloatArray:
    """Each episode's pdis or dr value (wpdis has none: it is a ratio over episodes)."""
    w = weighted.weight
    if estimator == "dr":
        before = np.concatenate((np.ones((w.shape[0], 1)), w[:, :-1]), axis=1)
        q_hat, v_hat = _grid(steps, steps.q_hat), _grid(steps, steps.v_hat)
        values = np.sum(w * (weighted.reward - q_hat) + before * v_hat, axis=1)
    else:
        values = np.sum(w * weighted.reward, axis=1)
    return np.asarray(values, dtype=np.float64)


def _group_sums(group: IntArray, n_groups: int, values: FloatArray) -> FloatArray:
    """(n_groups, columns): the column sums of ``values`` (rows: episodes) within each group."""
    columns = values.reshape(values.shape[0], -1)
    out = np.empty((n_groups, columns.shape[1]))
    for j in range(columns.shape[1]):
        out[:, j] = np.bincount(group, weights=columns[:, j], minlength=n_groups)
    return out


def _ratio_columns(
    steps: Steps, estimator: str, weighted: _Weighted
) -> tuple[FloatArray, FloatArray]:
    """Per episode, (E, columns): the numerator and denominator terms of a self-normalised
    estimator, whose value is the sum over columns of (sum of numerators) / (sum of
    denominators). wpdis: one column per step index, w x r over w. wdr: those of w x (r - q_hat)
    over w, and one per step index of w_(t-1) x v_hat over w_(t-1) (w_(-1) = 1: the first is
    the mean of the first steps' v_hat)."""
    w = weighted.weight
    if estimator == "wpdis":
        return w * weighted.reward, w
    before = np.concatenate((np.ones((w.shape[0], 1)), w[:, :-1]), axis=1)
    q_hat, v_hat = _grid(steps, steps.q_hat), _grid(steps, steps.v_hat)
    return (
        np.concatenate((w * (weighted.reward - q_hat), before * v_hat), axis=1),
        np.concatenate((w, before), axis=1),
    )


def _statistics(
    steps: Steps, estimator: str, weighted: _Weighted, group: IntArray, n_groups: int
) -> tuple[FloatArray, FloatArray]:
    """Each group's sufficient statistics (numerator, denominator), each (n_groups, columns),
    such that a resample drawing group g c_g times has the value
    sum over columns of (c @ numerator) / (c @ denominator)."""
    if estimator in _SELF_NORMALISED:
        top, bottom = _ratio_columns(steps, estimator, weighted)
        return _group_sums(group, n_groups, top), _group_sums(group, n_groups, bottom)
    values = _episode_values(steps, estimator, weighted)
    return (
        _group_sums(group, n_groups, values),
        _group_sums(group, n_groups, np.ones(steps.n_episodes)),
    )


def _values(numerator: FloatArray, denominator: FloatArray, counts: FloatArray) -> FloatArray:
    """The estimator on each row of ``counts`` (resamples x groups); a step index no resampled
    episode gives weight to adds 0."""
    top = counts @ numerator
    bottom = counts @ denominator
    ratio = np.divide(top, bottom, out=np.zeros_like(top), where=bottom > 0.0)
    return np.asarray(ratio.sum(axis=1), dtype=np.float64)


def _point(steps: Steps, estimator: str, weighted: _Weighted) -> float:
    if estimator in _SELF_NORMALISED:
        # The grid itself is the only group: no bincount needed.
        columns = _ratio_columns(steps, estimator, weighted)
        top, bottom = np.sum(columns[0], axis=0), np.sum(columns[1], axis=0)
        ratio = np.divide(top, bottom, out=np.zeros_like(top), where=bottom > 0.0)
        return float(ratio.sum())
    return float(np.mean(_episode_values(steps, estimator, weighted)))


def _bootstrap(
    numerator: FloatArray,
    denominator: FloatArray,
    n_boot: int,
    rng: np.random.Generator,
    confidence: float,
) -> tuple[float, float]:
    """The expanded percentile interval over ``n_boot`` resamples of the groups, with
    replacement."""
    n_groups = numerator.shape[0]
    probabilities = np.full(n_groups, 1.0 / n_groups)
    block = max(1, _BLOCK // n_groups)
    out = np.empty(n_boot)
    for start in range(0, n_boot, block):
        size = min(block, n_boot - start)
        counts = rng.multinomial(n_groups, probabilities, size=size).astype(np.float64)
        out[start : start + size] = _values(numerator, denominator, counts)
    level = expanded_level(confidence, n_groups)
    low, high = np.quantile(out, [1.0 - level, level])
    return float(low), float(high)


def _t_quantile(p: float, df: int) -> float:
    """Student's t quantile, p in (0.5, 1): bisection on the exact distribution function for
    few degrees of freedom (Abramowitz & Stegun 26.7.3-4), the Cornish-Fisher expansion
    (26.7.5, exact to 5 digits there) beyond 30."""
    if df > 30:
        z = NormalDist().inv_cdf(p)
        terms = (
            (z**3 + z) / 4.0,
            (5 * z**5 + 16 * z**3 + 3 * z) / 96.0,
            (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384.0,
            (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / 92160.0,
        )
        return z + sum(term / float(df) ** (k + 1) for k, term in enumerate(terms))

    def inside(t: float) -> float:  # P(|T| <= t)
        theta = math.atan(t / math.sqrt(df))
        c2 = math.cos(theta) ** 2
        total = term = 1.0
        if df % 2 == 0:
            for k in range(1, df // 2):
                term *= c2 * (2 * k - 1) / (2 * k)
                total += term
            return math.sin(theta) * total
        if df == 1:
            return 2.0 * theta / math.pi
        for k in range(1, (df - 1) // 2):
            term *= c2 * (2 * k) / (2 * k + 1)
            total += term
        return 2.0 / math.pi * (theta + math.sin(theta) * math.cos(theta) * total)

    low, high = 0.0, 1.0
    while inside(high) < 2.0 * p - 1.0:
        high *= 2.0
    for _ in range(100):
        middle = (low + high) / 2.0
        if inside(middle) < 2.0 * p - 1.0:
            low = middle
        else:
            high = middle
    return (low + high) / 2.0


def expanded_level(confidence: float, n: int) -> float:
    """The upper quantile level of Hesterberg's (2015) expanded percentile interval: the level
    whose normal quantile is sqrt(n / (n - 1)) times Student's t quantile on n - 1 degrees of
    freedom, widening the percentile interval for few resampled units."""
    if n < 2:
        return (1.0 + confidence) / 2.0
    t = _t_quantile((1.0 + confidence) / 2.0, n - 1)
    return NormalDist().cdf(math.sqrt(n / (n - 1)) * t)


def _bernstein(values: FloatArray, width: float, confidence: float) -> tuple[float, float]:
    """Maurer & Pontil's (2009) empirical Bernstein bound, two-sided (delta / 2 each side), for
    independent values lying in a range of ``width``."""
    n = values.size
    log_term = math.log(4.0 / (1.0 - confidence))
    variance = float(np.var(values, ddof=1))
    half = math.sqrt(2.0 * variance * log_term / n) + 7.0 * width * log_term / (3.0 * (n - 1))
    mean = float(np.mean(values))
    return mean - half, mean + half


def _value_bounds(
    steps: Steps, estimator: str, clip: float, reward_range: tuple[float, float]
) -> tuple[float, float]:
    """The range an episode's pdis or dr value must lie in (see the module's docstring)."""
    lo, hi = float(reward_range[0]), float(reward_range[1])
    low, high = clip * min(lo, 0.0), clip * max(hi, 0.0)
    if estimator != "dr":
        return low, high
    model = np.concatenate((steps.q_hat, steps.v_hat, [lo, hi]))
    m_lo, m_hi = float(model.min()), float(model.max())
    term_lo, term_hi = clip * min(m_lo, 0.0), clip * max(m_hi, 0.0)
    longest = int(steps.lengths.max())
    # v_hat at the first step (weight 1), weight x v_hat at the T - 1 later ones, and
    # -weight x q_hat at all T steps.
    low += m_lo + (longest - 1) * term_lo - longest * term_hi
    high += m_hi + (longest - 1) * term_hi - longest * term_lo
    return low, high


def _cut(
    bounds: tuple[float, float], reward_range: tuple[float, float] | None
) -> tuple[float, float]:
    if reward_range is None:
        return bounds
    lo, hi = float(reward_range[0]), float(reward_range[1])
    return min(max(bounds[0], lo), hi), min(max(bounds[1], lo), hi)


def _groups(steps: Steps) -> tuple[IntArray, int, bool]:
    """The resampling units: people, or episodes when there are fewer than MIN_CLUSTERS people."""
    labels, group = np.unique(steps.cluster, return_inverse=True)
    if labels.size >= MIN_CLUSTERS:
        return group.astype(np.int64), int(labels.size), True
    return np.arange(steps.n_episodes, dtype=np.int64), steps.n_episodes, False


def _not_enough(n_episodes: int, ess: float, min_episodes: int, min_ess: float) -> str:
    if n_episodes >= min_episodes and ess >= min_ess:
        return ""
    needs = f"needs {min_episodes} episodes"
    if min_ess > 0:
        needs += f" and an effective size of {min_ess:g}"
    return f"not enough evidence: {n_episodes} episodes, effective size {ess:.1f} ({needs})"


def _weight_mean(steps: Steps) -> tuple[float, float]:
    """The mean of the episodes' final weights, unclipped, and its standard error (episodes as
    independent: the check below wants a gross departure, not a fine one)."""
    log_ratio = np.full(steps.n_steps, -np.inf)
    np.log(steps.target, out=log_ratio, where=steps.target > 0.0)
    log_ratio -= np.log(steps.logged)
    final = np.exp(np.minimum(np.add.reduceat(log_ratio, steps.offsets[:-1]), 700.0))
    n = final.size
    se = float(np.std(final, ddof=1) / math.sqrt(n)) if n > 1 else math.inf
    return float(np.mean(final)), se


def unseen_margins(
    steps: Steps, estimator: str, value: float, weight_mean: float
) -> tuple[float, float]:
    """How far an interval around ``value`` reaches below and above for what the logs do not
    show (see "What the logs do not show" in the module's docstring): the unseen share
    u = 1 - ``weight_mean`` (0 when the weights average 1 or more) of the candidate's episodes
    may return anything from the lowest to the highest return the logs show (0 included).
    ``wpdis`` spreads that share over what the logs show (``wdr``, and ``dr`` with a model, over
    what the model says), so its value moves by u x (return - value); ``pdis`` (and ``dr``
    without a model) counts it as earning 0, so theirs by u x return."""
    unseen = min(max(1.0 - weight_mean, 0.0), 1.0) if math.isfinite(weight_mean) else 1.0
    if unseen == 0.0 or steps.n_episodes == 0:
        return 0.0, 0.0
    returns = steps.returns()
    lowest, highest = min(0.0, float(np.min(returns))), max(0.0, float(np.max(returns)))
    modelled = estimator == "dr" and bool(np.any(steps.q_hat) or np.any(steps.v_hat))
    if estimator in _SELF_NORMALISED or modelled:
        return unseen * max(value - lowest, 0.0), unseen * max(highest - value, 0.0)
    return unseen * -lowest, unseen * highest


def _unsupported(share: float) -> str:
    """The reason to give no value when the candidate puts more than UNSUPPORTED_LIMIT of its
    probability, on average over the logged steps, on actions the logger never takes."""
    if share <= UNSUPPORTED_LIMIT:
        return ""
    return (
        "not enough evidence: this learner would often do what the logs never show "
        f"({share:.0%} of its choices, on average, are actions the robots never take there)"
    )


def _unrepresented(weight_mean: float, weight_se: float) -> str:
    """The reason to give no value when the weights' mean plus twice its standard error is below
    1 - WEIGHT_TOLERANCE; "" otherwise."""
    if weight_mean + 2.0 * weight_se >= 1.0 - WEIGHT_TOLERANCE:
        return ""
    return (
        "not enough evidence: the logs rarely show what this learner would do (its importance "
        f"weights average {weight_mean:.2f}, where logs that show it average 1)"
    )


def _implausible(steps: Steps, estimator: str) -> str:
    """The reason to give no dr or wdr value when the candidate's model, on average over the
    logged episodes' first steps, expects a return outside the range of those the logs show
    (0 included): its values are beliefs (R-MAX's, for what it has not tried, its optimistic
    bound), and an estimate leaning on them would be no better."""
    if estimator not in MODEL_ESTIMATORS or steps.n_episodes == 0:
        return ""
    # Each episode's first step the candidate decides: a step forced on every learner (the
    # person chose it) carries logged = target = 1 and no model value, and would pull the mean
    # to 0.
    forced = (steps.logged == 1.0) & (steps.target == 1.0) & (steps.q_hat == 0) & (steps.v_hat == 0)
    episode = np.repeat(np.arange(steps.n_episodes), steps.lengths)
    rows = np.flatnonzero(~forced)
    if rows.size == 0:
        return ""
    _, first = np.unique(episode[rows], return_index=True)
    returns = steps.returns()
    lowest, highest = min(0.0, float(np.min(returns))), max(0.0, float(np.max(returns)))
    expected = float(np.mean(steps.v_hat[rows[first]]))
    if lowest <= expected <= highest:
        return ""
    return (
        "not enough evidence: this learner's own model expects "
        f"{expected:.2f} per encounter, beyond anything the logs show ({lowest:.2f} to "
        f"{highest:.2f}); it cannot speak for what they do not show (try wpdis)"
    )


def resampled(steps: Steps, estimator: str, clip: float, counts: FloatArray) -> FloatArray:
    """The estimator on resamples of the people: ``counts[b, g]`` copies of the g-th person (in
    the order of ``np.unique(steps.cluster)``) in resample b. The bootstrap's computation, for
    callers that resample two estimates with the same people (a difference between learners)."""
    _check_estimator(estimator)
    _check_clip(clip)
    labels, group = np.unique(steps.cluster, return_inverse=True)
    weighted = _weighted(steps, clip)
    numerator, denominator = _statistics(
        steps, estimator, weighted, group.astype(np.int64), int(labels.size)
    )
    return _values(numerator, denominator, np.asarray(counts, dtype=np.float64))


# ---------------------------------------------------------------------------------------------
# The public functions


def point(steps: Steps, estimator: str = DEFAULT_ESTIMATOR, *, clip: float = DEFAULT_CLIP) -> float:
    """The estimate alone: no interval, no evidence check. Raises ValueError on logs without
    episodes."""
    _check_estimator(estimator)
    _check_clip(clip)
    if steps.n_episodes == 0:
        raise ValueError("no episodes: nothing to estimate.")
    return _point(steps, estimator, _weighted(steps, clip))


def estimate(
    steps: Steps,
    estimator: str = DEFAULT_ESTIMATOR,
    *,
    clip: float = DEFAULT_CLIP,
    interval: str = "bootstrap",
    confidence: float = 0.95,
    n_boot: int = 1000,
    rng: np.random.Generator | None = None,
    reward_range: tuple[float, float] | None = None,
    min_episodes: int = DEFAULT_MIN_EPISODES,
    min_ess: float = DEFAULT_MIN_ESS,
) -> Estimate:
    """The candidate's value per episode with a ``confidence`` interval, or "not enough
    evidence". ``interval="bernstein"`` needs ``reward_range`` (see the module's docstring);
    given with either method, ``reward_range`` is checked against the logs and bounds the
    interval. ``rng`` None: a fixed seed, so the same logs give the same interval."""
    _check_estimator(estimator)
    _check_clip(clip)
    _check_interval(interval, confidence, n_boot)
    _check_minimums(min_episodes, min_ess)
    if interval == "bernstein" and reward_range is None:
        raise ValueError("the bernstein interval needs reward_range=(lo, hi).")
    _check_range(steps, reward_range)
    generator = _make_rng(rng)

    n_episodes, n_clusters = steps.n_episodes, steps.n_clusters
    if n_episodes == 0:
        return Estimate(
            estimator=estimator,
            value=None,
            interval=None,
            n_episodes=0,
            n_clusters=0,
            ess=0.0,
            clip=float(clip),
            clipped_share=0.0,
            unsupported_mean=0.0,
            unsupported_max=0.0,
            enough=False,
            reason=_not_enough(0, 0.0, min_episodes, min_ess),
        )
    weighted = _weighted(steps, clip)
    ess = _ess(weighted.final)
    weight_mean, weight_se = _weight_mean(steps)
    unsupported = float(np.mean(steps.unsupported))
    reason = (
        _not_enough(n_episodes, ess, min_episodes, min_ess)
        or _unsupported(unsupported)
        or _unrepresented(weight_mean, weight_se)
        or _implausible(steps, estimator)
    )
    value: float | None = None
    bounds: Interval | None = None
    if not reason:
        value = _point(steps, estimator, weighted)
        if interval == "bootstrap":
            group, n_groups, by_person = _groups(steps)
            numerator, denominator = _statistics(steps, estimator, weighted, group, n_groups)
            low, high = _bootstrap(numerator, denominator, n_boot, generator, confidence)
            method = "bootstrap" if by_person else "bootstrap-episodes"
        else:
            assert reward_range is not None
            kind = "dr" if estimator in MODEL_ESTIMATORS else "pdis"
            lowest, highest = _value_bounds(steps, kind, clip, reward_range)
            values = _episode_values(steps, kind, weighted)
            low, high = _bernstein(values, highest - lowest, confidence)
            method = "bernstein" if kind == estimator else f"bernstein-{kind}"
        # The bernstein interval of wpdis is the pdis one, of wdr the dr one (their margins too).
        kind = estimator if method in ("bootstrap", "bootstrap-episodes") else kind
        below, above = unseen_margins(steps, kind, value, weight_mean)
        low, high = _cut((low - below, high + above), reward_range)
        bounds = Interval(low=low, high=high, method=method, confidence=float(confidence))
    return Estimate(
        estimator=estimator,
        value=value,
        interval=bounds,
        n_episodes=n_episodes,
        n_clusters=n_clusters,
        ess=ess,
        clip=float(clip),
        clipped_share=weighted.clipped_share,
        unsupported_mean=unsupported,
        unsupported_max=float(np.max(steps.unsupported)),
        enough=not reason,
        reason=reason,
        weight_mean=weight_mean,
    )


def per_cluster(
    steps: Steps,
    estimator: str = DEFAULT_ESTIMATOR,
    *,
    clip: float = DEFAULT_CLIP,
    interval: str = "bootstrap",
    confidence: float = 0.95,
    n_boot: int = 1000,
    rng: np.random.Generator | None = None,
    reward_range: tuple[float, float] | None = None,
    min_episodes: int = DEFAULT_MIN_EPISODES,
    min_ess: float = DEFAULT_MIN_ESS,
) -> list[Estimate]:
    """One estimate per person, in the order of ``np.unique(steps.cluster)``, each from that
    person's episodes alone (a bootstrap resamples them: ``bootstrap-episodes``)."""
    _check_estimator(estimator)
    _check_clip(clip)
    _check_interval(interval, confidence, n_boot)
    _check_minimums(min_episodes, min_ess)
    generator = _make_rng(rng)
    return [
        estimate(
            steps.select(steps.cluster == label),
            estimator,
            clip=clip,
            interval=interval,
            confidence=confidence,
            n_boot=n_boot,
            rng=generator,
            reward_range=reward_range,
            min_episodes=min_episodes,
            min_ess=min_ess,
        )
        for label in np.unique(steps.cluster)
    ]


def on_policy(
    steps: Steps,
    *,
    interval: str = "bootstrap",
    confidence: float = 0.95,
    n_boot: int = 1000,
    rng: np.random.Generator | None = None,
    reward_range: tuple[float, float] | None = None,
    min_episodes: int = DEFAULT_MIN_EPISODES,
) -> Estimate:
    """The logging policy's own value: the mean episode return (estimator ``logged``; every
    weight is 1, so ``ess`` is the number of episodes and the clip, reported as 1, cuts
    nothing). The intervals are built as in :func:`estimate`; the bernstein one uses the
    return's range, ``reward_range``, itself."""
    _check_interval(interval, confidence, n_boot)
    _check_minimums(min_episodes, 0.0)
    if interval == "bernstein" and reward_range is None:
        raise ValueError("the bernstein interval needs reward_range=(lo, hi).")
    _check_range(steps, reward_range)
    generator = _make_rng(rng)
    n_episodes = steps.n_episodes
    reason = _not_enough(n_episodes, float(n_episodes), min_episodes, 0.0)
    value: float | None = None
    bounds: Interval | None = None
    if not reason:
        returns = steps.returns()
        value = float(np.mean(returns))
        if interval == "bootstrap":
            group, n_groups, by_person = _groups(steps)
            numerator = _group_sums(group, n_groups, returns)
            denominator = _group_sums(group, n_groups, np.ones(n_episodes))
            low, high = _bootstrap(numerator, denominator, n_boot, generator, confidence)
            method = "bootstrap" if by_person else "bootstrap-episodes"
        else:
            assert reward_range is not None
            width = float(reward_range[1]) - float(reward_range[0])
            low, high = _bernstein(returns, width, confidence)
            method = "bernstein"
        low, high = _cut((low, high), reward_range)
        bounds = Interval(low=low, high=high, method=method, confidence=float(confidence))
    return Estimate(
        estimator="logged",
        value=value,
        interval=bounds,
        n_episodes=n_episodes,
        n_clusters=steps.n_clusters,
        ess=float(n_episodes),
        clip=1.0,
        clipped_share=0.0,
        unsupported_mean=0.0,
        unsupported_max=0.0,
        enough=not reason,
        reason=reason,
    )
