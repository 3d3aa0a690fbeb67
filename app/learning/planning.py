"""Value iteration over one context's estimated model, and the action-distribution helpers."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .space import NegotiationSpace
from .types import FloatArray, IntArray

__all__ = [
    "draw",
    "gibbs",
    "greedy",
    "pair_levels",
    "space_levels",
    "state_values",
    "sweep_value_iteration",
    "value_iteration",
]

# Rewards (and a pinned value) within this bound keep every value of the sweeps finite: in an
# acyclic space a value adds up at most one reward per level.
_FINITE_BOUND = 1e300


def state_values(space: NegotiationSpace, q: FloatArray) -> FloatArray:
    """V(s) = max over the state's actions, with V(END) = 0 appended.

    q: (..., P) -> (..., L + 1).
    """
    v = np.maximum.reduceat(q, space.state_start, axis=-1)
    pad = np.zeros((*v.shape[:-1], 1), dtype=np.float64)
    return np.concatenate([v, pad], axis=-1)


def pair_levels(succ: IntArray, state_start: IntArray, n_states: int) -> IntArray | None:
    """Each pair's level in an acyclic negotiation; None when its states form a cycle (or the
    layout is not one of pairs grouped by state in state order, at least one per state).

    succ: (P, M) successor states, ``n_states`` standing for END; state_start: (L,) first pair
    of each state. A pair that can only end the episode has level 0; any other has one more
    than the highest level among the pairs of its successors, so its Q depends on pairs of
    lower levels only, and value iteration leaves it unchanged from sweep ``level`` on.
    """
    L = n_states
    if (
        len(state_start) != L
        or L == 0
        or int(state_start[0]) != 0
        or np.any(np.diff(state_start) <= 0)
        or int(state_start[-1]) >= succ.shape[0]
    ):
        return None
    # A state's height is one more than the highest level of its pairs (END's is 0). Relaxed
    # from 0, the heights settle after at most L rounds when there is no cycle, and keep
    # growing when there is one.
    height = np.zeros(L + 1, dtype=np.int64)
    for _ in range(L + 1):
        level: IntArray = height[succ].max(axis=1)
        settled = height.copy()
        settled[:L] = 1 + np.maximum.reduceat(level, state_start)
        if np.array_equal(settled, height):
            return level
        height = settled
    return None


@dataclass(frozen=True)
class _Sweeps:
    """The pairs each sweep of value iteration can still change in an acyclic space.

    level: (P,) :func:`pair_levels`; depth: the highest level. ``pairs[lo, hi]``: the pairs of
    level lo..hi (a slice when they are contiguous), with ``succ[lo, hi]`` their successors.
    """

    level: IntArray
    depth: int
    pairs: dict[tuple[int, int], slice | IntArray]
    succ: dict[tuple[int, int], IntArray]


@functools.lru_cache(maxsize=32)
def _sweeps(space: NegotiationSpace) -> _Sweeps | None:
    """The sweep plan of a space, or None when it has a cycle (no mission's space has one:
    every action leads to a later state or to END)."""
    level = pair_levels(space.succ, space.state_start, space.n_states)
    if level is None:
        return None
    level.setflags(write=False)
    depth = int(level.max())
    pairs: dict[tuple[int, int], slice | IntArray] = {}
    succ: dict[tuple[int, int], IntArray] = {}
    for lo in range(1, depth + 1):
        for hi in range(lo, depth + 1):
            rows = np.flatnonzero((level >= lo) & (level <= hi))
            contiguous = rows[-1] - rows[0] + 1 == len(rows)
            pairs[lo, hi] = slice(int(rows[0]), int(rows[-1]) + 1) if contiguous else rows
            succ[lo, hi] = space.succ[rows]
    return _Sweeps(level, depth, pairs, succ)


def space_levels(space: NegotiationSpace) -> IntArray | None:
    """The (read-only) :func:`pair_levels` of a space's pairs; None if it has a cycle."""
    plan = _sweeps(space)
    return None if plan is None else plan.level


