"""The mission as data: the office mission's facts, other missions, and bad mission files."""

from __future__ import annotations

import copy
import json
from datetime import time
from pathlib import Path
from typing import Any

import pytest

from app.learning import (
    ActionKind,
    Mission,
    MissionError,
    StateKind,
    load_mission,
    office_mission,
    space_for,
)


def office_dict() -> dict[str, Any]:
    return copy.deepcopy(office_mission().to_dict())


def write(tmp_path: Path, data: object, name: str = "mission.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


class TestOfficeMission:
    def test_contexts_states_and_pairs(self) -> None:
        mission = office_mission()
        space = space_for(mission)
        assert mission.n_contexts == 16
        assert space.n_contexts == 16
        assert space.n_states == 17
        assert space.END == 17
        assert space.n_actions == 30
        kinds = [space.state_info(s).kind for s in range(space.n_states)]
        assert kinds.count(StateKind.OBSERVE) == 1
        assert kinds.count(StateKind.REQUEST) == 3
        assert kinds.count(StateKind.ENGAGED) == 1
        assert kinds.count(StateKind.TYPE_KNOWN) == 3
        assert kinds.count(StateKind.DETAIL_KNOWN) == 9
        assert space.state_info(space.END).kind is StateKind.END

    def test_actions_per_state(self) -> None:
        space = space_for(office_mission())
        counts: dict[StateKind, set[int]] = {}
        for s in range(space.n_states):
            kind = space.state_info(s).kind
            counts.setdefault(kind, set()).add(len(space.actions_of(s)))
        # initiate/pass; respond; query_type + 3 infer_type; query_detail + 3 infer_detail; perform
        assert counts == {
            StateKind.OBSERVE: {2},
            StateKind.REQUEST: {1},
            StateKind.ENGAGED: {4},
            StateKind.TYPE_KNOWN: {4},
            StateKind.DETAIL_KNOWN: {1},
        }
        assert [space.actions[a].kind for a in space.actions_of(space.OBSERVE)] == [
            ActionKind.INITIATE,
            ActionKind.PASS,
        ]
        silent = {space.actions[a].kind for a in range(space.n_actions) if space.silent[a]}
        assert silent == {ActionKind.RESPOND, ActionKind.INFER_TYPE, ActionKind.INFER_DETAIL}

    def test_vmax_is_60(self) -> None:
        mission = office_mission()
        assert mission.rewards.max_step == 6.0
        assert mission.gamma == 0.9
        assert mission.v_max == pytest.approx(60.0, rel=1e-12)

    def test_rewards(self) -> None:
        r = office_mission().rewards
        assert (r.positive, r.accepted_service, r.negative, r.query) == (1.0, 5.0, -2.0, -0.5)

    def test_names(self) -> None:
        mission = office_mission()
        assert [s.name for s in mission.time_slots] == ["morning", "noon", "afternoon", "evening"]
        assert mission.situations == ("arriving", "working", "stretching", "busy")
        assert mission.unavailable_situations == ("busy",)
        assert [s.name for s in mission.services] == [
            "ProvideDrink",
            "BriefInformation",
            "ArrangeSchedule",
        ]
        assert mission.service("ProvideDrink").details == ("tea", "coffee", "water")

    def test_context_index_round_trip(self) -> None:
        mission = office_mission()
        seen = set()
        for c in range(mission.n_contexts):
            slot, situation = mission.context_names(c)
            assert mission.context_index(slot, situation) == c
            seen.add((slot, situation))
        assert len(seen) == 16
        with pytest.raises(ValueError, match="time slot"):
            mission.context_index("midnight", "busy")
        with pytest.raises(ValueError, match="situation"):
            mission.context_index("noon", "sleeping")

    @pytest.mark.parametrize(
        ("clock", "slot"),
        [
            (time(6, 0), "morning"),
            (time(10, 59), "morning"),
            (time(11, 0), "noon"),
            (time(13, 59), "noon"),
            (time(14, 0), "afternoon"),
            (time(17, 59), "afternoon"),
            (time(18, 0), "evening"),
            (time(23, 59), "evening"),
            (time(0, 0), "evening"),
            (time(5, 59), "evening"),
        ],
    )
    def test_slot_at_boundaries(self, clock: time, slot: str) -> None:
        assert office_mission().slot_at(clock) == slot

    def test_fingerprint_is_stable_and_shape_sensitive(self) -> None:
        mission = office_mission()
        again = Mission.from_dict(office_dict())
        assert again == mission
        assert again.fingerprint == mission.fingerprint
        data = office_dict()
        data["rewards"]["negative"] = -3.0
        assert Mission.from_dict(data).fingerprint != mission.fingerprint

    def test_integer_rewards_are_the_same_mission(self) -> None:
        data = office_dict()
        data["rewards"] = {"positive": 1, "accepted_service": 5, "negative": -2, "query": -0.5}
        mission = Mission.from_dict(data)
        assert mission.fingerprint == office_mission().fingerprint
        assert isinstance(mission.rewards.positive, float)


class TestOtherMissions:
    def test_load_a_mission_with_other_names(self, tmp_path: Path) -> None:
        data = {
            "name": "care-home",
            "situations": ["resting", "walking", "asleep"],
            "unavailable_situations": ["asleep"],
            "time_slots": [
                {"name": "day", "start": "07:00", "end": "19:00"},
                {"name": "night", "start": "19:00", "end": "07:00"},
            ],
            "services": [
                {"name": "Snack", "details": ["fruit", "biscuit"]},
                {"name": "Call", "details": ["family"]},
            ],
            "rewards": {"positive": 2.0, "accepted_service": 8.0, "negative": -1.0, "query": 0.0},
            "gamma": 0.8,
        }
        mission = load_mission(write(tmp_path, data))
        assert mission.name == "care-home"
        assert mission.n_contexts == 6
        assert mission.v_max == pytest.approx(10.0 / 0.2)
        assert mission.slot_at(time(3, 0)) == "night"
        assert mission.context_names(mission.context_index("night", "walking")) == (
            "night",
            "walking",
        )
        space = space_for(mission)
        # OBSERVE, 2 REQUEST, ENGAGED, 2 TYPE_KNOWN, 3 DETAIL_KNOWN
        assert space.n_states == 9
        # initiate, pass, 2 respond, query_type + 2 infer_type, (1 + 2) + (1 + 1), 3 perform
        assert space.n_actions == 2 + 2 + 3 + 5 + 3
        assert space.detail_known_state("Call", "family") == space.n_states - 1
        assert Mission.from_dict(mission.to_dict()) == mission

    def test_defaults_for_optional_fields(self) -> None:
        data = office_dict()
        for key in ("rewards", "gamma", "unavailable_situations"):
            del data[key]
        mission = Mission.from_dict(data)
        assert mission.gamma == 0.9
        assert mission.v_max == pytest.approx(60.0)
        assert mission.unavailable_situations == ()


def _slots(*spans: tuple[str, str]) -> list[dict[str, str]]:
    return [{"name": f"s{i}", "start": a, "end": b} for i, (a, b) in enumerate(spans)]


def _bad(change: Any) -> dict[str, Any]:
    data = office_dict()
    change(data)
    return data


BAD_MISSIONS = [
    # (description, mutation, words the message must contain)
    ("missing field", lambda d: d.pop("services"), ["'services'", "missing"]),
    (
        "missing slot field",
        lambda d: d["time_slots"][1].pop("end"),
        ["time_slots[1]", "'end'", "missing"],
    ),
    (
        "missing details",
        lambda d: d["services"][2].pop("details"),
        ["services[2]", "'details'", "missing"],
    ),
    ("unknown field", lambda d: d.update(colour="blue"), ["unknown field", "'colour'"]),
    (
        "unknown reward field",
        lambda d: d["rewards"].update(bonus=1.0),
        ["rewards", "unknown field", "'bonus'"],
    ),
    (
        "duplicate service",
        lambda d: d["services"].append(dict(d["services"][0])),
        ["services[3]", "'ProvideDrink'", "twice"],
    ),
    (
        "duplicate detail",
        lambda d: d["services"][1]["details"].append("news"),
        ["services[1].details[3]", "'news'", "twice"],
    ),
    (
        "duplicate situation",
        lambda d: d["situations"].append("working"),
        ["situations[4]", "'working'", "twice"],
    ),
    (
        "duplicate slot name",
        lambda d: d.update(
            time_slots=[
                {"name": "a", "start": "00:00", "end": "12:00"},
                {"name": "a", "start": "12:00", "end": "00:00"},
            ]
        ),
        ["time_slots[1]", "'a'", "twice"],
    ),
    (
        "overlapping slots",
        lambda d: d["time_slots"][1].update(start="10:30"),
        ["time_slots[1]", "noon overlaps morning", "10:30"],
    ),
    (
        "gap between slots",
        lambda d: d["time_slots"][2].update(start="14:30"),
        ["time_slots", "no slot covers", "14:00"],
    ),
    (
        "gap at the wrap",
        lambda d: d["time_slots"][3].update(end="05:00"),
        ["no slot covers", "05:00"],
    ),
    (
        "whole-day slot beside another",
        lambda d: d.update(time_slots=_slots(("06:00", "06:00"), ("08:00", "09:00"))),
        ["time_slots[1]", "s1 overlaps s0", "08:00"],
    ),
    (
        "bad clock format",
        lambda d: d["time_slots"][0].update(start="6:00"),
        ["time_slots[0].start", "'6:00'", "HH:MM"],
    ),
    (
        "clock out of range",
        lambda d: d["time_slots"][2].update(end="24:00"),
        ["time_slots[2].end", "'24:00'", "HH:MM"],
    ),
    (
        "clock not a string",
        lambda d: d["time_slots"][0].update(end=1100),
        ["time_slots[0].end", "1100", "HH:MM"],
    ),
    (
        "negative reward not negative",
        lambda d: d["rewards"].update(negative=2.0),
        ["rewards.negative", "below 0"],
    ),
    (
        "positive reward not positive",
        lambda d: d["rewards"].update(positive=-1.0),
        ["rewards.positive", "above 0"],
    ),
    (
        "query reward positive",
        lambda d: d["rewards"].update(query=0.5),
        ["rewards.query", "0 or less"],
    ),
    (
        "accepted bonus negative",
        lambda d: d["rewards"].update(accepted_service=-1.0),
        ["rewards.accepted_service", "0 or more"],
    ),
    (
        "reward not a number",
        lambda d: d["rewards"].update(query="cheap"),
        ["rewards.query", "not a number"],
    ),
    ("gamma 1", lambda d: d.update(gamma=1.0), ["gamma", "[0, 1)"]),
    ("gamma negative", lambda d: d.update(gamma=-0.1), ["gamma", "[0, 1)"]),
    ("gamma a string", lambda d: d.update(gamma="0.9"), ["gamma", "not a number"]),
    (
        "bad name",
        lambda d: d["services"][0].update(name="Provide Drink"),
        ["services[0].name", "'Provide Drink'", "not a valid name"],
    ),
    (
        "bad detail name",
        lambda d: d["services"][0]["details"].__setitem__(1, "9lives"),
        ["services[0].details[1]", "'9lives'"],
    ),
    ("no services", lambda d: d.update(services=[]), ["services", "at least one"]),
    (
        "no details",
        lambda d: d["services"][0].update(details=[]),
        ["services[0].details", "at least one detail"],
    ),
    ("services not a list", lambda d: d.update(services={"a": 1}), ["services", "expected a list"]),
    (
        "unknown unavailable situation",
        lambda d: d.update(unavailable_situations=["asleep"]),
        ["unavailable_situations[0]", "'asleep'"],
    ),
    (
        "every situation unavailable",
        lambda d: d.update(unavailable_situations=d["situations"]),
        ["unavailable_situations", "at least one situation"],
    ),
]


@pytest.mark.parametrize(
    ("change", "words"),
    [pytest.param(change, words, id=name) for name, change, words in BAD_MISSIONS],
)
def test_bad_missions_are_rejected_saying_what_and_where(
    tmp_path: Path, change: Any, words: list[str]
) -> None:
    path = write(tmp_path, _bad(change), "bad.json")
    with pytest.raises(MissionError) as info:
        load_mission(path)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    for word in words:
        assert word in message, f"{word!r} not in {message!r}"


def test_from_dict_names_the_source() -> None:
    data = office_dict()
    data["gamma"] = 2
    with pytest.raises(MissionError, match=r"^robot-7\.json: gamma: "):
        Mission.from_dict(data, source="robot-7.json")


def test_not_an_object(tmp_path: Path) -> None:
    with pytest.raises(MissionError, match="must be a JSON object"):
        load_mission(write(tmp_path, ["office"]))


def test_invalid_json_reports_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{\n  "name": "office",\n  "situations": [,]\n}\n', encoding="utf-8")
    with pytest.raises(MissionError) as info:
        load_mission(path)
    message = str(info.value)
    assert str(path) in message
    assert "not valid JSON" in message
    assert "line 3, column 18" in message


@pytest.mark.parametrize("kind", ["missing", "directory"])
def test_unreadable_path(tmp_path: Path, kind: str) -> None:
    path = tmp_path / "nowhere.json" if kind == "missing" else tmp_path
    with pytest.raises(MissionError) as info:
        load_mission(path)
    message = str(info.value)
    assert str(path) in message
    assert "cannot be read" in message


def test_mission_error_is_a_value_error() -> None:
    assert issubclass(MissionError, ValueError)


def test_a_single_whole_day_slot_is_allowed() -> None:
    data = office_dict()
    data["time_slots"] = _slots(("00:00", "00:00"))
    mission = Mission.from_dict(data)
    assert mission.n_contexts == len(mission.situations)
    assert mission.slot_at(time(0, 0)) == mission.slot_at(time(23, 59)) == "s0"
