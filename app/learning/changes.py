"""Changes a learner decided: which contexts it now believes changed, after each update
(docs/method.md §8, "Changes detected").

A learner *decides* that what a person wants in a context changed by its own mechanism: the
routine of ``dts-routine`` (a routine it trusted was refused, and the person then took another
service or detail there, or turned every offer down), or the change test of DTS
(``change_alpha`` > 0: the test restarted the context). After each :meth:`update
<app.learning.learners.base.TabularLearner.update>` the learner's ``changes`` holds the changes
that update decided, as :class:`ContextChange` records (empty for learners without a
mechanism of their own: ``decides_changes`` is False).

For every learner, what the profile says counts too: :class:`ProfileWatch` follows the profile's
belief (``app.learning.beliefs``, docs/method.md §14) over the learner's transitions and reports
the changes of that belief the same way. :class:`ChangeWatch` puts the two together for one
person: the learner's own decisions where it has a mechanism, the profile's where it has none
(or both, with ``profile=True``).

Every record is small and JSON-serialisable (:meth:`ContextChange.to_dict`): the learner's
episode, the context (its index and its names), what the learner believed before and what now
(a service and detail, a service, or nothing), which mechanism decided it, and the evidence: the
person's answers that fired it, with the mechanism's figures. Pure: the standard library and
numpy only.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .beliefs import Answer, BeliefFold, EpisodeEvidence, Item, episode_evidence
from .space import ActionKind, NegotiationSpace, StateKind
from .types import Polarity, Transition

__all__ = [
    "SOURCES",
    "ChangeWatch",
    "ContextChange",
    "ProfileWatch",
    "Step",
    "item_doc",
    "step_of",
]

SOURCES = ("routine", "change_test", "profile")
"""The mechanisms a change can come from: the routine of ``dts-routine``, DTS's change test,
the profile's belief."""


@dataclass(frozen=True, slots=True)
class Step:
    """One answer of the person that is part of the evidence: the learner's episode, the robot's
    action (its name in the mission, ``perform(ProvideDrink, tea)``) and the person's response
    (``accepted``, ``rejected``, ``terminated``, ``answered``, ``human_request``, ``none``), with
    the service or detail they named."""

    episode: int
    action: str
    response: str
    service: str | None = None
    detail: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "episode": self.episode,
            "action": self.action,
            "response": self.response,
            "service": self.service,
            "detail": self.detail,
        }


