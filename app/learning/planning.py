"""Value iteration over one context's estimated model, and the action-distribution helpers."""

from __future__ import annotations

import numpy as np

from .space import NegotiationSpace
from .types import FloatArray

__all__ = ["draw", "gibbs", "greedy", "state_values", "value_iteration"]


def state_values(space: NegotiationSpace, q: FloatArray) -> FloatArray:
    """V(s) = max over the state's actions, with V(END) = 0 appended.

    q: (..., P) -> (..., L + 1).
    """
    v = np.maximum.reduceat(q, space.state_start, axis=-1)
    pad = np.zeros((*v.shape[:-1], 1), dtype=np.float64)
    return np.concatenate([v, pad], axis=-1)


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
) -> FloatArray:
    """Q(s,a) <- R(s,a) + gamma * sum_j T(s,a,j) * V(succ(s,a,j)), until max |dQ| < tol.

    reward: (..., P); transition: (..., P, M), rows sum to 1 over ``space.succ`` columns (padding
    columns carry 0); fixed: (..., P) bool, pairs pinned at ``fixed_value`` (R-MAX's unknown
    pairs). Leading dimensions batch independent models (posterior samples). Returns (..., P).
    """
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
    cdf = np.cumsum(probabilities)
    u = rng.random() * cdf[-1]
    index = int(np.searchsorted(cdf, u, side="right"))
    return min(index, int(probabilities.shape[0]) - 1)
