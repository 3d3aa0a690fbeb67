"""The mission page's form: a mission written the way staff say it, without JSON.

One line per service (``ProvideDrink: tea, coffee, water``), the situations and the
do-not-disturb ones as comma lists, one line per time slot (``morning 06:00-11:00``), renames as
lines (``cha -> tea``), and the rewards and discount kept as they are unless changed. The form
reads into the documents ``missions.set_mission`` takes; the service checks them, and its
messages (``services[1].details[0]: ...``) are put back next to the field they are about, in
the form's words (services and their *choices*).
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

from app.learning import Mission
from app.learning.remap import MissionDiff, Renames, diff_missions

__all__ = [
    "FIELDS",
    "Change",
    "FormError",
    "MissionForm",
    "MissionVersion",
    "changes",
    "field_of",
    "history",
]

# The form's text fields, in the order of the page (the hidden ones aside).
FIELDS = (
    "services",
    "situations",
    "do_not_disturb",
    "time_slots",
    "renames",
    "name",
    "reward_positive",
    "reward_accepted_service",
    "reward_negative",
    "reward_query",
    "gamma",
)
_REWARDS = ("positive", "accepted_service", "negative", "query")
_SLOT = re.compile(
    r"^(?P<name>[^\s:]+)\s*:?\s+(?P<start>\d{1,2}[:.h]\d{2})\s*"
    r"(?:-|–|—|to)\s*(?P<end>\d{1,2}[:.h]\d{2})$"
)
_ARROW = re.compile(r"\s*(?:->|→|=>)\s*")
_KINDS = {
    "time slot": "time_slots",
    "slot": "time_slots",
    "situation": "situations",
    "service": "services",
    "choice": "details",
}


class FormError(ValueError):
    """A field the form cannot read: which field, and a sentence for the person."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(message)
        self.field = field_name
        self.message = message


def _commas(text: str) -> list[str]:
    return [part.strip() for part in text.replace("\n", ",").split(",") if part.strip()]


def _lines(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if line.strip()]


def _number(value: float) -> str:
    """The exact number, without a needless ".0": 5.0 -> "5", 0.9 -> "0.9"."""
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def _clock(text: str) -> str:
    hours, minutes = re.split(r"[:.h]", text)
    return f"{int(hours):02d}:{minutes}"