@dataclass(frozen=True, slots=True)
class ContextChange:
    """A learner decided that what the person wants in one context changed.

    ``episode``: the learner's episode whose update decided it. ``context``: the context's index
    in the learner's mission, with its names (``time_slot``, ``situation``). ``before`` and
    ``now``: what the learner believed the person wants there, before and after (a service and
    detail, a service without a detail, or None: nothing). ``source``: the mechanism (one of
    :data:`SOURCES`). ``evidence``: the answers that fired it, oldest first; ``figures``: the
    mechanism's numbers (refusals counted, the test's chance and level...).
    """

    episode: int
    context: int
    time_slot: str
    situation: str
    before: Item | None
    now: Item | None
    source: str
    evidence: tuple[Step, ...] = ()
    figures: Mapping[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (``json.dumps`` takes it as it is)."""
        return {
            "episode": self.episode,
            "context": self.context,
            "time_slot": self.time_slot,
            "situation": self.situation,
            "before": item_doc(self.before),
            "now": item_doc(self.now),
            "source": self.source,
            "evidence": [s.to_dict() for s in self.evidence],
            "figures": {k: float(v) for k, v in self.figures.items()},
        }


def item_doc(item: Item | None) -> dict[str, str | None] | None:
    """``{"service": ..., "detail": ...}``, or None for nothing."""
    return None if item is None else {"service": item.service, "detail": item.detail}


def response_of(space: NegotiationSpace, tr: Transition) -> tuple[str, str | None, str | None]:
    """The person's response to a visible step, read back from the transition: the response
    word, and the service or detail named (None for a silent step's ``"none"``)."""
    act = space.actions[tr.action]
    kind = act.kind
    nxt = None if tr.next_state == space.END else space.states[tr.next_state]
    if kind is ActionKind.INITIATE:
        return ("accepted" if nxt is not None else "rejected"), None, None
    if kind is ActionKind.PASS:
        if nxt is None:
            return "none", None, None
        return "human_request", (nxt.service if nxt.kind is StateKind.REQUEST else None), None
    if kind is ActionKind.QUERY_TYPE:
        return ("answered", nxt.service, None) if nxt is not None else ("terminated", None, None)
    if kind is ActionKind.QUERY_DETAIL:
        return ("answered", None, nxt.detail) if nxt is not None else ("terminated", None, None)
    if kind is ActionKind.PERFORM:
        return ("accepted" if tr.signal == Polarity.POSITIVE else "rejected"), None, None
    return "none", None, None


def step_of(space: NegotiationSpace, tr: Transition) -> Step:
    """The transition as a :class:`Step` of evidence."""
    response, service, detail = response_of(space, tr)
    return Step(tr.episode, space.action_name(tr.action), response, service, detail)


def context_names(space: NegotiationSpace, context: int) -> tuple[str, str]:
    slot, situation = space.mission.context_names(context)
    return str(slot), str(situation)


# -- the profile's belief -----------------------------------------------------------------------


@dataclass(slots=True)
class _ContextWatch:
    fold: BeliefFold = field(default_factory=BeliefFold)
    steps: dict[int, list[Step]] = field(default_factory=dict)  # episodes of the current run


class ProfileWatch:
    """The profile's belief (``app.learning.beliefs``) per context, followed over a learner's
    transitions: :meth:`observe` takes what one update took and returns the changes of belief
    that the episodes it closed made (source ``"profile"``).

    The evidence of an episode is read from its transitions as the service reads it from the
    history: the person's request after a pass, their answers to questions, the performed
    service accepted or refused, the offer refused (:func:`app.learning.beliefs.episode_evidence`).
    """

    def __init__(self, space: NegotiationSpace) -> None:
        self.space = space
        self._contexts: dict[int, _ContextWatch] = {}
        self._open: dict[int, list[Transition]] = {}

    def observe(self, transitions: Iterable[Transition]) -> list[ContextChange]:
        out: list[ContextChange] = []
        space = self.space
        for tr in transitions:
            if space.silent[tr.action]:
                continue
            rows = self._open.setdefault(tr.episode, [])
            rows.append(tr)
            if tr.next_state == space.END:
                change = self._close(self._open.pop(tr.episode))
                if change is not None:
                    out.append(change)
        return out

    def _close(self, rows: Sequence[Transition]) -> ContextChange | None:
        space = self.space
        first = rows[0]
        steps = [step_of(space, tr) for tr in rows]
        answers = [
            Answer(tr.action, s.response, s.service, s.detail)
            for tr, s in zip(rows, steps, strict=True)
        ]
        ev: EpisodeEvidence = episode_evidence(space, first.episode, answers)
        watch = self._contexts.setdefault(first.context, _ContextWatch())
        before = watch.fold.change
        run = [i for i, _ in watch.fold.run]
        watch.fold.add(ev)
        if ev.relevant:
            watch.steps[first.episode] = steps
        after = watch.fold.change
        if after is None or after is before:
            if not watch.fold.run:  # the run of contradictions is over: its steps are not needed
                watch.steps = {}
            return None
        evidence = [s for seq in sorted(watch.steps) for s in watch.steps[seq] if seq >= after.seq]
        watch.steps = {}
        slot, situation = context_names(space, first.context)
        return ContextChange(
            episode=first.episode,
            context=first.context,
            time_slot=slot,
            situation=situation,
            before=after.before,
            now=after.now,
            source="profile",
            evidence=tuple(evidence),
            figures={"contradicting_episodes": float(len(run) + 1)},
        )


class ChangeWatch:
    """The changes decided for one person after each update: the learner's own
    (``learner.changes``) when it has a mechanism (``learner.decides_changes``), the profile's
    (:class:`ProfileWatch`) when it has none, or both with ``profile=True``.

    Call :meth:`observe` with the transitions right after ``learner.update(transitions)``.
    """

    def __init__(self, learner: Any, *, profile: bool | None = None) -> None:
        self.learner = learner
        own = bool(getattr(learner, "decides_changes", False))
        self.own = own
        self.profile = (
            ProfileWatch(learner.space) if (profile or (profile is None and not own)) else None
        )

    def observe(self, transitions: Sequence[Transition]) -> list[ContextChange]:
        out = list(self.learner.changes) if self.own else []
        if self.profile is not None:
            out += self.profile.observe(transitions)
        return out
