"""The mission as data: time slots, situations, services with their details, and rewards.

A mission names everything a deployment negotiates about. The default is the office mission of
the paper (three services, three details each, four time slots, four situations); a deployment can
load another one from JSON with the same shape. Every check raises :class:`MissionError` with a
sentence that says what is wrong and where (``office.json: services[1].details[0]: ...``).
"""

from __future__ import annotations

import functools
import hashlib
import json
import re
import zoneinfo
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import time
from pathlib import Path
from typing import Any

__all__ = [
    "Mission",
    "MissionError",
    "Rewards",
    "Service",
    "TimeSlot",
    "load_mission",
    "office_mission",
    "readable",
]

_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_.-]{0,63}$")
_CLOCK = re.compile(r"^([01]\d|2[0-3]):([0-5]\d)$")
_MINUTES_PER_DAY = 24 * 60
_LABEL_MAX = 64
_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])")
_DISPLAY_FIELDS = ("labels", "time_zone")
"""Fields of the mission document that are display only: outside the fingerprint."""


def readable(name: str) -> str:
    """The default label of a mission name, a readable form of the id: ``ProvideDrink`` ->
    "Provide drink", ``phone_call`` -> "phone call", ``TV`` -> "TV"."""
    words = _CAMEL.sub(" ", name).replace("_", " ").split()
    if not words:
        return name
    first, rest = words[0], [w if w.isupper() else w.lower() for w in words[1:]]
    return " ".join([first, *rest])


@functools.cache
def _time_zones() -> frozenset[str]:
    return frozenset(zoneinfo.available_timezones())


def _check_time_zone(value: object) -> str:
    if not isinstance(value, str) or not value or len(value) > 64:
        raise MissionError(f"time_zone: {value!r} is not an IANA time zone name (Europe/Paris).")
    # A name of the time zone database's list: "Europe", a folder of it, is no zone.
    if value not in _time_zones():
        raise MissionError(
            f"time_zone: {value!r} is not an IANA time zone name (such as Europe/Paris or UTC)."
        ) from None
    return value


class MissionError(ValueError):
    """A mission (or mission file) that cannot be used, with the place that is wrong."""


def _check_name(value: object, where: str) -> str:
    if not isinstance(value, str) or not _NAME.match(value):
        raise MissionError(
            f"{where}: {value!r} is not a valid name (a letter, then up to 63 letters, digits, "
            "'_', '.' or '-')."
        )
    return value


def _check_unique(names: Sequence[str], where: str) -> None:
    seen: set[str] = set()
    for i, name in enumerate(names):
        if name in seen:
            raise MissionError(f"{where}[{i}]: the name {name!r} is used twice.")
        seen.add(name)


def _minutes(t: time) -> int:
    return t.hour * 60 + t.minute


def _parse_clock(value: object, where: str) -> time:
    if isinstance(value, time):
        return value
    if not isinstance(value, str) or not _CLOCK.match(value):
        raise MissionError(f"{where}: {value!r} is not a local time of the form 'HH:MM'.")
    hours, minutes = value.split(":")
    return time(int(hours), int(minutes))


@dataclass(frozen=True, slots=True)
class TimeSlot:
    """A named part of the day, ``[start, end)`` in local time; wraps midnight if end <= start
    (so start == end is the whole day, for a mission with a single slot)."""

    name: str
    start: time
    end: time

    def minutes(self) -> range | tuple[range, range]:
        """The minutes of the day this slot covers, as one range or two (when it wraps midnight)."""
        s, e = _minutes(self.start), _minutes(self.end)
        if s < e:
            return range(s, e)
        return (range(s, _MINUTES_PER_DAY), range(0, e))

    def contains(self, t: time) -> bool:
        m = _minutes(t)
        s, e = _minutes(self.start), _minutes(self.end)
        return s <= m < e if s < e else (m >= s or m < e)