@dataclass
class MissionForm:
    """What the staff typed (or the mission in force, written out), field by field."""

    services: str = ""
    situations: str = ""
    do_not_disturb: str = ""
    time_slots: str = ""
    renames: str = ""
    name: str = ""
    reward_positive: str = ""
    reward_accepted_service: str = ""
    reward_negative: str = ""
    reward_query: str = ""
    gamma: str = ""
    errors: dict[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, mission: Mission) -> MissionForm:
        """The mission written as the form shows it."""
        return cls(
            services="\n".join(f"{s.name}: {', '.join(s.details)}" for s in mission.services),
            situations=", ".join(mission.situations),
            do_not_disturb=", ".join(mission.unavailable_situations),
            time_slots="\n".join(
                f"{s.name} {s.start:%H:%M}-{s.end:%H:%M}" for s in mission.time_slots
            ),
            name=mission.name,
            reward_positive=_number(mission.rewards.positive),
            reward_accepted_service=_number(mission.rewards.accepted_service),
            reward_negative=_number(mission.rewards.negative),
            reward_query=_number(mission.rewards.query),
            gamma=_number(mission.gamma),
        )

    @classmethod
    def from_fields(cls, form: dict[str, str], mission: Mission) -> MissionForm:
        """The submitted form; a field left out keeps ``mission``'s value."""
        current = cls.of(mission)
        values = {name: form.get(name, getattr(current, name)) for name in FIELDS}
        # Browsers send line breaks as CRLF; the form keeps plain ones.
        return cls(**{k: v.replace("\r\n", "\n").replace("\r", "\n") for k, v in values.items()})

    def values(self) -> dict[str, str]:
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "errors"}

    # -- to the service's documents ---------------------------------------------------------
    def documents(self, current: Mission) -> tuple[dict[str, Any], dict[str, dict[str, str]]]:
        """(mission document, renames document), or :class:`FormError` for a field that cannot
        be read. ``current``: the mission in force, for the names renames refer to."""
        doc = self._mission()
        # The form does not edit the display settings: they are carried over, the labels of
        # the names that stay (a renamed name keeps its label under its new name).
        renames = self._renames(current)
        moved = {old: new for kind in renames.values() for old, new in kind.items()}
        names = {s["name"] for s in doc["time_slots"]} | set(doc["situations"])
        for service in doc["services"]:
            names |= {service["name"], *service["details"]}
        labels = {}
        for name, text in current.labels:
            target = moved.get(name, name)
            if target in names:
                labels[target] = text
        if labels:
            doc["labels"] = labels
        if current.time_zone != "UTC":
            doc["time_zone"] = current.time_zone
        return doc, renames

    def _mission(self) -> dict[str, Any]:
        services = []
        for i, line in enumerate(_lines(self.services), 1):
            name, colon, rest = line.partition(":")
            if not colon or not name.strip():
                raise FormError(
                    "services",
                    f"Line {i}, {line!r}: write a service and its "
                    "choices as 'ProvideDrink: tea, coffee, water'.",
                )
            services.append({"name": name.strip(), "details": _commas(rest)})
        slots = []
        for line in _lines(self.time_slots):
            found = _SLOT.match(line)
            if not found:
                raise FormError(
                    "time_slots",
                    f"{line!r}: write a time slot as its name and its "
                    "local hours, 'morning 06:00-11:00'.",
                )
            slots.append(
                {
                    "name": found["name"],
                    "start": _clock(found["start"]),
                    "end": _clock(found["end"]),
                }
            )
        rewards: dict[str, float] = {}
        for key in _REWARDS:
            rewards[key] = self._float(f"reward_{key}")
        return {
            "name": self.name.strip(),
            "situations": _commas(self.situations),
            "unavailable_situations": _commas(self.do_not_disturb),
            "time_slots": slots,
            "services": services,
            "rewards": rewards,
            "gamma": self._float("gamma"),
        }

    def _float(self, name: str) -> float:
        text = getattr(self, name).strip()
        try:
            return float(text)
        except ValueError:
            raise FormError(name, f"{text!r} is not a number.") from None

    def _renames(self, current: Mission) -> dict[str, dict[str, str]]:
        known = {
            "time_slots": {s.name for s in current.time_slots},
            "situations": set(current.situations),
            "services": {s.name for s in current.services},
            "details": {d for s in current.services for d in s.details},
        }
        out: dict[str, dict[str, str]] = {}
        for line in _lines(self.renames):
            parts = _ARROW.split(line)
            if len(parts) != 2 or not parts[0] or not parts[1]:
                raise FormError("renames", f"{line!r}: write a rename as 'old name -> new name'.")
            old, new = parts
            kind, colon, name = old.partition(":")
            section = _KINDS.get(kind.strip().lower()) if colon else None
            if section is not None:
                old = name.strip()
            elif "/" in old:
                section = "details"  # "ProvideDrink/cha": that service's choice only
            else:
                found = [k for k, names in known.items() if old in names]
                if not found:
                    raise FormError(
                        "renames",
                        f"{line!r}: the mission in force has no service, "
                        f"choice, situation or time slot named {old!r}.",
                    )
                if len(found) > 1:
                    words = " or ".join(f"'{_word(k)}: {old} -> {new}'" for k in found)
                    raise FormError(
                        "renames", f"{line!r}: {old!r} names more than one thing; write {words}."
                    )
                section = found[0]
            if old in out.get(section, {}):
                raise FormError("renames", f"{line!r}: {old!r} is renamed twice.")
            out.setdefault(section, {})[old] = new
        return out


