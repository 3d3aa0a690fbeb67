"""The changes told to staff about simulated people, counted against their true changes
(``app.fleet.detection``), without a service: the learning core's rule, the episodes and names
of the recorded changes mapped to events and contexts, and the two targets."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

import numpy as np
import pytest

from app.fleet import Person, make_people
from app.fleet.detection import count_changes, detection_summary, true_person
from app.learning import office_mission
from app.learning.population import Detection, true_changes

MISSION = office_mission()
EVENTS, CHANGE_AT = 120, 60


@dataclass(frozen=True)
class Moment:
    episode: int
    at: dt.datetime = dt.datetime(2026, 12, 1, tzinfo=dt.UTC)


@dataclass(frozen=True)
class Change:
    """What counting reads of an ``attune_client.ChangeEvent``."""

    time_slot: str
    situation: str
    decided: Moment


def recorded_at(context: int, event: int) -> Change:
    """A change recorded in ``context``, decided by the episode of ``event`` (0-based)."""
    slot, situation = MISSION.context_names(context)
    return Change(slot, situation, Moment(event + 1))


def visits(contexts: np.ndarray, context: int, start: int) -> list[int]:
    """The events from ``start`` on whose context is ``context``."""
    return [int(e) for e in np.flatnonzero(contexts == context) if e >= start]


@pytest.fixture(scope="module")
def person() -> Person:
    (one,) = make_people(MISSION, users=1, events=EVENTS, change_at=CHANGE_AT, seed=3, prefix="d")
    return one


class TestTruePerson:
    def test_the_same_needs_and_events(self) -> None:
        for change_at in (CHANGE_AT, None):
            for simulated in make_people(
                MISSION, users=3, events=EVENTS, change_at=change_at, seed=4, prefix="t"
            ):
                described = true_person(simulated)
                assert described.n_events == simulated.events
                np.testing.assert_array_equal(described.contexts, simulated.contexts)
                for e in (0, CHANGE_AT - 1, CHANGE_AT, EVENTS - 1):
                    assert described.profile_at(e) is simulated.profile_at(e)
                assert described.change_at == change_at

    def test_the_true_changes_are_the_needs_replaced_or_ended(self) -> None:
        for simulated in make_people(
            MISSION, users=6, events=EVENTS, change_at=CHANGE_AT, seed=4, prefix="t"
        ):
            before, after = simulated.profiles
            expected = {n.context for n in before.needs if after.need_at(n.context) != n}
            changes = true_changes(true_person(simulated))
            assert {c.context for c in changes} == expected
            gained = {n.context for n in after.needs} - {n.context for n in before.needs}
            assert not gained & {c.context for c in changes}  # a new need is not a change
        (still,) = make_people(MISSION, users=1, events=EVENTS, change_at=None, seed=4, prefix="s")
        assert true_changes(true_person(still)) == []


class TestCounting:
    def test_caught_late_and_false_alarms(self, person: Person) -> None:
        first, *rest = true_changes(true_person(person))
        seen = visits(person.contexts, first.context, CHANGE_AT)
        before = int(np.flatnonzero(person.contexts[:CHANGE_AT] == first.context)[-1])
        unchanged = next(
            c
            for c in range(MISSION.n_contexts)
            if c not in {t.context for t in true_changes(true_person(person))}
        )
        recorded = [  # newest first, as the service lists them
            recorded_at(first.context, seen[4]),  # a second change there: a false alarm
            recorded_at(unchanged, seen[0]),  # a context that did not change
            recorded_at(first.context, seen[2]),  # the first at or after the change: caught
            recorded_at(first.context, before),  # before the change point: a false alarm
        ]
        counted = count_changes(MISSION, [person], {person.user_id: recorded})
        assert counted.caught == [(seen[2] - CHANGE_AT, 3)]
        assert counted.missed == len(rest)
        assert counted.false_alarms == 3
        assert (counted.persons, counted.events) == (1, EVENTS)

    def test_names_the_mission_lacks_are_false_alarms(self, person: Person) -> None:
        odd = Change("midnight", "stretching", Moment(CHANGE_AT + 5))
        counted = count_changes(MISSION, [person], {person.user_id: [odd]})
        assert counted.false_alarms == 1
        assert counted.caught == []

    def test_a_person_without_recorded_changes_misses_them_all(self, person: Person) -> None:
        counted = count_changes(MISSION, [person], {})
        assert counted.missed == counted.true == len(true_changes(true_person(person)))
        assert counted.false_alarms == 0


class TestSummary:
    def test_the_figures(self) -> None:
        detection = Detection(
            caught=[(2, 1), (9, 3), (30, 4)], missed=1, false_alarms=2, events=1000, persons=4
        )
        got = detection_summary(detection, changed=True)
        assert got["counted"] is True
        assert (got["true_changes"], got["caught"], got["missed"]) == (4, 3, 1)
        assert got["caught_share"] == pytest.approx(3 / 4)
        assert (got["within_visits"], got["caught_within"]) == (3, 2)
        assert got["caught_within_share"] == pytest.approx(2 / 4)
        assert (got["median_events_late"], got["max_events_late"]) == (9.0, 30)
        assert got["false_alarms"] == 2
        assert got["recorded"] == 5
        assert got["events_per_month"] == 500
        assert got["false_alarms_per_person_month"] == pytest.approx(500 * 2 / 1000)
        caught, alarms = got["targets"]
        assert (caught["name"], alarms["name"]) == ("caught_within", "false_alarms")
        assert "within 3 visits" in caught["target"]
        assert (caught["value"], caught["met"], caught["why"]) == (pytest.approx(0.5), False, None)
        assert alarms["met"] is None
        assert "without --change-at" in alarms["why"]

    def test_the_targets_met_or_not_checked(self) -> None:
        all_caught = Detection(caught=[(1, 1), (2, 2)], events=500, persons=1)
        caught, _ = detection_summary(all_caught, changed=True)["targets"]
        assert caught["met"] is True
        quiet = Detection(false_alarms=1, events=1000, persons=2)
        got = detection_summary(quiet, changed=False)
        caught, alarms = got["targets"]
        assert caught["met"] is None
        assert "with --change-at" in caught["why"]
        assert (alarms["value"], alarms["met"]) == (pytest.approx(0.5), True)
        noisy = Detection(false_alarms=3, events=1000, persons=2)
        assert detection_summary(noisy, changed=False)["targets"][1]["met"] is False
        assert got["caught_share"] is None
        assert got["median_events_late"] is None
        nothing_to_catch = detection_summary(Detection(events=10, persons=1), changed=True)
        assert nothing_to_catch["targets"][0]["why"] == "no true change to catch"