def value_iteration(
    space: NegotiationSpace,
    reward: FloatArray,
    transition: FloatArray,
    *,
    gamma: float,
    tol: float,
    max_sweeps: int,
    fixed: np.ndarray | None = None,
    fixed_value: float = 0.0,
    level: int | None = None,
) -> FloatArray:
    """Q(s,a) <- R(s,a) + gamma * sum_j T(s,a,j) * V(succ(s,a,j)), until max |dQ| < tol.

    reward: (..., P); transition: (..., P, M), rows sum to 1 over ``space.succ`` columns (padding
    columns carry 0); fixed: (..., P) bool, pairs pinned at ``fixed_value`` (R-MAX's unknown
    pairs). Leading dimensions batch independent models (posterior samples). Returns (..., P).
    level: only the pairs of this level and below (:func:`space_levels`) are wanted; the others
    may be left unfinished (None: every pair).

    The result is :func:`sweep_value_iteration`'s for less work, bit for bit (but that a reward
    of -0.0 may leave a zero of the other sign, which compares equal). In an acyclic space
    (every mission's) sweep i can only change the pairs of level i and above: the others depend
    on nothing that still changes, so the full sweep gives them their value again. Each sweep
    here updates only those pairs, by the same numpy operations on the same values, and
    measures the change over them (the others' change is 0), so it stops after the same sweep
    with the same values. After sweep i the pairs of level i and below are final, so the last
    sweep needed updates only the wanted pairs and measures nothing, and the sweeps after it
    are skipped (past the highest level they find no change). This needs every value finite:
    rewards or a pinned value beyond +-1e300 (where an overflow's infinite change would never
    stop the full sweeps), a cyclic space and batch dimensions that differ between ``reward``
    (or ``fixed``) and ``transition`` take the full sweeps.
    """
    plan = _sweeps(space)
    q = np.where(fixed, fixed_value, reward) if fixed is not None else reward.copy()
    if (
        plan is None
        or q.shape[:-1] != transition.shape[:-2]
        or (fixed is not None and not abs(fixed_value) <= _FINITE_BOUND)
        or not float(np.abs(reward).max(initial=0.0)) <= _FINITE_BOUND
    ):
        return sweep_value_iteration(
            space,
            reward,
            transition,
            gamma=gamma,
            tol=tol,
            max_sweeps=max_sweeps,
            fixed=fixed,
            fixed_value=fixed_value,
        )
    # V is kept state-major, (L + 1, ...), V(END) = 0: its successor rows are then one take,
    # and seen batch-major they have the strides of the full sweeps' ``v[..., succ]``, so the
    # einsum adds up each pair's terms in the same order.
    batch = q.ndim - 1
    v = np.zeros((space.n_states + 1, *q.shape[:-1]), dtype=np.float64)
    head_axes, batch_major = _AXES[batch] if batch < len(_AXES) else _axes(batch)
    head = v[:-1].transpose(head_axes)
    top = plan.depth if level is None else max(0, min(level, plan.depth))
    last = min(top, max_sweeps)
    for i in range(1, last + 1):
        key = (i, plan.depth if i < last else top)
        pairs = plan.pairs[key]
        np.maximum.reduceat(q, space.state_start, axis=-1, out=head)
        nxt = v.take(plan.succ[key], axis=0).transpose(batch_major)  # (..., n, M)
        new = np.einsum("...pm,...pm->...p", transition[..., pairs, :], nxt)
        new *= gamma
        new += reward[..., pairs]  # reward + gamma * (T . V), as the full sweeps add it
        if fixed is not None:
            new = np.where(fixed[..., pairs], fixed_value, new)
        if i == last:  # the wanted pairs are final now, or the sweeps run out
            q[..., pairs] = new
            break
        change = new - q[..., pairs]
        q[..., pairs] = new
        # max |change| < tol, every value being finite
        if change.max() < tol and change.min() > -tol:
            break
    return q


def _axes(batch: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Transpositions for ``batch`` leading dimensions: state-major to batch-major V, and
    (n, M, ...) successor values to (..., n, M)."""
    return (*range(1, batch + 1), 0), (*range(2, batch + 2), 0, 1)


_AXES = tuple(_axes(batch) for batch in range(4))


def sweep_value_iteration(
    space: NegotiationSpace,
    reward: FloatArray,
    transition: FloatArray,
    *,
    gamma: float,
    tol: float,
    max_sweeps: int,
    fixed: np.ndarray | None = None,
    fixed_value: float = 0.0,
) -> FloatArray:
    """:func:`value_iteration` by full sweeps over every pair, for any space (the reference
    that :func:`value_iteration` reproduces)."""
    q = np.where(fixed, fixed_value, reward) if fixed is not None else reward.copy()
    for _ in range(max_sweeps):
        v = state_values(space, q)
        nxt = v[..., space.succ]  # (..., P, M)
        new = reward + gamma * np.einsum("...pm,...pm->...p", transition, nxt)
        if fixed is not None:
            new = np.where(fixed, fixed_value, new)
        delta = float(np.max(np.abs(new - q)))
        q = new
        if delta < tol:
            break
    return q


def gibbs(pref: FloatArray, tau: float) -> FloatArray:
    """P(a) = exp(pref(a) / tau) / sum_b exp(pref(b) / tau), by log-sum-exp; argmax when tau ~ 0."""
    if tau <= 1e-12:
        return greedy(pref)
    z = (pref - pref.max()) / tau
    e = np.exp(z)
    out: FloatArray = e / e.sum()
    return out


def greedy(values: FloatArray, atol: float = 1e-12) -> FloatArray:
    """Uniform over the maximal entries (a seeded tie-break once drawn)."""
    best = values >= values.max() - atol
    out: FloatArray = best / best.sum()
    return out


def draw(probabilities: FloatArray, rng: np.random.Generator) -> int:
    """Index drawn from ``probabilities`` with one uniform draw from ``rng``."""
    if probabilities.shape[0] == 1:
        return 0
    cdf = probabilities.cumsum()
    u = rng.random() * cdf[-1]
    index = int(cdf.searchsorted(u, side="right"))
    return min(index, int(probabilities.shape[0]) - 1)
