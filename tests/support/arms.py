"""A rollout salt that splits a test's people evenly.

A rollout's salt is random, so with a dozen people a 50 % rollout leaves one arm with too few
of them for a test to compare, now and then. Tests that need both arms filled pin the salt to
the first one (searched, not written down) that splits each of the given groups of people
within one of its share."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import pytest

from app.services import rollouts


def even_salt(groups: Iterable[Sequence[str]], share: float = 0.5) -> str:
    """The first salt of a fixed sequence under which each group's candidates number
    ``round(len(group) * share)`` give or take one."""
    groups = [list(g) for g in groups]
    for i in range(100_000):
        salt = f"{i:016x}"
        if all(
            abs(sum(rollouts.hash_place(salt, u) < share for u in g) - round(len(g) * share)) <= 1
            for g in groups
        ):
            return salt
    raise AssertionError("no salt splits these people evenly")  # pragma: no cover


def pin_even_salt(
    monkeypatch: pytest.MonkeyPatch, groups: Iterable[Sequence[str]], share: float = 0.5
) -> str:
    """Make every rollout started in this test use :func:`even_salt` of ``groups``."""
    salt = even_salt(groups, share)
    monkeypatch.setattr(rollouts, "new_salt", lambda: salt)
    return salt