def _word(section: str) -> str:
    return {
        "time_slots": "time slot",
        "situations": "situation",
        "services": "service",
        "details": "choice",
    }[section]


# -- the service's messages, next to their field ------------------------------------------------
_PATHS = [
    ("services", "services"),
    ("time_slots", "time_slots"),
    ("unavailable_situations", "do_not_disturb"),
    ("situations", "situations"),
    ("renames", "renames"),
    ("rewards", "advanced"),
    ("gamma", "gamma"),
    ("name", "name"),
]
_LIMIT_WORDS = [
    ("time slots", "time_slots"),
    ("situations", "situations"),
    ("contexts", "time_slots"),
    ("services", "services"),
    ("details", "services"),
]


def field_of(message: str, doc: dict[str, Any] | None = None) -> tuple[str, str]:
    """(field, message in the form's words) for a 422 message of the mission service: the
    path in the documents (``services[1].details[0]``) becomes the names the person typed."""
    text = re.sub(r"^mission: ", "", message)
    target = "general"
    reward = re.match(r"rewards\.(positive|accepted_service|negative|query): ", text)
    if reward:
        target, text = f"reward_{reward[1]}", text[reward.end() :]
    for prefix, name in _PATHS:
        if target == "general" and re.match(rf"{prefix}\b", text):
            target = name
            # "gamma: ..." next to the discount's field needs no path.
            text = re.sub(rf"^{prefix}: ", "", text)
            break
    else:
        for word, name in _LIMIT_WORDS:
            if re.match(rf"\d+ {word} ", text):
                target = name
                break
    services = (doc or {}).get("services") or []
    slots = (doc or {}).get("time_slots") or []

    def service(m: re.Match[str]) -> str:
        i = int(m[1])
        name = services[i]["name"] if i < len(services) else f"service {i + 1}"
        if m[2] is not None:
            return f"{name}, choice {int(m[2]) + 1}"
        return f"{name} (line {i + 1})" if m[3] == ".name" else name

    def slot(m: re.Match[str]) -> str:
        i = int(m[1])
        name = slots[i]["name"] if i < len(slots) else f"{i + 1}"
        return f"time slot {name}" + ({".start": ", start", ".end": ", end"}.get(m[2] or "", ""))

    text = re.sub(r"services\[(\d+)\](?:\.details\[(\d+)\]|(\.name|\.details))?", service, text)
    text = re.sub(r"time_slots\[(\d+)\](\.name|\.start|\.end)?", slot, text)
    text = re.sub(
        r"unavailable_situations\[(\d+)\]",
        lambda m: f"do-not-disturb situation {int(m[1]) + 1}",
        text,
    )
    text = re.sub(r"situations\[(\d+)\]", lambda m: f"situation {int(m[1]) + 1}", text)
    text = re.sub(r"renames\.\w+\.([^:]+):", r"rename of \1:", text)
    text = re.sub(r"\bdetails\b", "choices", text)
    text = re.sub(r"\bdetail\b", "choice", text)
    return target, text[:1].upper() + text[1:]


# -- what a change does, in words ----------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Change:
    """One line of a change's summary: ``kind`` is added, removed, renamed or changed."""

    kind: str
    text: str


def _split(name: str) -> tuple[str, str]:
    service, _, detail = name.partition("/")
    return service, detail


