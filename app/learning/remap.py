"""Carrying learned models across a change of mission, by names (docs/method.md, "When a mission
changes").

A mission change (a detail added under a service, a service or situation added, a detail dropped,
a time slot renamed) renumbers the negotiation's contexts, pairs and successor columns. What a
learner learned is tied to *names*: the time slot and situation of a context, the kind, service
and detail of a state or an action. :func:`remap_learner` builds a fresh learner of the new
mission (same class, same parameters) and copies every exported table entry whose names exist in
both missions onto it; successor columns are matched by the name of the successor state. What is
new starts as a fresh learner has it; what was removed leaves the model.

``renames`` carries statistics across a rename::

    {"time_slots": {"am": "morning"}, "situations": {...}, "services": {...},
     "details": {"cha": "tea", "ProvideDrink/hot_water": "water"}}

A plain detail key renames that detail under every service that has it; a key
``"Service/detail"`` (the old service name) renames it under that service only, and wins over a
plain key. Old names are the old mission's, new names the new mission's.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, TypeVar

import numpy as np

from .learners.base import TabularLearner
from .mission import Mission
from .space import Action, NegotiationSpace, StateInfo, StateKind, space_for
from .types import IntArray, Transition

__all__ = [
    "MissionDiff",
    "NamesDiff",
    "Renames",
    "RenamesError",
    "SpaceMap",
    "check_renames",
    "diff_missions",
    "remap_learner",
]

_SECTIONS = ("time_slots", "situations", "services", "details")
_EMPTY: Mapping[str, str] = MappingProxyType({})

L = TypeVar("L", bound=TabularLearner[Any])


class RenamesError(ValueError):
    """A renames map that cannot be applied, with the entry that is wrong."""


# -- renames -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Renames:
    """Old name -> new name, per kind of name; every section may be empty.

    ``details`` keys are a detail name (under every service that has it) or
    ``"OldService/detail"`` (under that service only).
    """

    time_slots: Mapping[str, str] = field(default_factory=lambda: _EMPTY)
    situations: Mapping[str, str] = field(default_factory=lambda: _EMPTY)
    services: Mapping[str, str] = field(default_factory=lambda: _EMPTY)
    details: Mapping[str, str] = field(default_factory=lambda: _EMPTY)

    def __post_init__(self) -> None:
        for section in _SECTIONS:
            value = getattr(self, section)
            if not isinstance(value, Mapping):
                raise RenamesError(
                    f"renames.{section}: expected an object of old name -> new name, got "
                    f"{type(value).__name__}."
                )
            for old, new in value.items():
                if not isinstance(old, str) or not old:
                    raise RenamesError(f"renames.{section}: {old!r} is not a name.")
                if not isinstance(new, str) or not new:
                    raise RenamesError(
                        f"renames.{section}.{old}: expected the new name (a string), got {new!r}."
                    )
            object.__setattr__(self, section, MappingProxyType(dict(value)))

    @classmethod
    def from_dict(cls, obj: object) -> Renames:
        """Parse plain data (a request body); ``None`` is no renames.

        Raises :class:`RenamesError` naming the entry that is wrong."""
        if obj is None:
            return cls()
        if not isinstance(obj, Mapping):
            raise RenamesError(f"renames: expected an object, got {type(obj).__name__}.")
        unknown = sorted(str(k) for k in obj if k not in _SECTIONS)
        if unknown:
            raise RenamesError(
                f"renames: unknown field {unknown[0]!r}; allowed: {', '.join(_SECTIONS)}."
            )
        return cls(**{k: obj[k] for k in _SECTIONS if k in obj})

    def to_dict(self) -> dict[str, dict[str, str]]:
        return {s: dict(getattr(self, s)) for s in _SECTIONS if getattr(self, s)}

    def __bool__(self) -> bool:
        return any(getattr(self, s) for s in _SECTIONS)


def _injective(
    section: str,
    mapping: Mapping[str, str | None],
    keys: Mapping[str, str],
    what: str,
    where: str = "",
) -> None:
    """Raise if two old names land on one new name (``keys``: renamed old name -> its key)."""
    owner: dict[str, str] = {}
    for old, new in mapping.items():
        if new is None:
            continue
        if new in owner:
            first, second = owner[new], old
            blame, other = (second, first) if second in keys else (first, second)
            raise RenamesError(
                f"renames.{section}.{keys[blame]}: {new!r} would also be the new name of the "
                f"old {what} {other!r}{where}; two old names cannot become one."
            )
        owner[new] = old


def _simple_map(
    section: str, what: str, old: tuple[str, ...], new: tuple[str, ...], renames: Mapping[str, str]
) -> dict[str, str | None]:
    for key, target in renames.items():
        if key not in old:
            raise RenamesError(
                f"renames.{section}.{key}: there is no {what} {key!r} in the old "
                f"mission; its {section.replace('_', ' ')}: {list(old)}."
            )
        if target not in new:
            raise RenamesError(
                f"renames.{section}.{key}: {target!r} is not a {what} of the new "
                f"mission; its {section.replace('_', ' ')}: {list(new)}."
            )
    out: dict[str, str | None] = {}
    for name in old:
        target = renames.get(name, name)
        out[name] = target if target in new else None
    _injective(section, out, {k: k for k in renames}, what)
    return out


@dataclass(frozen=True)
class _Names:
    """Old name -> new name (None: removed) for every name of the old mission."""

    time_slots: dict[str, str | None]
    situations: dict[str, str | None]
    services: dict[str, str | None]
    details: dict[tuple[str, str], str | None]  # (old service, old detail) -> new detail

    @classmethod
    def build(cls, old: Mission, new: Mission, renames: Renames | None) -> _Names:
        r = renames or Renames()
        slots = _simple_map(
            "time_slots",
            "time slot",
            tuple(s.name for s in old.time_slots),
            tuple(s.name for s in new.time_slots),
            r.time_slots,
        )
        situations = _simple_map(
            "situations", "situation", old.situations, new.situations, r.situations
        )
        services = _simple_map(
            "services",
            "service",
            tuple(s.name for s in old.services),
            tuple(s.name for s in new.services),
            r.services,
        )
        new_details = {s.name: s.details for s in new.services}
        old_details = {s.name: s.details for s in old.services}
        qualified: dict[tuple[str, str], tuple[str, str]] = {}  # (service, detail) -> (target, key)
        plain: dict[str, str] = {}
        for key, target in r.details.items():
            if "/" in key:
                owner, _, name = key.partition("/")
                if owner not in old_details:
                    raise RenamesError(
                        f"renames.details.{key}: there is no service {owner!r} "
                        f"in the old mission; its services: {list(old_details)}."
                    )
                if name not in old_details[owner]:
                    raise RenamesError(
                        f"renames.details.{key}: {owner} has no detail "
                        f"{name!r} in the old mission; its details: "
                        f"{list(old_details[owner])}."
                    )
                qualified[(owner, name)] = (target, key)
            else:
                if not any(key in d for d in old_details.values()):
                    raise RenamesError(
                        f"renames.details.{key}: no service of the old mission "
                        f"has the detail {key!r}."
                    )
                plain[key] = target
        details: dict[tuple[str, str], str | None] = {}
        for service in old.services:
            image = services[service.name]
            per: dict[str, str | None] = {}
            keys: dict[str, str] = {}
            for detail in service.details:
                if (service.name, detail) in qualified:
                    target, key = qualified[(service.name, detail)]
                elif detail in plain:
                    target, key = plain[detail], detail
                else:
                    target, key = detail, ""
                if key:
                    keys[detail] = key
                if image is None:
                    per[detail] = None
                    continue
                if key and target not in new_details[image]:
                    hint = (
                        ""
                        if "/" in key
                        else (
                            f" (a plain key renames {detail!r} under every service that has it; "
                            f"'{service.name}/{detail}' names one)"
                        )
                    )
                    raise RenamesError(
                        f"renames.details.{key}: {target!r} is not a detail of {image} in the "
                        f"new mission; its details: {list(new_details[image])}{hint}."
                    )
                per[detail] = target if target in new_details[image] else None
            _injective("details", per, keys, "detail", f" of {service.name}")
            for detail, image_detail in per.items():
                details[(service.name, detail)] = image_detail
        return cls(slots, situations, services, details)

    def state(self, info: StateInfo) -> StateInfo | None:
        service = detail = None
        if info.service is not None:
            service = self.services[info.service]
            if service is None:
                return None
        if info.detail is not None:
            assert info.service is not None
            detail = self.details[(info.service, info.detail)]
            if detail is None:
                return None
        return StateInfo(info.kind, service, detail)

    def action(self, action: Action) -> Action | None:
        mapped = self.state(StateInfo(StateKind.OBSERVE, action.service, action.detail))
        return None if mapped is None else Action(action.kind, mapped.service, mapped.detail)


def check_renames(old: Mission, new: Mission, renames: Renames) -> None:
    """Raise :class:`RenamesError` naming the first entry of ``renames`` that cannot apply from
    ``old`` to ``new``: an old name the old mission lacks, a new name the new mission lacks, or two
    old names that would become one."""
    _Names.build(old, new, renames)


# -- the index map ------------------------------------------------------------------------------
class SpaceMap:
    """Where each index of ``old``'s negotiation space is in ``new``'s (-1 / None: removed).

    Arrays (read-only, int64): ``contexts`` (C_old,), ``states`` (L_old + 1,) with END -> END,
    ``actions`` (P_old,) and ``columns`` (P_old, M_old): the new successor column of each old
    one, matched by the successor state's name (-1 for padding, a removed successor, or a
    removed pair).
    """

    def __init__(
        self, old: NegotiationSpace, new: NegotiationSpace, renames: Renames | None = None
    ) -> None:
        self.old, self.new = old, new
        names = _Names.build(old.mission, new.mission, renames)
        self.names = names
        slots_new = {s.name: i for i, s in enumerate(new.mission.time_slots)}
        sits_new = {s: i for i, s in enumerate(new.mission.situations)}
        contexts = np.full(old.n_contexts, -1, dtype=np.int64)
        for c in range(old.n_contexts):
            slot, situation = old.mission.context_names(c)
            slot2, situation2 = names.time_slots[slot], names.situations[situation]
            if slot2 is not None and situation2 is not None:
                contexts[c] = slots_new[slot2] * len(sits_new) + sits_new[situation2]
        state_index = {info: i for i, info in enumerate(new.states)}
        states = np.full(old.n_states + 1, -1, dtype=np.int64)
        for s, info in enumerate(old.states):
            mapped = names.state(info)
            if mapped is not None:
                states[s] = state_index.get(mapped, -1)
        states[old.END] = new.END
        actions = np.full(old.n_actions, -1, dtype=np.int64)
        for p, action in enumerate(old.actions):
            target = names.action(action)
            if target is not None:
                actions[p] = new._action_index.get(target, -1)
        columns = np.full((old.n_actions, old.max_succ), -1, dtype=np.int64)
        for p in range(old.n_actions):
            p2 = int(actions[p])
            if p2 < 0:
                continue
            for j in np.flatnonzero(old.succ_mask[p]):
                s2 = int(states[old.succ[p, j]])
                if s2 >= 0:
                    columns[p, j] = new._succ_column[p2].get(s2, -1)
        for arr in (contexts, states, actions, columns):
            arr.setflags(write=False)
        # Flat (source, target) positions of the kept entries, per table shape (``_copy``).
        self._flat: dict[
            tuple[str, tuple[int, ...], tuple[int, ...]], tuple[IntArray, IntArray]
        ] = {}
        self.contexts: IntArray = contexts
        self.states: IntArray = states
        self.actions: IntArray = actions
        self.columns: IntArray = columns

    @classmethod
    def between(cls, old: Mission, new: Mission, renames: Renames | None = None) -> SpaceMap:
        return cls(space_for(old), space_for(new), renames)

    @staticmethod
    def _get(table: IntArray, index: int, name: str) -> int | None:
        if isinstance(index, bool) or not 0 <= index < table.shape[0]:
            raise ValueError(f"{name} must be in [0, {table.shape[0]}), got {index!r}.")
        out = int(table[index])
        return None if out < 0 else out

    def context(self, c: int) -> int | None:
        return self._get(self.contexts, c, "context")

    def state(self, s: int) -> int | None:
        """A non-terminal local state (END is :meth:`next_state`'s)."""
        return self._get(self.states[:-1], s, "state")

    def action(self, a: int) -> int | None:
        return self._get(self.actions, a, "action")

    def next_state(self, s: int) -> int | None:
        """A successor state: any local state or END (which stays END)."""
        return self._get(self.states, s, "next_state")

    def sample(
        self, context: int, state: int, action: int, next_state: int
    ) -> tuple[int, int, int, int] | None:
        """(context, state, action, next_state) in the new space, or None if any part is gone."""
        c, s = self.context(context), self.state(state)
        a, n = self.action(action), self.next_state(next_state)
        if c is None or s is None or a is None or n is None:
            return None
        return c, s, a, n

    def transition(self, tr: Transition) -> Transition | None:
        """A journal sample carried to the new space (reward and signal as recorded), or None."""
        mapped = self.sample(tr.context, tr.state, tr.action, tr.next_state)
        if mapped is None:
            return None
        c, s, a, n = mapped
        return Transition(tr.episode, c, s, a, tr.reward, n, tr.signal)

    def kept_contexts(self) -> tuple[IntArray, IntArray]:
        """(old indices, new indices) of the contexts in both spaces."""
        old = np.flatnonzero(self.contexts >= 0).astype(np.int64)
        return old, self.contexts[old]

    def kept_actions(self) -> tuple[IntArray, IntArray]:
        """(old indices, new indices) of the pairs in both spaces."""
        old = np.flatnonzero(self.actions >= 0).astype(np.int64)
        return old, self.actions[old]


# -- moving a learner ---------------------------------------------------------------------------
def _axis_indices(
    code: str, smap: SpaceMap, shape_old: tuple[int, ...]
) -> list[tuple[list[np.ndarray], list[np.ndarray]]]:
    """Blocks of (old indices per axis, new indices per axis) covering every kept entry."""
    c_old, c_new = smap.kept_contexts()
    fixed_old: list[np.ndarray] = []
    fixed_new: list[np.ndarray] = []
    for ch, n in zip(code, shape_old, strict=True):
        if ch == "C":
            fixed_old.append(c_old)
            fixed_new.append(c_new)
        elif ch in "234":
            fixed_old.append(np.arange(n))
            fixed_new.append(np.arange(n))
        else:
            fixed_old.append(np.empty(0, dtype=np.int64))  # filled per pair below
            fixed_new.append(np.empty(0, dtype=np.int64))
    if "P" not in code:
        if "M" in code:
            raise ValueError(f"shape code {code!r}: M needs P")
        return [(fixed_old, fixed_new)]
    p_axis = code.index("P")
    m_axis = code.find("M")
    blocks = []
    for p_old, p_new in zip(*smap.kept_actions(), strict=True):
        src, dst = list(fixed_old), list(fixed_new)
        src[p_axis], dst[p_axis] = np.asarray([p_old]), np.asarray([p_new])
        if m_axis >= 0:
            cols = smap.columns[p_old]
            j_old = np.flatnonzero(cols >= 0)
            src[m_axis], dst[m_axis] = j_old, cols[j_old]
        blocks.append((src, dst))
    return blocks


def _flat_indices(
    code: str, smap: SpaceMap, shape_old: tuple[int, ...], shape_new: tuple[int, ...]
) -> tuple[IntArray, IntArray]:
    """The kept entries of a table of shape code ``code`` as flat positions in the old and the
    new table, computed once per map and shape (a change moves many learners alike)."""
    key = (code, shape_old, shape_new)
    found = smap._flat.get(key)
    if found is None:
        src: list[np.ndarray] = [np.empty(0, dtype=np.int64)]
        dst: list[np.ndarray] = [np.empty(0, dtype=np.int64)]
        for old_axes, new_axes in _axis_indices(code, smap, shape_old):
            src.append(np.ravel_multi_index(np.ix_(*old_axes), shape_old).ravel())
            dst.append(np.ravel_multi_index(np.ix_(*new_axes), shape_new).ravel())
        found = (np.concatenate(src).astype(np.int64), np.concatenate(dst).astype(np.int64))
        smap._flat[key] = found
    return found


def _copy(source: np.ndarray, target: np.ndarray, code: str, smap: SpaceMap) -> None:
    src, dst = _flat_indices(code, smap, source.shape, target.shape)
    flat = target.reshape(-1)  # a view: the fresh learner's tables are contiguous
    if not np.shares_memory(flat, target):
        raise ValueError("a learner table is not contiguous")
    flat[dst] = source.reshape(-1)[src]


_MAPS: dict[tuple[str, str, str], SpaceMap] = {}  # the maps of the latest changes


def _space_map(learner: TabularLearner[Any], new: Mission, renames: Renames | None) -> SpaceMap:
    """The map of ``learner``'s mission onto ``new``, shared by the learners of one change
    (a space depends on its mission only, and a mission is named by its fingerprint)."""
    key = (
        learner.mission.fingerprint,
        new.fingerprint,
        json.dumps(renames.to_dict() if renames else {}, sort_keys=True),
    )
    found = _MAPS.get(key)
    if found is None:
        found = SpaceMap(learner.space, space_for(new), renames)
        if len(_MAPS) >= 16:
            _MAPS.clear()
        _MAPS[key] = found
    return found


def remap_learner(learner: L, new: Mission, renames: Renames | None = None) -> L:
    """The learner carried to mission ``new``, by names: a new learner of the same class and
    parameters whose tables are a fresh learner's, with every entry of a (context, pair,
    successor) present in both missions copied from ``learner``.

    Kept: ``episodes`` and ``version``; per kept pair its visits, last executions and every
    table entry (successor columns by the successor's name); per kept context its scalars.
    Dropped: the samples of open episodes, the Q cache. Where a pair loses a successor (a detail
    or service removed), its counts there leave and its reward sums are scaled to the samples
    kept (``TabularLearner._reward_sums``), so its mean reward is unchanged. ``learner`` itself
    is not changed. Raises :class:`RenamesError` for renames that cannot apply.
    """
    smap = _space_map(learner, new, renames)
    fresh = type(learner)(new, learner.params)
    fresh.version = learner.version
    fresh.episodes = learner.episodes
    # By names, renamed as the mission's names were; rules the new mission lacks lie idle.
    fresh.guidance = learner.guidance.renamed(renames) if renames else learner.guidance.copy()
    old_tables = learner._exported()
    new_tables = fresh._exported()
    for name, (source, code) in old_tables.items():
        _copy(source, new_tables[name][0], code, smap)
    lost = smap.columns < 0
    lost &= learner.space.succ_mask & (smap.actions >= 0)[:, None]
    if lost.any():
        for sums, counts in type(learner)._reward_sums.items():
            _rescale_sums(learner, fresh, sums, counts, smap)
    fresh._cache.clear()
    fresh._pending.clear()
    return fresh


def _rescale_sums(
    old: TabularLearner[Any], new: TabularLearner[Any], sums: str, counts: str, smap: SpaceMap
) -> None:
    """Scale the kept reward sums by (count kept / count before) of the same samples."""
    count_code = old._exported()[counts][1]
    m_axis = count_code.index("M")
    before = getattr(old, counts).sum(axis=m_axis)  # the sums' shape, old indices
    moved = np.zeros(getattr(new, sums).shape, dtype=np.float64)
    _copy(before, moved, count_code.replace("M", ""), smap)
    after = getattr(new, counts).sum(axis=m_axis)  # new pairs and contexts: 0, left as they are
    target = getattr(new, sums)
    scale = np.divide(after, moved, out=np.ones_like(moved), where=moved > 0)
    target[...] = np.where(moved > 0, target * scale, target)


# -- what changed -------------------------------------------------------------------------------
@dataclass(frozen=True)
class NamesDiff:
    """One kind of name across a change: kept (new names), added, removed (old names), and the
    kept ones that were renamed, as (old, new)."""

    kept: tuple[str, ...]
    added: tuple[str, ...]
    removed: tuple[str, ...]
    renamed: tuple[tuple[str, str], ...] = ()

    @property
    def changed(self) -> bool:
        return bool(self.added or self.removed or self.renamed)

    def counts(self) -> dict[str, int]:
        return {
            "kept": len(self.kept),
            "added": len(self.added),
            "removed": len(self.removed),
            "renamed": len(self.renamed),
        }

    def to_dict(self) -> dict[str, Any]:
        return {
            "kept": list(self.kept),
            "added": list(self.added),
            "removed": list(self.removed),
            "renamed": [{"old": o, "new": n} for o, n in self.renamed],
        }


def _names_diff(mapping: Mapping[str, str | None], new: tuple[str, ...]) -> NamesDiff:
    images = {v for v in mapping.values() if v is not None}
    return NamesDiff(
        kept=tuple(n for n in new if n in images),
        added=tuple(n for n in new if n not in images),
        removed=tuple(o for o, n in mapping.items() if n is None),
        renamed=tuple((o, n) for o, n in mapping.items() if n is not None and n != o),
    )


@dataclass(frozen=True)
class MissionDiff:
    """What a change of mission keeps, adds and removes. Details and contexts are named
    ``"Service/detail"`` and ``"slot/situation"``; ``pairs`` counts (state, action) pairs of one
    context's negotiation."""

    old: str
    new: str
    time_slots: NamesDiff
    situations: NamesDiff
    services: NamesDiff
    details: NamesDiff
    contexts: NamesDiff
    pairs: dict[str, int]
    rewards_changed: bool
    gamma_changed: bool

    @property
    def unchanged(self) -> bool:
        """Nothing a learner's tables or values depend on differs."""
        return not (
            any(
                d.changed
                for d in (
                    self.time_slots,
                    self.situations,
                    self.services,
                    self.details,
                    self.contexts,
                )
            )
            or self.rewards_changed
            or self.gamma_changed
        )

    def counts(self) -> dict[str, dict[str, int]]:
        return {
            name: getattr(self, name).counts()
            for name in ("time_slots", "situations", "services", "details", "contexts")
        }

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"old": self.old, "new": self.new}
        for name in ("time_slots", "situations", "services", "details", "contexts"):
            out[name] = getattr(self, name).to_dict()
        out["pairs"] = dict(self.pairs)
        out["rewards_changed"] = self.rewards_changed
        out["gamma_changed"] = self.gamma_changed
        return out


