"""A fleet's prior: what a newcomer's learner starts from, built from aggregates of the
learners of the fleet's other people (docs/method.md §16).

A home's residents share most routines; a new resident need not start from nothing. The prior is
a learner of the newcomer's algorithm whose tables hold, per (context, pair), an **average over
contributors** of what each contributor's learner learned there, at a fixed small weight:

- every contributor counts once, however much it was served: its evidence on a pair is first
  turned into rates (the share of each outcome, the mean reward), and the rates are averaged;
- a pair enters the prior only when at least ``min_support`` contributors have evidence on it,
  so no pair's figures are one person's; elsewhere the newcomer starts as a fresh learner does;
- the averaged rates enter with ``strength`` pseudo-samples per pair (scaled by the share of
  contributors that have evidence on it), so a few of the newcomer's own answers outweigh them.

Nothing else is taken: no counts of episodes, no times, no open episodes, no staff corrections.

Which tables are averaged, per algorithm (:data:`PRIOR_TABLES`):

- ``counts``: a successor-count table (C, P, ..., M) and ``sums``, its reward-sum table
  (C, P, ...): the rates are the shares of the counts (over all but the pair axes) and the mean
  reward of each sum cell; ``derived`` tables are the counts summed over their last axis;
- ``values``: a value table (C, P), averaged where the contributors have visited the pair,
  and never below a fresh learner's initial value (a learner without a posterior, greedy
  once its exploration decays, would never try again a pair that others found bad);
- ``pooled``: a (count, reward sum) pair of one number each, averaged as a rate;
- ``routines`` (``dts-routine``): the routine per context: the newcomer starts trusting the
  routine that nearly all the contributors holding one there trust (:func:`_routines`);
- ``fresh_offers``: the offers' pairs (initiate, pass) start fresh: whether the person wants
  service in a context at all is theirs; what they want where the home agrees is shared.

Pure: the standard library and numpy only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .learners import make_learner
from .learners.base import TabularLearner
from .mission import Mission
from .types import FloatArray

__all__ = [
    "DEFAULT_STRENGTH",
    "FRESH_ONLY",
    "MIN_SUPPORT",
    "PRIOR_TABLES",
    "PriorSpec",
    "population_prior",
]

DEFAULT_STRENGTH = 4.0  # pseudo-samples per pair that every contributor has evidence on
MIN_SUPPORT = 3  # the fewest contributors with evidence on a pair for it to enter the prior
# Learners the service starts fresh even where a fleet's prior is in force: HRI gains at the start
# from it but loses later (after event 100 of a home, docs/method.md §16), its exclusion rule
# keeping too few samples per pair for the prior's to fade.
FRESH_ONLY = frozenset({"hri"})
# A routine the newcomer starts trusting: held and trusted by at least this share of the
# contributors that hold a routine in the context (and by at least min_support of them).
ROUTINE_AGREEMENT = 0.875


@dataclass(frozen=True)
class PriorSpec:
    """Which of an algorithm's tables a prior averages, and how (see the module's docstring)."""

    counts: str | None = None
    sums: str | None = None
    derived: tuple[str, ...] = ()
    values: tuple[str, ...] = ()
    pooled: tuple[str, ...] = ()
    routines: str | None = None
    fresh_offers: bool = False


PRIOR_TABLES: Mapping[str, PriorSpec] = {
    "hri": PriorSpec(counts="ns", sums="rs"),
    "rmax": PriorSpec(counts="ns", sums="r"),
    "dts": PriorSpec(counts="dns", sums="dr", derived=("dn",), pooled=("answered",)),
    "dts-adapt": PriorSpec(counts="dns", sums="dr", derived=("dn",), pooled=("answered",)),
    "dts-routine": PriorSpec(
        counts="dns",
        sums="dr",
        derived=("dn",),
        pooled=("answered",),
        routines="routine",
        fresh_offers=True,
    ),
    "qlearning": PriorSpec(values=("q",)),
}


def population_prior(
    algorithm: str,
    params: Mapping[str, Any] | None,
    mission: Mission,
    contributors: Sequence[TabularLearner[Any]],
    *,
    strength: float = DEFAULT_STRENGTH,
    min_support: int = MIN_SUPPORT,
) -> TabularLearner[Any]:
    """A new learner of ``algorithm`` (with ``params``) for ``mission`` that starts from the
    contributors' averaged tables; a fresh learner when fewer than ``min_support`` contributors
    are given. Contributors of another algorithm or mission are refused (``ValueError``)."""
    if not strength > 0.0 or not np.isfinite(strength):
        raise ValueError(f"strength must be a positive number, got {strength!r}.")
    if min_support < 1:
        raise ValueError(f"min_support must be at least 1, got {min_support!r}.")
    learner = make_learner(algorithm, params, mission)
    for other in contributors:
        if other.algorithm != algorithm:
            raise ValueError(f"a contributor learns with {other.algorithm!r}, not {algorithm!r}.")
        if other.mission.fingerprint != mission.fingerprint:
            raise ValueError("a contributor's learner is laid out for another mission.")
    if len(contributors) < min_support:
        return learner
    spec = PRIOR_TABLES[algorithm]
    if spec.counts is not None:
        counts, sums = _counts_and_sums(
            [getattr(o, spec.counts) for o in contributors],
            [getattr(o, spec.sums) for o in contributors] if spec.sums else None,
            strength=strength,
            min_support=min_support,
        )
        if spec.fresh_offers:
            # Whether to offer is the newcomer's own: its offers' pairs start fresh.
            root = list(learner.space.root_actions)
            counts[:, root] = 0.0
            if sums is not None:
                sums[:, root] = 0.0
        getattr(learner, spec.counts)[...] = counts
        if spec.sums is not None and sums is not None:
            getattr(learner, spec.sums)[...] = sums
        for name in spec.derived:
            getattr(learner, name)[...] = counts.sum(axis=-1)
    for name in spec.values:
        table = getattr(learner, name)
        table[...] = _values(
            [getattr(o, name) for o in contributors],
            [o.visits for o in contributors],
            table,
            min_support=min_support,
        )
    for name in spec.pooled:
        getattr(learner, name)[...] = _pooled(
            [getattr(o, name) for o in contributors], strength=strength, min_support=min_support
        )
    if spec.routines is not None:
        getattr(learner, spec.routines)[...] = _routines(
            [getattr(o, spec.routines) for o in contributors], min_support=min_support
        )
    learner._cache.clear()
    return learner


def _routines(tables: Sequence[FloatArray], *, min_support: int) -> FloatArray:
    """(C, P) routine tables (``dts-routine``: one non-zero entry per context at most, > 0
    when trusted): the newcomer starts trusting, as if taken once, the routine that at least
    ``min_support`` contributors trust in a context and at least :data:`ROUTINE_AGREEMENT` of
    the contributors that hold one there; no routine elsewhere."""
    r = np.stack([np.asarray(t, dtype=np.float64) for t in tables])  # (K, C, P)
    trusted = (r > 0.0).sum(axis=0)  # (C, P)
    holding = (r != 0.0).any(axis=2).sum(axis=0)  # (C,)
    agree = (trusted >= min_support) & (trusted >= ROUTINE_AGREEMENT * holding[:, None])
    out = np.zeros(r.shape[1:], dtype=np.float64)
    out[agree] = 1.0
    return out


def _counts_and_sums(
    counts: Sequence[FloatArray],
    sums: Sequence[FloatArray] | None,
    *,
    strength: float,
    min_support: int,
) -> tuple[FloatArray, FloatArray | None]:
    n = np.stack([np.asarray(c, dtype=np.float64) for c in counts])  # (K, C, P, ..., M)
    k, c, p = n.shape[:3]
    flat = n.reshape(k, c, p, -1)
    total = flat.sum(axis=-1)  # (K, C, P)
    has = total > 0.0
    support = has.sum(axis=0)  # (C, P)
    shares = np.divide(flat, total[..., None], out=np.zeros_like(flat), where=has[..., None])
    mean_share = shares.sum(axis=0) / np.maximum(support, 1)[..., None]
    weight = strength * support / k  # pseudo-samples per pair
    weight[support < min_support] = 0.0
    prior_counts = (weight[..., None] * mean_share).reshape(n.shape[1:])
    if sums is None:
        return prior_counts, None
    r = np.stack([np.asarray(s, dtype=np.float64) for s in sums])  # (K, C, P, ...)
    cell = n.sum(axis=-1)  # (K, C, P, ...): the samples under each sum cell
    in_cell = cell > 0.0
    mean_reward = np.divide(r, cell, out=np.zeros_like(r), where=in_cell)
    cell_support = in_cell.sum(axis=0)
    mean_reward = mean_reward.sum(axis=0) / np.maximum(cell_support, 1)
    prior_sums = prior_counts.sum(axis=-1) * mean_reward
    return prior_counts, prior_sums


def _values(
    tables: Sequence[FloatArray],
    visits: Sequence[np.ndarray],
    initial: FloatArray,
    *,
    min_support: int,
) -> FloatArray:
    q = np.stack([np.asarray(t, dtype=np.float64) for t in tables])
    seen = np.stack([np.asarray(v) > 0 for v in visits])
    support = seen.sum(axis=0)
    mean = np.where(seen, q, 0.0).sum(axis=0) / np.maximum(support, 1)
    # Never below a fresh learner's start: a value the contributors found worse than that is
    # their experience of the pair, not the newcomer's, and a learner without a posterior
    # (Q-learning is greedy once its exploration has decayed) would never try it again.
    out: FloatArray = np.where(support >= min_support, np.maximum(mean, initial), initial)
    return out


def _pooled(tables: Sequence[FloatArray], *, strength: float, min_support: int) -> FloatArray:
    """(count, reward sum) pairs: the mean rate at ``strength`` samples."""
    pairs = np.stack([np.asarray(t, dtype=np.float64) for t in tables])  # (K, 2)
    has = pairs[:, 0] > 0.0
    if has.sum() < min_support:
        return np.zeros(2, dtype=np.float64)
    rate = float(np.mean(pairs[has, 1] / pairs[has, 0]))
    weight = strength * float(has.mean())
    return np.asarray([weight, weight * rate], dtype=np.float64)