@dataclass(frozen=True, slots=True)
class Service:
    """A service the robot can perform and the details the person may want of it."""

    name: str
    details: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Rewards:
    """Reward constants of the negotiation (docs/method.md §2)."""

    positive: float = 1.0
    accepted_service: float = 5.0
    negative: float = -2.0
    query: float = -0.5

    def __post_init__(self) -> None:
        for name in ("positive", "accepted_service", "negative", "query"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise MissionError(f"rewards.{name}: {value!r} is not a number.")
            if not -1e6 <= value <= 1e6:  # also refuses NaN and infinities
                raise MissionError(
                    f"rewards.{name}: {value!r} is not a number between -1e6 and 1e6."
                )
        if self.positive <= 0:
            raise MissionError(f"rewards.positive: must be above 0, got {self.positive}.")
        if self.accepted_service < 0:
            raise MissionError(
                f"rewards.accepted_service: must be 0 or more, got {self.accepted_service}."
            )
        if self.negative >= 0:
            raise MissionError(f"rewards.negative: must be below 0, got {self.negative}.")
        if self.query > 0:
            raise MissionError(f"rewards.query: must be 0 or less, got {self.query}.")
        for name in ("positive", "accepted_service", "negative", "query"):
            # Floats always: "positive": 1 and 1.0 are one mission (one fingerprint), and the
            # rewards flow into exported states, which must re-export identically.
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def max_step(self) -> float:
        """The largest one-step reward: a service accepted with positive feedback."""
        return self.positive + self.accepted_service


@dataclass(frozen=True, slots=True)
class Mission:
    """Everything a deployment negotiates about; validated at construction.

    ``unavailable_situations`` are situations in which a person never wants to be interrupted
    (the office mission's ``busy``); the simulated users of the experiments respect them.

    ``labels`` (name -> words, for any time slot, situation, service or detail) and
    ``time_zone`` (an IANA name, the fleet's clock for people's pages) are display only: they
    are outside the fingerprint, so a mission that changes only them is the same mission for
    learning. A name without a label reads as :func:`readable` makes it.
    """

    name: str
    time_slots: tuple[TimeSlot, ...]
    situations: tuple[str, ...]
    services: tuple[Service, ...]
    rewards: Rewards = field(default_factory=Rewards)
    gamma: float = 0.9
    unavailable_situations: tuple[str, ...] = ()
    labels: tuple[tuple[str, str], ...] = ()
    time_zone: str = "UTC"

    def __post_init__(self) -> None:
        if isinstance(self.labels, Mapping):
            object.__setattr__(self, "labels", tuple(self.labels.items()))
        for name in ("time_slots", "situations", "services", "unavailable_situations", "labels"):
            value = getattr(self, name)
            if not isinstance(value, tuple | list):
                raise MissionError(f"{name}: expected a list, got {type(value).__name__}.")
            object.__setattr__(self, name, tuple(value))  # hashable, whatever the caller passed
        for i, service in enumerate(self.services):
            if not isinstance(service, Service):
                raise MissionError(f"services[{i}]: expected a Service.")
            object.__setattr__(service, "details", tuple(service.details))
        _check_name(self.name, "name")
        if not self.time_slots:
            raise MissionError("time_slots: a mission needs at least one time slot.")
        for i, slot in enumerate(self.time_slots):
            _check_name(slot.name, f"time_slots[{i}].name")
        _check_unique([s.name for s in self.time_slots], "time_slots")
        self._check_day_cover()
        if not self.situations:
            raise MissionError("situations: a mission needs at least one situation.")
        for i, situation in enumerate(self.situations):
            _check_name(situation, f"situations[{i}]")
        _check_unique(self.situations, "situations")
        if not self.services:
            raise MissionError("services: a mission needs at least one service.")
        for i, service in enumerate(self.services):
            _check_name(service.name, f"services[{i}].name")
            if not service.details:
                raise MissionError(
                    f"services[{i}].details: {service.name} needs at least one detail."
                )
            for j, detail in enumerate(service.details):
                _check_name(detail, f"services[{i}].details[{j}]")
            _check_unique(service.details, f"services[{i}].details")
        _check_unique([s.name for s in self.services], "services")
        if isinstance(self.gamma, bool) or not isinstance(self.gamma, int | float):
            raise MissionError(f"gamma: {self.gamma!r} is not a number.")
        if not 0.0 <= self.gamma < 1.0:
            raise MissionError(f"gamma: the discount must be in [0, 1), got {self.gamma}.")
        object.__setattr__(self, "gamma", float(self.gamma))
        for i, situation in enumerate(self.unavailable_situations):
            if situation not in self.situations:
                raise MissionError(
                    f"unavailable_situations[{i}]: {situation!r} is not one of the situations "
                    f"{list(self.situations)}."
                )
        if set(self.unavailable_situations) == set(self.situations):
            raise MissionError("unavailable_situations: at least one situation must allow service.")
        self._check_labels()
        # By name: one mission whatever order its document listed them in.
        object.__setattr__(self, "labels", tuple(sorted(self.labels)))
        _check_time_zone(self.time_zone)

    def _check_labels(self) -> None:
        names = {s.name for s in self.time_slots} | set(self.situations)
        for service in self.services:
            names |= {service.name, *service.details}
        seen: set[str] = set()
        for pair in self.labels:
            if not isinstance(pair, tuple) or len(pair) != 2:
                raise MissionError("labels: expected an object of name -> label.")
            name, label = pair
            where = f"labels.{name}"
            if name not in names:
                raise MissionError(
                    f"{where}: {name!r} is not a time slot, situation, service or detail of the "
                    "mission."
                )
            if name in seen:
                raise MissionError(f"{where}: labelled twice.")
            seen.add(name)
            if not isinstance(label, str) or not label.strip() or len(label) > _LABEL_MAX:
                raise MissionError(
                    f"{where}: a label is text of 1 to {_LABEL_MAX} characters, got {label!r}."
                )
            if any(ord(ch) < 32 or ch == "\x7f" for ch in label):
                raise MissionError(f"{where}: a label must not hold control characters.")

    def _check_day_cover(self) -> None:
        owner: list[str | None] = [None] * _MINUTES_PER_DAY
        for i, slot in enumerate(self.time_slots):
            spans = slot.minutes()
            for span in spans if isinstance(spans, tuple) else (spans,):
                for m in span:
                    if owner[m] is not None:
                        raise MissionError(
                            f"time_slots[{i}]: {slot.name} overlaps {owner[m]} at "
                            f"{m // 60:02d}:{m % 60:02d}."
                        )
                    owner[m] = slot.name
        if None in owner:
            m = owner.index(None)
            raise MissionError(
                f"time_slots: no slot covers {m // 60:02d}:{m % 60:02d}; the slots must cover the "
                "whole day."
            )

    # -- derived -------------------------------------------------------------------------------
    @property
    def v_max(self) -> float:
        """Upper bound on the optimal value: R_max,step / (1 - gamma)."""
        return self.rewards.max_step / (1.0 - self.gamma)

    @property
    def n_contexts(self) -> int:
        return len(self.time_slots) * len(self.situations)

    def context_index(self, time_slot: str, situation: str) -> int:
        """Index of the context (time slot, situation); ``ValueError`` names the allowed values."""
        slots = [s.name for s in self.time_slots]
        if time_slot not in slots:
            raise ValueError(f"unknown time slot {time_slot!r}; allowed: {slots}")
        if situation not in self.situations:
            raise ValueError(f"unknown situation {situation!r}; allowed: {list(self.situations)}")
        return slots.index(time_slot) * len(self.situations) + self.situations.index(situation)

    def context_names(self, context: int) -> tuple[str, str]:
        """(time slot, situation) of a context index."""
        slot, situation = divmod(context, len(self.situations))
        return self.time_slots[slot].name, self.situations[situation]

    def slot_at(self, t: time) -> str:
        """Name of the time slot that contains the local time ``t``."""
        for slot in self.time_slots:
            if slot.contains(t):
                return slot.name
        raise AssertionError("time slots cover the day")  # guaranteed by _check_day_cover

    def label(self, name: str | None) -> str:
        """The words staff read for a mission name: its label, or a readable form of it."""
        if not name:
            return ""
        return dict(self.labels).get(name) or readable(name)

    def service(self, name: str) -> Service:
        for service in self.services:
            if service.name == name:
                return service
        raise ValueError(f"unknown service {name!r}; allowed: {[s.name for s in self.services]}")

    # -- (de)serialization ---------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "situations": list(self.situations),
            "unavailable_situations": list(self.unavailable_situations),
            "time_slots": [
                {"name": s.name, "start": s.start.strftime("%H:%M"), "end": s.end.strftime("%H:%M")}
                for s in self.time_slots
            ],
            "services": [{"name": s.name, "details": list(s.details)} for s in self.services],
            "rewards": {
                "positive": self.rewards.positive,
                "accepted_service": self.rewards.accepted_service,
                "negative": self.rewards.negative,
                "query": self.rewards.query,
            },
            "gamma": self.gamma,
            **({"labels": dict(self.labels)} if self.labels else {}),
            **({"time_zone": self.time_zone} if self.time_zone != "UTC" else {}),
        }

    def shape(self) -> dict[str, Any]:
        """The document without its display fields (labels, time zone): what learning sees."""
        doc = self.to_dict()
        for name in _DISPLAY_FIELDS:
            doc.pop(name, None)
        return doc

    def same_display(self, other: Mission) -> bool:
        """Whether ``other`` has the same labels and time zone."""
        return dict(self.labels) == dict(other.labels) and self.time_zone == other.time_zone

    @property
    def fingerprint(self) -> str:
        """A digest of everything that shapes a learner's tables, to match exported states
        (the labels and time zone are left out: they are display only)."""
        return _fingerprint(self)

    @classmethod
    def from_dict(cls, data: object, *, source: str = "mission") -> Mission:
        """Build a mission from plain data; errors name ``source`` and the path inside it."""
        try:
            return cls._from_dict(data)
        except MissionError as exc:
            raise MissionError(f"{source}: {exc}") from None

    @classmethod
    def _from_dict(cls, data: object) -> Mission:
        if not isinstance(data, Mapping):
            raise MissionError("the mission must be a JSON object.")
        allowed = {
            "name",
            "situations",
            "unavailable_situations",
            "time_slots",
            "services",
            "rewards",
            "gamma",
            *_DISPLAY_FIELDS,
        }
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise MissionError(f"unknown field {unknown[0]!r}; allowed: {sorted(allowed)}.")
        for required in ("name", "situations", "time_slots", "services"):
            if required not in data:
                raise MissionError(f"the field {required!r} is missing.")
        slots = []
        for i, raw in enumerate(_as_list(data["time_slots"], "time_slots")):
            where = f"time_slots[{i}]"
            obj = _as_object(raw, where, required=("name", "start", "end"))
            slots.append(
                TimeSlot(
                    name=_check_name(obj["name"], f"{where}.name"),
                    start=_parse_clock(obj["start"], f"{where}.start"),
                    end=_parse_clock(obj["end"], f"{where}.end"),
                )
            )
        services = []
        for i, raw in enumerate(_as_list(data["services"], "services")):
            where = f"services[{i}]"
            obj = _as_object(raw, where, required=("name", "details"))
            details = _as_list(obj["details"], f"{where}.details")
            services.append(
                Service(
                    name=_check_name(obj["name"], f"{where}.name"),
                    details=tuple(
                        _check_name(d, f"{where}.details[{j}]") for j, d in enumerate(details)
                    ),
                )
            )
        rewards = Rewards()
        if "rewards" in data:
            obj = _as_object(data["rewards"], "rewards", required=())
            extra = sorted(set(obj) - {"positive", "accepted_service", "negative", "query"})
            if extra:
                raise MissionError(
                    f"rewards: unknown field {extra[0]!r}; allowed: accepted_service, negative, "
                    "positive, query."
                )
            rewards = Rewards(**obj)
        labels = data.get("labels", {})
        if not isinstance(labels, dict):
            raise MissionError(f"labels: expected an object, got {type(labels).__name__}.")
        return cls(
            name=_check_name(data["name"], "name"),
            time_slots=tuple(slots),
            situations=tuple(_as_list(data["situations"], "situations")),
            services=tuple(services),
            rewards=rewards,
            gamma=data.get("gamma", 0.9),
            unavailable_situations=tuple(
                _as_list(data.get("unavailable_situations", []), "unavailable_situations")
            ),
            labels=tuple(labels.items()),
            time_zone=data.get("time_zone", "UTC"),
        )