def diff_missions(old: Mission, new: Mission, renames: Renames | None = None) -> MissionDiff:
    """What moving from ``old`` to ``new`` with ``renames`` keeps, adds and removes; raises
    :class:`RenamesError` like :func:`check_renames`."""
    smap = SpaceMap.between(old, new, renames)
    names = smap.names
    details: dict[str, str | None] = {}
    for (service, detail), target in names.details.items():
        image = names.services[service]
        details[f"{service}/{detail}"] = None if target is None else f"{image}/{target}"
    contexts: dict[str, str | None] = {}
    for c in range(old.n_contexts):
        c2 = int(smap.contexts[c])
        contexts["/".join(old.context_names(c))] = (
            None if c2 < 0 else "/".join(new.context_names(c2))
        )
    kept_pairs = int(np.count_nonzero(smap.actions >= 0))
    return MissionDiff(
        old=old.name,
        new=new.name,
        time_slots=_names_diff(names.time_slots, tuple(s.name for s in new.time_slots)),
        situations=_names_diff(names.situations, new.situations),
        services=_names_diff(names.services, tuple(s.name for s in new.services)),
        details=_names_diff(
            details, tuple(f"{s.name}/{d}" for s in new.services for d in s.details)
        ),
        contexts=_names_diff(
            contexts, tuple("/".join(new.context_names(c)) for c in range(new.n_contexts))
        ),
        pairs={
            "kept": kept_pairs,
            "added": smap.new.n_actions - kept_pairs,
            "removed": smap.old.n_actions - kept_pairs,
        },
        rewards_changed=old.rewards != new.rewards,
        gamma_changed=old.gamma != new.gamma,
    )