def changes(old: Mission, new: Mission, diff: MissionDiff) -> list[Change]:
    """What moving from ``old`` to ``new`` changes, in plain words (``diff``: the service's
    ``diff_missions`` of the two, with the change's renames)."""
    out: list[Change] = []
    new_services = set(diff.services.added)
    gone_services = set(diff.services.removed)
    for name in diff.services.added:
        out.append(
            Change(
                "added",
                f"New service {name}, with the choices {', '.join(new.service(name).details)}.",
            )
        )
    for name in diff.services.removed:
        out.append(Change("removed", f"Service {name} removed."))
    for a, b in diff.services.renamed:
        out.append(Change("renamed", f"Service {a} renamed {b}."))
    for name in diff.details.added:
        service, detail = _split(name)
        if service not in new_services:
            out.append(Change("added", f"New choice for {service}: {detail}."))
    for name in diff.details.removed:
        service, detail = _split(name)
        if service not in gone_services:
            out.append(Change("removed", f"Choice removed from {service}: {detail}."))
    for a, b in diff.details.renamed:
        (service, d1), (_, d2) = _split(a), _split(b)
        if d1 != d2:
            out.append(Change("renamed", f"Choice of {service} renamed: {d1} → {d2}."))
    for name in diff.situations.added:
        out.append(Change("added", f"New situation: {name}."))
    for name in diff.situations.removed:
        out.append(Change("removed", f"Situation removed: {name}."))
    for a, b in diff.situations.renamed:
        out.append(Change("renamed", f"Situation renamed: {a} → {b}."))
    if set(old.unavailable_situations) != set(new.unavailable_situations):
        now = ", ".join(new.unavailable_situations) or "none"
        out.append(Change("changed", f"Do not disturb now in: {now}."))
    old_slots = {s.name: s for s in old.time_slots}
    renamed_slots = {b: a for a, b in diff.time_slots.renamed}
    for name in diff.time_slots.added:
        s = new.time_slots[[t.name for t in new.time_slots].index(name)]
        out.append(Change("added", f"New time slot: {name}, {s.start:%H:%M}–{s.end:%H:%M}."))
    for name in diff.time_slots.removed:
        out.append(Change("removed", f"Time slot removed: {name}."))
    for a, b in diff.time_slots.renamed:
        out.append(Change("renamed", f"Time slot renamed: {a} → {b}."))
    for s in new.time_slots:
        before = old_slots.get(renamed_slots.get(s.name, s.name))
        if before is not None and (before.start, before.end) != (s.start, s.end):
            out.append(
                Change(
                    "changed",
                    f"Hours of {s.name}: {before.start:%H:%M}–"
                    f"{before.end:%H:%M} become {s.start:%H:%M}–"
                    f"{s.end:%H:%M}.",
                )
            )
    if diff.rewards_changed:
        out.append(Change("changed", "The rewards (advanced settings) changed."))
    if diff.gamma_changed:
        out.append(
            Change(
                "changed",
                f"The discount (advanced settings) changed from {old.gamma:g} to {new.gamma:g}.",
            )
        )
    if old.name != new.name:
        out.append(Change("renamed", f"The mission is now called {new.name}."))
    return out


# -- the versions of a fleet's mission --------------------------------------------------------
@dataclass(frozen=True, slots=True)
class MissionVersion:
    """A version as the history shows it: when, by which key, and what it changed from the
    version before (``changes`` None for the first)."""

    version: int
    mission: Mission
    created_at: dt.datetime | None
    set_by: str | None
    stored: bool
    renames: Renames
    changes: list[Change] | None


def history(items: Sequence[dict[str, Any]]) -> list[MissionVersion]:
    """The versions of ``missions.list_missions`` (newest first), each with what it changed."""
    out: list[MissionVersion] = []
    before: Mission | None = None
    for item in reversed(items):
        mission = Mission.from_dict(item["mission"], source=f"version {item['version']}")
        renames = Renames.from_dict(item.get("renames"))
        changed = None
        if before is not None:
            changed = changes(before, mission, diff_missions(before, mission, renames))
        created = item.get("created_at")
        out.append(
            MissionVersion(
                version=item["version"],
                mission=mission,
                created_at=dt.datetime.fromisoformat(created) if created else None,
                set_by=item.get("set_by"),
                stored=bool(item.get("stored", True)),
                renames=renames,
                changes=changed,
            )
        )
        before = mission
    return out[::-1]