def _as_list(value: object, where: str) -> list[Any]:
    if not isinstance(value, list):
        raise MissionError(f"{where}: expected a list, got {type(value).__name__}.")
    return value


def _as_object(value: object, where: str, *, required: Sequence[str]) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise MissionError(f"{where}: expected an object, got {type(value).__name__}.")
    for key in required:
        if key not in value:
            raise MissionError(f"{where}: the field {key!r} is missing.")
    return value


def load_mission(path: str | Path) -> Mission:
    """Read a mission from a JSON file; a bad file raises :class:`MissionError` naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MissionError(f"{path}: cannot be read ({exc.strerror or exc}).") from None
    except UnicodeDecodeError:
        raise MissionError(f"{path}: is not UTF-8 text.") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MissionError(
            f"{path}: not valid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}."
        ) from None
    except RecursionError:
        raise MissionError(f"{path}: the JSON is nested too deeply to be a mission.") from None
    return Mission.from_dict(data, source=str(path))


_OFFICE = Path(__file__).with_name("missions") / "office.json"


@functools.cache
def office_mission() -> Mission:
    """The paper's office mission (docs/method.md §2), loaded from the packaged JSON."""
    return load_mission(_OFFICE)


@functools.lru_cache(maxsize=16)
def _fingerprint(mission: Mission) -> str:
    # Every saved learner state carries it, so it is computed once per mission.
    canonical = json.dumps(mission.shape(), sort_keys=True, separators=(",", ":"))
    return "sha256:" + hashlib.sha256(canonical.encode()).hexdigest()[:32]
