"""A map of the paper's claims over the choices the reconstruction had to make
(docs/method.md §13, "A map of the claims").

The paper lost several of its settings with its equations. Each such choice is an :class:`Axis`
with a plausible range of values and the value every other command uses (its *default*). A
:class:`Setting` picks one value per axis; the default setting is the reading every other command
runs, and any other setting is *a reading*, never the paper.

The axes split in three by what they change: the simulated users and their mission (a
:class:`World`), R-MAX, or the HRI learner. Each method's runs depend only on its world and on its
own axes, so a sweep runs every method variant once per world and decides every setting from the
runs it combines: R-MAX's and the HRI learner's variants multiply into settings without another run.
Methods keep the paper's labels in every variant, so their random draws are the same in every
setting of a world (common random numbers), and the default setting's runs are exactly those of
``attune experiment paper`` for the same seeds.

Pure: the standard library and numpy only.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import time

from .claims import HRI100, HRI200, QL, RMAX, Claim, check_claims
from .evaluation import Method, RunResult
from .mission import Mission

__all__ = [
    "AXES",
    "Axis",
    "ClaimMap",
    "Grid",
    "Setting",
    "Value",
    "World",
    "build_map",
    "decide",
    "method_key",
    "setting_methods",
    "with_time_slots",
]

Value = int | float | str


@dataclass(frozen=True)
class Axis:
    """One choice the paper left open: its values in the sweep, and the default's value.

    ``scope`` says what it changes: ``world`` (the simulated users or their mission), ``rmax``
    or ``hri`` (that learner only). ``quick`` is the smaller range of the quick sweep.
    """

    key: str
    label: str
    values: tuple[Value, ...]
    default: Value
    quick: tuple[Value, ...]
    scope: str

    def __post_init__(self) -> None:
        if self.default not in self.values or self.default not in self.quick:
            raise ValueError(f"axis {self.key}: the default {self.default!r} must be swept.")
        if not set(self.quick) <= set(self.values):
            raise ValueError(f"axis {self.key}: quick values must be among the values.")
        if self.scope not in ("world", "rmax", "hri"):
            raise ValueError(f"axis {self.key}: unknown scope {self.scope!r}.")


AXES: tuple[Axis, ...] = (
    Axis(
        "time_slots",
        "time slots per day (contexts: slots × 4 situations)",
        (2, 4, 8),
        4,
        (2, 4),
        "world",
    ),
    Axis(
        "p_self", "users speak first after a pass (p_self)", (0.2, 0.5, 0.8), 0.5, (0.5,), "world"
    ),
    Axis(
        "noise",
        "users' answer noise ν (p_acc = 1 − ν, eps_fb = ν)",
        (0.0, 0.05, 0.1),
        0.05,
        (0.05,),
        "world",
    ),
    Axis("m", "R-MAX known threshold m", (1, 2, 4), 2, (1, 2), "rmax"),
    Axis("optimism", "R-MAX value of unknown pairs, × Vmax", (1.0, 0.1), 1.0, (1.0,), "rmax"),
    Axis(
        "exclusion",
        "HRI exclusion scope",
        ("per_pair", "root_only", "none"),
        "per_pair",
        ("per_pair", "none"),
        "hri",
    ),
    Axis("pref_scale", "HRI preference scale", ("vmax", "raw"), "vmax", ("vmax",), "hri"),
)
"""The swept choices, in the order of a setting's values (docs/method.md §13 gives the ranges)."""

_AXIS = {axis.key: axis for axis in AXES}
_INDEX = {axis.key: i for i, axis in enumerate(AXES)}


@dataclass(frozen=True, order=True)
class Setting:
    """One value per axis of :data:`AXES`, in that order."""

    values: tuple[Value, ...]

    def __post_init__(self) -> None:
        if len(self.values) != len(AXES):
            raise ValueError(f"a setting has {len(AXES)} values, got {len(self.values)}.")
        for axis, value in zip(AXES, self.values, strict=True):
            if value not in axis.values:
                raise ValueError(f"{axis.key}={value!r} is not among {axis.values}.")

    @classmethod
    def default(cls) -> Setting:
        """The default reading: the value every other command uses, on every axis."""
        return cls(tuple(axis.default for axis in AXES))

    @classmethod
    def of(cls, **changes: Value) -> Setting:
        """The default setting with ``changes`` (by axis key)."""
        unknown = sorted(set(changes) - set(_AXIS))
        if unknown:
            raise ValueError(f"{unknown[0]} is not an axis; axes: {', '.join(_AXIS)}.")
        return cls(tuple(changes.get(axis.key, axis.default) for axis in AXES))

    def __getitem__(self, key: str) -> Value:
        if key not in _INDEX:
            raise KeyError(f"{key} is not an axis; axes: {', '.join(_AXIS)}.")
        return self.values[_INDEX[key]]

    def as_dict(self) -> dict[str, Value]:
        return {axis.key: value for axis, value in zip(AXES, self.values, strict=True)}

    @property
    def is_default(self) -> bool:
        return self == Setting.default()

    def changes(self) -> dict[str, Value]:
        """The axes on which this setting differs from the default, with its values there."""
        return {
            axis.key: value
            for axis, value in zip(AXES, self.values, strict=True)
            if value != axis.default
        }

    def label(self) -> str:
        """``default``, or the changes from it: ``reading: m=1, exclusion=none``."""
        changes = self.changes()
        if not changes:
            return "default"
        return "reading: " + ", ".join(f"{k}={_text(v)}" for k, v in changes.items())

    def world(self) -> World:
        return World(int(self["time_slots"]), float(self["p_self"]), float(self["noise"]))


