"""Staff guidance: corrections that steer a learner's decisions in one context.

Care staff know things the robot has not learned yet ("she drinks coffee in the morning",
"never offer him the news", "don't disturb her while she works"). A :class:`Rule` says so for one
(time slot, situation) of the mission, by names:

- ``prefers`` (service, detail): along the path that performs it without asking (initiate, infer
  the service, infer the detail) each of the robot's draws takes that path's action with
  probability at least ``1 - PREFER_SLACK``; so the next decisions there perform it without asking
  in at least ``(1 - PREFER_SLACK) ** 3`` of draws. It holds until the person's own answers
  contradict it :data:`CONTRADICTIONS` times in a row (then the person wins: the rule is
  *overridden* and the learner's own beliefs decide again).
- ``avoid`` (service, or service and detail): the robot never chooses to perform it there, nor
  infers it, nor asks a question whose answer could oblige it to. A hard rule.
- ``quiet``: the robot never initiates there; it still answers the person's requests. A hard rule.

What the *person* settles is not overridden: a person who asks for an avoided service by name is
served, as under ``quiet``. Rules steer the action distributions only: the learner's tables learn
from what happens exactly as without them, so lifting a rule leaves the learner's own beliefs.

The learner keeps its rules (:class:`Guidance`, docs/method.md §15) in its state document,
so they are exported, imported, snapshotted and replayed with the rest of the model. Pure:
stdlib and numpy.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

import numpy as np

from .mission import Mission
from .space import Action, ActionKind, NegotiationSpace, StateKind
from .state import StateFormatError
from .types import FloatArray, Polarity, Transition

__all__ = [
    "CONTRADICTIONS",
    "PREFER_SLACK",
    "Guidance",
    "Reason",
    "ReasonCode",
    "Rule",
    "RuleError",
    "RuleKind",
    "Verdict",
    "guidance_from_state",
    "verdict",
]

PREFER_SLACK = 0.01
"""Share of each draw along a ``prefers`` path left to the learner's own distribution."""
CONTRADICTIONS = 2
"""Consecutive contradicting answers of the person that override a ``prefers`` rule."""
_RULE_ID = re.compile(r"^[A-Za-z0-9._:-]{1,128}$")


class RuleKind(StrEnum):
    PREFERS = "prefers"
    AVOID = "avoid"
    QUIET = "quiet"


class Verdict(StrEnum):
    """How an answer of the person bears on a ``prefers`` rule."""

    CONFIRMS = "confirms"
    CONTRADICTS = "contradicts"
    NEUTRAL = "neutral"


class ReasonCode(StrEnum):
    """Why a correction does not fit a mission."""

    BAD_ID = "bad_id"
    UNKNOWN_TIME_SLOT = "unknown_time_slot"
    UNKNOWN_SITUATION = "unknown_situation"
    QUIET_TAKES_NOTHING = "quiet_takes_nothing"
    NEEDS_SERVICE = "needs_service"
    UNKNOWN_SERVICE = "unknown_service"
    NEEDS_DETAIL = "needs_detail"
    UNKNOWN_DETAIL = "unknown_detail"


@dataclass(frozen=True, slots=True)
class Reason:
    """One reason a rule does not fit a mission, with what the caller needs to say it in its
    own words: the ``field`` at fault, the value it ``got``, the values ``allowed`` there, and
    for a detail the ``service`` it belongs to. :meth:`sentence` is the API's wording."""

    code: ReasonCode
    field: str
    kind: RuleKind
    got: str | None = None
    allowed: tuple[str, ...] = ()
    service: str | None = None

    def sentence(self) -> str:
        c, allowed = self.code, ", ".join(self.allowed)
        if c is ReasonCode.BAD_ID:
            return "the correction id must match ^[A-Za-z0-9._:-]{1,128}$."
        if c is ReasonCode.UNKNOWN_TIME_SLOT:
            return f"unknown time slot {self.got!r}; allowed: {list(self.allowed)}"
        if c is ReasonCode.UNKNOWN_SITUATION:
            return f"unknown situation {self.got!r}; allowed: {list(self.allowed)}"
        if c is ReasonCode.QUIET_TAKES_NOTHING:
            return "quiet takes no service or detail: the robot does not initiate at all there."
        if c is ReasonCode.NEEDS_SERVICE:
            return f"{self.kind.value} needs a service: one of {allowed}."
        if c is ReasonCode.UNKNOWN_SERVICE:
            return f"service must be one of {allowed}; got {self.got!r}."
        if c is ReasonCode.NEEDS_DETAIL:
            return f"prefers needs a detail of {self.service}: one of {allowed}."
        return f"detail of {self.service} must be one of {allowed}; got {self.got!r}."


