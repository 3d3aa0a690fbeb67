"""The changes the service told staff about the simulated people, counted against the changes
their needs really went through.

A simulated person's *true changes* are the contexts whose need the change point replaced (another
service or detail) or ended (nothing wanted there any more); a context that only gains a need is
a new routine to learn, not a change to detect. That is the learning core's rule for its
robustness suite (``app.learning.population.true_changes``), and so is the counting
(``match_contexts``): a true change is caught by the first recorded change in its context whose
deciding episode is at or after the change point; every other recorded change is a false alarm.

The robots play each person's events in order, one episode per event, so the episode a change's
``decided`` names (the person's episode index, from 1) is its event index + 1, and its time slot
and situation name its context in the mission.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from app.learning import Mission, population
from app.learning.population import (
    CAUGHT_TARGET,
    CAUGHT_VISITS,
    EVENTS_PER_MONTH,
    FALSE_ALARMS_TARGET,
    Detection,
    match_contexts,
)

from .simulate import Person

__all__ = [
    "CAUGHT_TARGET_TEXT",
    "FALSE_ALARMS_TARGET_TEXT",
    "Recorded",
    "count_changes",
    "detection_summary",
    "true_person",
]

CAUGHT_TARGET_TEXT = (
    f"≥ {100 * CAUGHT_TARGET:.0f}% of abrupt changes caught within {CAUGHT_VISITS} visits of "
    "the changed context"
)
FALSE_ALARMS_TARGET_TEXT = (
    f"≤ {FALSE_ALARMS_TARGET:g} false alarm per person per {EVENTS_PER_MONTH} events when no "
    "change happens"
)


class _Moment(Protocol):
    @property
    def episode(self) -> int: ...


class Recorded(Protocol):
    """What counting needs of a recorded change (``attune_client.ChangeEvent``)."""

    @property
    def time_slot(self) -> str: ...

    @property
    def situation(self) -> str: ...

    @property
    def decided(self) -> _Moment: ...


def true_person(person: Person) -> population.Person:
    """``person`` as the learning core describes a simulated person: the same needs before and
    after each change point, and the same events."""
    points = np.asarray(person.change_points[1:], dtype=np.int64)
    schedule = np.searchsorted(points, np.arange(person.events), side="right")
    return population.Person(
        profiles=tuple(person.profiles),
        schedule=schedule.astype(np.int64),
        contexts=np.asarray(person.contexts, dtype=np.int64),
        change_at=int(points[0]) if points.size else None,
        change_points=tuple(int(p) for p in points),
    )


def _decided(mission: Mission, recorded: Iterable[Recorded]) -> list[tuple[int, int]]:
    """(event of the deciding episode, context index) of each change, oldest first. A change
    whose names the mission lacks matches no context (-1): it can only be a false alarm."""
    out = []
    for change in recorded:
        try:
            context = mission.context_index(change.time_slot, change.situation)
        except ValueError:
            context = -1
        out.append((int(change.decided.episode) - 1, context))
    return sorted(out, key=lambda pair: pair[0])


def count_changes(
    mission: Mission, people: Sequence[Person], recorded: Mapping[str, Iterable[Recorded]]
) -> Detection:
    """The changes recorded for each person (``recorded[user_id]``, in any order: the service
    lists them newest first; none when absent), counted against the person's true changes,
    over all ``people``."""
    total = Detection()
    for person in people:
        decided = _decided(mission, recorded.get(person.user_id, ()))
        total.add(match_contexts(true_person(person), decided))
    return total


def _share(part: int, whole: int) -> float | None:
    return part / whole if whole else None


def detection_summary(detection: Detection, *, changed: bool) -> dict[str, Any]:
    """The figures of ``detection`` and the issue's two targets (``caught_within``: a share of
    the true changes; ``false_alarms``: per person per :data:`EVENTS_PER_MONTH` events), each
    met (True), missed (False) or not checked by this run (None, with ``why``): the first needs
    a run whose needs change (``changed``) and true changes to catch, the second a run whose
    needs do not change."""
    late = [events for events, _ in detection.caught]
    within = detection.caught_within(CAUGHT_VISITS)
    caught_within_share = _share(within, detection.true)
    rate = detection.false_alarms_per(EVENTS_PER_MONTH)
    caught_target: dict[str, Any] = {
        "name": "caught_within",
        "target": CAUGHT_TARGET_TEXT,
        "value": caught_within_share,
        "met": None,
        "why": None,
    }
    if not changed:
        caught_target["why"] = "needs a run with --change-at"
    elif caught_within_share is None:
        caught_target["why"] = "no true change to catch"
    else:
        caught_target["met"] = caught_within_share >= CAUGHT_TARGET
    alarms_target: dict[str, Any] = {
        "name": "false_alarms",
        "target": FALSE_ALARMS_TARGET_TEXT,
        "value": rate,
        "met": None,
        "why": None,
    }
    if changed:
        alarms_target["why"] = "needs a run without --change-at"
    elif rate is None:
        alarms_target["why"] = "no event played"
    else:
        alarms_target["met"] = rate <= FALSE_ALARMS_TARGET
    return {
        "counted": True,
        "persons": detection.persons,
        "events": detection.events,
        "recorded": len(detection.caught) + detection.false_alarms,
        "true_changes": detection.true,
        "caught": len(detection.caught),
        "caught_share": _share(len(detection.caught), detection.true),
        "missed": detection.missed,
        "within_visits": CAUGHT_VISITS,
        "caught_within": within,
        "caught_within_share": caught_within_share,
        "median_events_late": float(np.median(late)) if late else None,
        "max_events_late": max(late) if late else None,
        "false_alarms": detection.false_alarms,
        "events_per_month": EVENTS_PER_MONTH,
        "false_alarms_per_person_month": rate,
        "targets": [caught_target, alarms_target],
    }