def _text(value: Value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True, order=True)
class World:
    """What the simulated users are and where they live: the world-scope axes of a setting."""

    time_slots: int
    p_self: float
    noise: float

    def user_params(self) -> dict[str, float]:
        """The simulated users' response parameters (``UserProfile`` fields)."""
        return {"p_acc": 1.0 - self.noise, "p_self": self.p_self, "eps_fb": self.noise}

    def mission(self, base: Mission) -> Mission:
        """``base`` with this world's number of time slots (:func:`with_time_slots`)."""
        return with_time_slots(base, self.time_slots)


def with_time_slots(mission: Mission, n: int) -> Mission:
    """``mission`` with coarser or finer time slots: ``n`` = its own number (itself), half of
    it (each two consecutive slots merged: ``morning-noon``) or twice it (each slot split at its
    midpoint: ``morning.1``, ``morning.2``). Nothing else changes."""
    slots = mission.time_slots
    if n == len(slots):
        return mission
    if 2 * n == len(slots):
        merged = [
            {"name": f"{a.name}-{b.name}", "start": _hhmm(a.start), "end": _hhmm(b.end)}
            for a, b in zip(slots[0::2], slots[1::2], strict=True)
        ]
        return _with_slots(mission, merged)
    if n == 2 * len(slots):
        split = []
        for slot in slots:
            start, end = _minutes(slot.start), _minutes(slot.end)
            length = (end - start) % 1440 or 1440
            middle = (start + length // 2) % 1440
            split += [
                {"name": f"{slot.name}.1", "start": _hhmm(start), "end": _hhmm(middle)},
                {"name": f"{slot.name}.2", "start": _hhmm(middle), "end": _hhmm(end)},
            ]
        return _with_slots(mission, split)
    raise ValueError(
        f"time slots: {n} is neither {len(slots)}, half of it nor twice it (mission "
        f"{mission.name!r})."
    )


def _minutes(t: time) -> int:
    return t.hour * 60 + t.minute


def _hhmm(t: time | int) -> str:
    minutes = t if isinstance(t, int) else _minutes(t)
    return f"{minutes // 60:02d}:{minutes % 60:02d}"


def _with_slots(mission: Mission, slots: list[dict[str, str]]) -> Mission:
    data = mission.to_dict()
    data["time_slots"] = slots
    return Mission.from_dict(data, source=f"{mission.name} with {len(slots)} time slots")


def setting_methods(setting: Setting) -> tuple[Method, Method, Method, Method]:
    """The paper's four methods under ``setting``: R-MAX, Q-learning, HRI τ=0.01, HRI τ=0.005.

    Labels are the paper's in every setting (so are the learners' random draws); under the
    default setting the parameters are the learners' defaults, spelled out.
    """
    hri = {"exclusion": setting["exclusion"], "pref_scale": setting["pref_scale"]}
    return (
        Method(RMAX, "rmax", {"m": setting["m"], "optimism": setting["optimism"]}),
        Method(QL, "qlearning"),
        Method(HRI100, "hri", {"tau": 0.01, **hri}),
        Method(HRI200, "hri", {"tau": 0.005, **hri}),
    )


MethodKey = tuple[str, str, tuple[tuple[str, Value], ...]]


def method_key(method: Method) -> MethodKey:
    """A hashable identity of a method: label, algorithm and parameters."""
    return (method.label, method.algorithm, tuple(sorted(method.params.items())))


@dataclass(frozen=True)
class Grid:
    """The values swept on each axis (by key, every axis of :data:`AXES`)."""

    values: Mapping[str, tuple[Value, ...]]

    def __post_init__(self) -> None:
        if set(self.values) != set(_AXIS):
            raise ValueError(f"a grid has values for exactly the axes {', '.join(_AXIS)}.")
        for key, values in self.values.items():
            axis = _AXIS[key]
            if not values or len(set(values)) != len(values):
                raise ValueError(f"axis {key}: values must be distinct, and at least one.")
            if not set(values) <= set(axis.values):
                raise ValueError(f"axis {key}: {values} is not within {axis.values}.")

    @classmethod
    def full(cls) -> Grid:
        return cls({axis.key: axis.values for axis in AXES})

    @classmethod
    def quick(cls) -> Grid:
        return cls({axis.key: axis.quick for axis in AXES})

    def settings(self) -> list[Setting]:
        """Every combination, in axis order (the first axis varies slowest)."""
        return [
            Setting(values)
            for values in itertools.product(*(self.values[axis.key] for axis in AXES))
        ]

    def worlds(self) -> list[World]:
        return list(dict.fromkeys(s.world() for s in self.settings()))

    def methods(self) -> list[Method]:
        """Every method variant the settings need in one world, each once."""
        out: dict[MethodKey, Method] = {}
        for setting in self.settings():
            for method in setting_methods(setting):
                out.setdefault(method_key(method), method)
        return list(out.values())


RunKey = tuple[World, MethodKey]


def decide(setting: Setting, runs: Mapping[RunKey, Sequence[RunResult]]) -> list[Claim]:
    """Decide the paper's claims under ``setting`` from the runs of its world and methods
    (``runs[(world, method_key(m))]``: that method's E1/E2 and E3 runs, every seed)."""
    world = setting.world()
    results: list[RunResult] = []
    for method in setting_methods(setting):
        key = (world, method_key(method))
        if key not in runs:
            raise KeyError(f"no runs of {method.label} {dict(method.params)} in {world}.")
        results.extend(runs[key])
    return check_claims(results)


@dataclass
class ClaimMap:
    """Which claims hold under which settings, and what follows from it.

    ``verdicts[setting]`` is one bool per claim of ``claims`` ((key, text) pairs, in
    :func:`check_claims` order); ``evidence[setting]`` the numbers each was decided on.
    """

    claims: list[tuple[str, str]]  # (key, text)
    verdicts: dict[Setting, list[bool]]
    evidence: dict[Setting, list[str]] = field(default_factory=dict)

    @property
    def settings(self) -> list[Setting]:
        return list(self.verdicts)

    def held(self, setting: Setting) -> int:
        return sum(self.verdicts[setting])

    def share(self, claim: int, where: Callable[[Setting], bool] = lambda s: True) -> float:
        """The share of settings (those ``where`` accepts) under which claim ``claim`` holds."""
        chosen = [v[claim] for s, v in self.verdicts.items() if where(s)]
        return sum(chosen) / len(chosen) if chosen else math.nan

    def best(self) -> list[Setting]:
        """The settings under which the most claims hold, fewest changes from the default
        first (then grid order)."""
        top = max(self.held(s) for s in self.verdicts)
        tied = [s for s in self.verdicts if self.held(s) == top]
        return sorted(tied, key=lambda s: (len(s.changes()), self.settings.index(s)))

    def marginal(self, key: str, value: Value, claim: int | None = None) -> float:
        """Among the settings with ``key = value``: the share under which ``claim`` holds, or
        (``claim`` None) the mean share of claims that hold."""
        where = [s for s in self.verdicts if s[key] == value]
        if not where:
            return math.nan
        if claim is not None:
            return sum(self.verdicts[s][claim] for s in where) / len(where)
        return sum(self.held(s) for s in where) / (len(where) * len(self.claims))

    def histogram(self) -> list[int]:
        """How many settings hold 0, 1, ..., len(claims) claims."""
        counts = [0] * (len(self.claims) + 1)
        for s in self.verdicts:
            counts[self.held(s)] += 1
        return counts


def build_map(settings: Iterable[Setting], runs: Mapping[RunKey, Sequence[RunResult]]) -> ClaimMap:
    """Decide every setting (:func:`decide`); every setting must yield the same claims."""
    claims: list[tuple[str, str]] | None = None
    verdicts: dict[Setting, list[bool]] = {}
    evidence: dict[Setting, list[str]] = {}
    for setting in settings:
        decided = decide(setting, runs)
        keys = [(c.key, c.text) for c in decided]
        if claims is None:
            claims = keys
        elif keys != claims:
            raise ValueError(f"setting {setting.label()} decided other claims: {keys}.")
        verdicts[setting] = [c.reproduced for c in decided]
        evidence[setting] = [c.evidence for c in decided]
    if claims is None:
        raise ValueError("no setting to decide.")
    return ClaimMap(claims, verdicts, evidence)