class RuleError(ValueError):
    """A rule that does not fit the mission; ``reasons`` say why (the first is the message)."""

    def __init__(self, reasons: tuple[Reason, ...]) -> None:
        super().__init__(reasons[0].sentence())
        self.reasons = reasons


@dataclass(slots=True)
class Rule:
    """One correction in force. ``since`` is the learner's episode count when it was made;
    ``meta`` is the caller's (author, time, note), kept as given. For ``prefers``: the person's
    answers since, counted (``confirmed``, ``contradicted``, the current run of contradictions
    ``streak``), and ``overridden_at``, the learner episode in which the person won."""

    id: str
    kind: RuleKind
    time_slot: str
    situation: str
    service: str | None = None
    detail: str | None = None
    since: int = 0
    meta: dict[str, Any] = field(default_factory=dict)
    confirmed: int = 0
    contradicted: int = 0
    streak: int = 0
    overridden_at: int | None = None
    # The fingerprint of the mission the rule was last found to fit: a rule checked once is
    # not checked again against the same mission (not part of the state document).
    fits: str | None = field(default=None, compare=False, repr=False)

    @property
    def in_force(self) -> bool:
        return self.overridden_at is None

    def reasons(self, mission: Mission) -> tuple[Reason, ...]:
        """Why the rule does not fit ``mission`` (empty: it fits): the correction's one
        validation, which the API and the console turn into their own words."""
        if self.fits == mission.fingerprint:
            return ()
        kind, out = self.kind, []
        if not _RULE_ID.match(self.id):
            out.append(Reason(ReasonCode.BAD_ID, "correction_id", kind, self.id))
        slots = tuple(t.name for t in mission.time_slots)
        if self.time_slot not in slots:
            out.append(
                Reason(ReasonCode.UNKNOWN_TIME_SLOT, "time_slot", kind, self.time_slot, slots)
            )
        elif self.situation not in mission.situations:
            out.append(
                Reason(
                    ReasonCode.UNKNOWN_SITUATION,
                    "situation",
                    kind,
                    self.situation,
                    mission.situations,
                )
            )
        names = tuple(s.name for s in mission.services)
        if kind is RuleKind.QUIET:
            if self.service is not None or self.detail is not None:
                out.append(Reason(ReasonCode.QUIET_TAKES_NOTHING, "service", kind, self.service))
        elif self.service is None:
            out.append(Reason(ReasonCode.NEEDS_SERVICE, "service", kind, None, names))
        elif self.service not in names:
            out.append(Reason(ReasonCode.UNKNOWN_SERVICE, "service", kind, self.service, names))
        else:
            details = mission.service(self.service).details
            if self.detail is None and kind is RuleKind.PREFERS:
                out.append(
                    Reason(ReasonCode.NEEDS_DETAIL, "detail", kind, None, details, self.service)
                )
            elif self.detail is not None and self.detail not in details:
                out.append(
                    Reason(
                        ReasonCode.UNKNOWN_DETAIL,
                        "detail",
                        kind,
                        self.detail,
                        details,
                        self.service,
                    )
                )
        if not out:
            self.fits = mission.fingerprint
        return tuple(out)

    def check(self, mission: Mission) -> None:
        """:class:`RuleError` (a ``ValueError``) with the reasons the rule does not fit the
        mission: what the mission does not have, or what the kind needs."""
        reasons = self.reasons(mission)
        if reasons:
            raise RuleError(reasons)

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "kind": self.kind.value,
            "time_slot": self.time_slot,
            "situation": self.situation,
            "service": self.service,
            "detail": self.detail,
            "since": self.since,
            "meta": dict(self.meta),
            "confirmed": self.confirmed,
            "contradicted": self.contradicted,
            "streak": self.streak,
            "overridden_at": self.overridden_at,
        }

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any]) -> Rule:
        """The rule of ``to_dict``'s document; ``ValueError`` if it is not one."""
        try:
            meta = doc.get("meta", {})
            rule = cls(
                id=str(doc["id"]),
                kind=RuleKind(doc["kind"]),
                time_slot=str(doc["time_slot"]),
                situation=str(doc["situation"]),
                service=doc.get("service"),
                detail=doc.get("detail"),
                since=doc.get("since", 0),
                meta=dict(meta),
                confirmed=doc.get("confirmed", 0),
                contradicted=doc.get("contradicted", 0),
                streak=doc.get("streak", 0),
                overridden_at=doc.get("overridden_at"),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a correction: {exc}") from None
        for name in ("since", "confirmed", "contradicted", "streak"):
            value = getattr(rule, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{name} must be a whole number >= 0.")
        if rule.overridden_at is not None and (
            isinstance(rule.overridden_at, bool) or not isinstance(rule.overridden_at, int)
        ):
            raise ValueError("overridden_at must be a whole number or null.")
        for name in ("service", "detail"):
            if getattr(rule, name) is not None and not isinstance(getattr(rule, name), str):
                raise ValueError(f"{name} must be text or null.")
        return rule


@dataclass(frozen=True, slots=True)
class _Overlay:
    """One context's rules compiled against a space: allowed pairs and the preferred path."""

    allowed: np.ndarray  # (P,) bool; all True where nothing is forbidden
    path: Mapping[int, int]  # state -> the pair the prefers rule in force takes there
    restricts: bool


def verdict(space: NegotiationSpace, rule: Rule, tr: Transition) -> Verdict:
    """How the person's response recorded in ``tr`` bears on the ``prefers`` rule ``rule``
    (in ``tr``'s context): they took or named what it says, or turned it down or named
    something else."""
    act = space.actions[tr.action]
    kind = act.kind
    nxt = space.state_info(tr.next_state)
    if kind is ActionKind.PERFORM:
        if act.service != rule.service or act.detail != rule.detail:
            return Verdict.NEUTRAL
        if tr.signal is Polarity.POSITIVE:
            return Verdict.CONFIRMS
        return Verdict.CONTRADICTS if tr.signal is Polarity.NEGATIVE else Verdict.NEUTRAL
    if kind is ActionKind.INITIATE:
        return Verdict.CONTRADICTS if tr.signal is Polarity.NEGATIVE else Verdict.NEUTRAL
    if kind is ActionKind.PASS and nxt.kind is StateKind.REQUEST:
        return Verdict.CONFIRMS if nxt.service == rule.service else Verdict.CONTRADICTS
    if kind is ActionKind.QUERY_TYPE and nxt.kind is StateKind.TYPE_KNOWN:
        return Verdict.CONFIRMS if nxt.service == rule.service else Verdict.CONTRADICTS
    if (
        kind is ActionKind.QUERY_DETAIL
        and nxt.kind is StateKind.DETAIL_KNOWN
        and act.service == rule.service
    ):
        return Verdict.CONFIRMS if nxt.detail == rule.detail else Verdict.CONTRADICTS
    return Verdict.NEUTRAL


class Guidance:
    """A learner's rules, in the order they were made, and their compiled overlays."""

    def __init__(self, rules: Iterable[Rule] = ()) -> None:
        self._rules: dict[str, Rule] = {}
        self._compiled: dict[tuple[int, int], _Overlay | None] = {}
        self._space_id = 0
        for rule in rules:
            self._rules[rule.id] = rule

    def __bool__(self) -> bool:
        return bool(self._rules)

    def __len__(self) -> int:
        return len(self._rules)

    @property
    def rules(self) -> tuple[Rule, ...]:
        return tuple(self._rules.values())

    def get(self, rule_id: str) -> Rule | None:
        return self._rules.get(rule_id)

    def add(self, rule: Rule, mission: Mission) -> None:
        """Put ``rule`` in force (replacing one of the same id); ``ValueError`` if it does not
        fit ``mission``."""
        rule.check(mission)
        self._rules.pop(rule.id, None)
        self._rules[rule.id] = replace(rule)
        self._compiled.clear()

    def lift(self, rule_id: str) -> Rule:
        """Take a rule out of force; ``KeyError`` if there is none of that id."""
        rule = self._rules.pop(rule_id)
        self._compiled.clear()
        return rule

    def copy(self) -> Guidance:
        return Guidance(replace(r, meta=dict(r.meta)) for r in self._rules.values())

    def renamed(self, renames: Any) -> Guidance:
        """A copy whose rules use the new names of a mission change's ``renames`` (an
        :class:`app.learning.remap.Renames`: old name -> new name per kind of name; a detail as
        ``"Service/detail"`` or alone)."""
        out = []
        for r in self._rules.values():
            detail = r.detail
            if detail is not None and r.service is not None:
                detail = renames.details.get(
                    f"{r.service}/{detail}", renames.details.get(detail, detail)
                )
            out.append(
                replace(
                    r,
                    meta=dict(r.meta),
                    fits=None,
                    time_slot=renames.time_slots.get(r.time_slot, r.time_slot),
                    situation=renames.situations.get(r.situation, r.situation),
                    service=None
                    if r.service is None
                    else renames.services.get(r.service, r.service),
                    detail=detail,
                )
            )
        return Guidance(out)

    # -- the person's answers ------------------------------------------------------------------
    def observe(self, space: NegotiationSpace, tr: Transition) -> None:
        """Count the person's answer in ``tr`` for the ``prefers`` rules in force there."""
        changed = False
        for rule in self._rules.values():
            if rule.kind is not RuleKind.PREFERS or not rule.in_force:
                continue
            if _context(space.mission, rule) != tr.context:
                continue
            said = verdict(space, rule, tr)
            if said is Verdict.CONFIRMS:
                rule.confirmed += 1
                rule.streak = 0
            elif said is Verdict.CONTRADICTS:
                rule.contradicted += 1
                rule.streak += 1
                if rule.streak >= CONTRADICTIONS:
                    rule.overridden_at = tr.episode
                    changed = True
        if changed:
            self._compiled.clear()

    # -- decisions -----------------------------------------------------------------------------
    def adjust(
        self, space: NegotiationSpace, context: int, state: int, probabilities: FloatArray
    ) -> FloatArray:
        """The distribution over ``state``'s actions once the rules of ``context`` apply."""
        overlay = self._overlay(space, context)
        if overlay is None:
            return probabilities
        actions = space.actions_of(state)
        out = probabilities
        target = overlay.path.get(state)
        if target is not None:
            out = probabilities * PREFER_SLACK
            out[target - actions.start] += 1.0 - PREFER_SLACK
        if overlay.restricts:
            mask = overlay.allowed[actions.start : actions.stop]
            if not mask.all() and mask.any():  # none allowed: the person settled it; serve
                out = np.where(mask, out, 0.0)
                total = float(out.sum())
                out = out / total if total > 0.0 else mask / float(mask.sum())
        return out

    def forbids_initiating(self, space: NegotiationSpace, context: int) -> bool:
        """Whether the rules in force in ``context`` leave the robot no way to initiate there
        (a ``quiet`` correction, or ``avoid`` rules that leave nothing to offer)."""
        overlay = self._overlay(space, context)
        return overlay is not None and not bool(overlay.allowed[space.INITIATE])

    def _overlay(self, space: NegotiationSpace, context: int) -> _Overlay | None:
        if not self._rules:
            return None
        if self._space_id != id(space):
            self._compiled.clear()
            self._space_id = id(space)
        key = (id(space), context)
        if key not in self._compiled:
            self._compiled[key] = _compile(space, context, self._rules.values())
        return self._compiled[key]


def _context(mission: Mission, rule: Rule) -> int | None:
    try:
        return mission.context_index(rule.time_slot, rule.situation)
    except ValueError:
        return None


def _known(mission: Mission, rule: Rule) -> bool:
    """The rule's names are all in ``mission`` (after a mission change they may not be)."""
    try:
        rule.check(mission)
    except ValueError:
        return False
    return True


def _compile(space: NegotiationSpace, context: int, rules: Iterable[Rule]) -> _Overlay | None:
    mission = space.mission
    mine = [r for r in rules if _context(mission, r) == context and _known(mission, r)]
    if not mine:
        return None
    forbidden = np.zeros(space.n_actions, dtype=bool)
    for rule in mine:
        if rule.kind is RuleKind.QUIET:
            forbidden[space.INITIATE] = True
        elif rule.kind is RuleKind.AVOID:
            for p, act in enumerate(space.actions):
                if act.service != rule.service:
                    continue
                if act.kind in (ActionKind.PERFORM, ActionKind.INFER_DETAIL):
                    forbidden[p] |= rule.detail is None or act.detail == rule.detail
                elif act.kind is ActionKind.INFER_TYPE:
                    forbidden[p] |= rule.detail is None
                elif act.kind is ActionKind.QUERY_DETAIL:
                    forbidden[p] = True  # the answer could name what is avoided
    allowed = _live(space, ~forbidden)
    path: dict[int, int] = {}
    preferred = [r for r in mine if r.kind is RuleKind.PREFERS and r.in_force]
    if preferred:
        rule = preferred[-1]  # the latest in force
        assert rule.service is not None
        assert rule.detail is not None
        path = {
            space.OBSERVE: space.INITIATE,
            space.ENGAGED: space.action_index(_action(ActionKind.INFER_TYPE, rule.service)),
            space.type_known_state(rule.service): space.action_index(
                _action(ActionKind.INFER_DETAIL, rule.service, rule.detail)
            ),
        }
    restricts = not bool(allowed.all())
    if not path and not restricts:
        return None
    allowed.setflags(write=False)
    return _Overlay(allowed=allowed, path=path, restricts=restricts)


def _action(kind: ActionKind, service: str, detail: str | None = None) -> Action:
    return Action(kind, service, detail)


def _live(space: NegotiationSpace, allowed: np.ndarray) -> np.ndarray:
    """``allowed`` without the robot's choices that lead only to states where every action is
    forbidden (a question whose answer could be an avoided service, an inference into one).
    ``pass`` stays: what follows it is the person's choice."""
    allowed = allowed.copy()
    allowed[space.PASS] = True
    end = space.END
    while True:
        live = np.zeros(space.n_states + 1, dtype=bool)
        live[end] = True
        for s in range(space.n_states):
            acts = space.actions_of(s)
            live[s] = bool(allowed[acts.start : acts.stop].any())
        changed = False
        for p in range(space.n_actions):
            if not allowed[p] or p == space.PASS:
                continue
            succ = space.succ[p][space.succ_mask[p]]
            if not live[succ].all():
                allowed[p] = False
                changed = True
        if not changed:
            return allowed


def guidance_from_state(doc: Any) -> Guidance:
    """The rules of a learner state document's ``guidance`` list; ``StateFormatError``."""
    if doc is None:
        return Guidance()
    if not isinstance(doc, list):
        raise StateFormatError("guidance must be a list of corrections.")
    rules = []
    for i, item in enumerate(doc):
        if not isinstance(item, Mapping):
            raise StateFormatError(f"guidance[{i}] must be an object.")
        try:
            rules.append(Rule.from_dict(item))
        except ValueError as exc:
            raise StateFormatError(f"guidance[{i}]: {exc}") from None
    return Guidance(rules)
