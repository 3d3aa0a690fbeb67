"""The what-if ranking judges each fleet against its own family's expectation: arms that swap
places between families give a row per direction, and families whose arms are apart only by
the noise of a few fleets are not ranked."""

from __future__ import annotations

from typing import Any

import pytest

from app.experiments.whatif import (
    RANK_GAP,
    TrialResult,
    _ranking,
    check_targets,
    found_key,
)
from app.learning.evaluation import Method
from app.learning.offpolicy import ESTIMATORS

K = 100
LOGGER = Method("Logger", "hri")
CANDIDATE = Method("Cand", "dts")


def trial(family: str, seed: int, truth: tuple[float, float], est: tuple[Any, Any]) -> TrialResult:
    """One fleet: the logger's and the candidate's truths, and their estimates (None: not
    enough evidence), the same for every estimator."""
    found: dict[str, dict[int, dict[str, Any]]] = {}
    for label, kinds, value in (
        (LOGGER.label, ("logged",), est[0]),
        (CANDIDATE.label, ESTIMATORS, est[1]),
    ):
        for kind in kinds:
            found[found_key(label, kind, "bootstrap")] = {
                K: {"value": value, "enough": value is not None}
            }
    return TrialResult(
        family, seed, {LOGGER.label: {K: truth[0]}, CANDIDATE.label: {K: truth[1]}}, found
    )


def rows(results: list[TrialResult]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = _ranking(results, LOGGER, [CANDIDATE], K)["pairs"]
    return out


def summary_of(results: list[TrialResult]) -> dict[str, Any]:
    """What check_targets reads: the ranking alone (no settings, so no coverage targets)."""
    return {
        "ranking": _ranking(results, LOGGER, [CANDIDATE], K),
        "sizes": [],
        "cells": [],
        "default_estimator": ESTIMATORS[0],
    }


def test_arms_that_swap_places_give_a_row_per_direction() -> None:
    results = [
        # the candidate is better for "a" people: the estimates say so in 2 of 3 fleets
        trial("a", 0, (1.0, 1.5), (1.0, 1.6)),
        trial("a", 1, (1.1, 1.6), (1.0, 0.9)),
        trial("a", 2, (0.9, 1.4), (1.0, 1.2)),
        # and worse for "b" people, one fleet not answered
        trial("b", 3, (2.0, 1.5), (2.0, 1.0)),
        trial("b", 4, (2.1, 1.6), (2.0, None)),
    ]
    found = {(r["better"], r["worse"]): r for r in rows(results)}
    assert set(found) == {("Cand", "Logger"), ("Logger", "Cand")}
    up, down = found["Cand", "Logger"], found["Logger", "Cand"]
    assert [f["family"] for f in up["families"]] == ["a"]
    assert [f["family"] for f in down["families"]] == ["b"]
    assert up["gap"] == pytest.approx(0.5)
    assert down["gap"] == pytest.approx(0.5)
    for estimator in ESTIMATORS:
        assert up[estimator] == {
            "trials": 3,
            "silent": 0,
            "ordered": pytest.approx(2 / 3, abs=1e-4),
        }
        assert down[estimator] == {"trials": 1, "silent": 1, "ordered": 1.0}
    assert up["truth"] == {"trials": 3, "ordered": 1.0}
    # the pooled gap would be small (+0.1 over the five fleets), the families' are not
    targets = check_targets(summary_of(results))
    assert any("Logger below Cand" in t["target"] and ", for a)" in t["target"] for t in targets)
    assert any("Cand below Logger" in t["target"] and ", for b)" in t["target"] for t in targets)


def test_a_family_apart_only_by_noise_is_not_ranked() -> None:
    # mean gap 0.2 >= RANK_GAP, but the fleets disagree wildly: twice its standard error is more
    noisy = [trial("n", s, (1.0, 1.0 + g), (1.0, 1.0)) for s, g in enumerate((1.5, -1.2, 0.3))]
    assert sum((1.0 + g) - 1.0 for g in (1.5, -1.2, 0.3)) / 3 >= RANK_GAP
    assert rows(noisy) == []
    # the same mean gap, shown by every fleet: ranked
    steady = [trial("s", s, (1.0, 1.0 + g), (1.0, 1.0)) for s, g in enumerate((0.2, 0.19, 0.21))]
    assert [r["better"] for r in rows(steady)] == ["Cand"]


def test_arms_apart_in_every_family_name_no_family() -> None:
    results = [trial(f, s, (1.0, 0.5), (1.0, 0.4)) for s, f in enumerate(("a", "b", "a", "b"))]
    (row,) = rows(results)
    assert (row["better"], row["worse"]) == ("Logger", "Cand")
    (target,) = check_targets(summary_of(results))
    assert ", for" not in target["target"]
    assert target["met"]
    assert target["value"] == 1.0
