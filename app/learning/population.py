"""Families of simulated people and the oracle, for the robustness suite (docs/method.md §12,
"Robustness").

A *family* is a kind of person (the paper's users, a shared home, shy people, noisy answerers,
...). Its generator turns a seeded numpy Generator into ``n_persons`` :class:`Person` objects:
the person's routines (need rules) at every event, the contexts of their events, and how they
answer. Everything random about the people is drawn here, before any learner runs, and their
coin flips come from a table of uniforms (:func:`uniforms_for`), so every learner and the oracle
meet the same events and the same flips (common random numbers).

The *oracle* knows every need: it initiates, infers and performs when a need exists and the
person is available, and passes otherwise (:func:`oracle_action`). It plays through the same
negotiation rules (:func:`app.learning.negotiation.outcome`) and the same person's responses as
the learners do; the suite reports each learner's reward as a share of the oracle's.

The *one-miss oracle* (:func:`run_one_miss`) is the best a learner can do without foreseeing a
change: it is the oracle, except at the first visit of each changed context after a change,
where it still acts on the old routine (performs it and is refused, or offers where nothing is
wanted any more); from then on it knows the new one. The suite reports the share of it in the
events after the change too.

*True changes* (:func:`true_changes`) are the contexts whose routine a change replaced or ended;
:func:`match_changes` counts the changes a learner decided (``app.learning.changes``) against
them: caught, how late, and false alarms (:func:`match_contexts` takes the decided changes as
events and contexts, as ``attune fleet simulate`` reads them from the service). The issue's
targets for detection are :data:`CAUGHT_TARGET` of the abrupt changes caught within
:data:`CAUGHT_VISITS` visits of the changed context, and at most :data:`FALSE_ALARMS_TARGET`
false alarm per person per :data:`EVENTS_PER_MONTH` events when nothing changes.

Pure: the standard library and numpy only.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from .changes import ChangeWatch, ContextChange
from .learners import make_learner
from .learners.base import TabularLearner
from .mission import Mission
from .negotiation import EXPECTS, Response, Tally, outcome
from .simulation import Need, Reaction, UserProfile, drift, event_stream, random_profile, respond
from .space import Action, ActionKind, NegotiationSpace, StateKind, space_for
from .types import Decision, FloatArray, IntArray, Observation, Transition

__all__ = [
    "CAUGHT_TARGET",
    "CAUGHT_VISITS",
    "DEFAULT_EVENTS",
    "DEFAULT_FAMILIES",
    "EVENTS_PER_MONTH",
    "FALSE_ALARMS_TARGET",
    "FAMILIES",
    "NOISE_RANGE",
    "Detection",
    "Family",
    "FamilyRun",
    "Person",
    "serve_event",
    "TrueChange",
    "change_event",
    "match_changes",
    "match_contexts",
    "oracle_action",
    "run_family",
    "run_learner",
    "run_one_miss",
    "run_oracle",
    "true_changes",
    "uniforms_for",
]

DEFAULT_EVENTS = 160  # events per person in the suite
STEP_UNIFORMS = 4  # per visible step: the reaction, an abort, a noise coin, the noise pick
STEP_COLUMNS = 4 * STEP_UNIFORMS  # an episode has at most four visible steps
P_NEED = 0.7  # the share of events in one of the person's need contexts (§11)
NOISE_RANGE = (0.10, 0.20)  # noisy answerers: the share of answers given at random
REFUSE_RANGE = (0.40, 0.60)  # people who often refuse: the chance of accepting an offer
RAMP = 40  # gradual drift: events over which the new routines take over
CAUGHT_TARGET, CAUGHT_VISITS = 0.90, 3  # abrupt changes caught within 3 visits
FALSE_ALARMS_TARGET = 1.0  # per person per EVENTS_PER_MONTH events, when nothing changes
EVENTS_PER_MONTH = 500
"""A person-month of events: the unit false alarms are counted in (about 16 events a day)."""


def change_event(n_events: int) -> int:
    """The event (0-based) at which the changing families change: 5/8 of the way (event 100
    of 160)."""
    return (5 * n_events) // 8


@dataclass(frozen=True)
class Person:
    """A simulated person through ``len(contexts)`` events.

    ``profiles[schedule[e]]`` holds the routines (need rules) and response parameters in force
    at event ``e``; ``contexts[e]`` is that event's context. ``p_random`` is the share of answers
    (to an offer, a question or a service) given at random. ``change_at`` is the first event of
    the change of routines the suite's windows are about, or None when the routines never
    change; ``change_points`` are the first events of every change (by default ``change_at``
    alone).
    """

    profiles: tuple[UserProfile, ...]
    schedule: IntArray
    contexts: IntArray
    p_random: float = 0.0
    change_at: int | None = None
    change_points: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if len(self.schedule) != len(self.contexts):
            raise ValueError("schedule and contexts must have one entry per event.")
        if not 0.0 <= self.p_random <= 1.0:
            raise ValueError(f"p_random must be in [0, 1], got {self.p_random!r}.")
        if not self.change_points and self.change_at is not None:
            object.__setattr__(self, "change_points", (self.change_at,))
        if list(self.change_points) != sorted(set(self.change_points)) or any(
            not 0 < p < len(self.contexts) for p in self.change_points
        ):
            raise ValueError("change_points must be increasing events after the first.")

    @property
    def n_events(self) -> int:
        return len(self.contexts)

    def profile_at(self, event: int) -> UserProfile:
        """The routines and response parameters in force at ``event`` (0-based)."""
        return self.profiles[int(self.schedule[event])]

    def respond(
        self, space: NegotiationSpace, event: int, state: int, action: int, uniforms: np.ndarray
    ) -> tuple[Reaction, bool]:
        """The person's reaction to a visible action at ``event``, and whether it was random.

        ``uniforms`` are the step's four numbers: the reaction and an abort (as
        :func:`app.learning.simulation.respond` takes them), then whether the answer is random
        (below ``p_random``) and which one. A robot that passes gets no answer, so noise never
        makes a person speak first.
        """
        profile = self.profile_at(event)
        context = int(self.contexts[event])
        kind = space.actions[action].kind
        if kind is not ActionKind.PASS and self.p_random > 0.0 and uniforms[2] < self.p_random:
            return _random_reaction(space, state, action, float(uniforms[3])), True
        return respond(space, profile, context, state, action, uniforms[:2]), False


def _random_reaction(space: NegotiationSpace, state: int, action: int, u: float) -> Reaction:
    """A response the action allows, drawn uniformly by ``u``, with a uniform name if it needs
    one (the service of an answer to "which service?", the detail of one to "which detail?")."""
    act = space.actions[action]
    allowed = EXPECTS[act.kind]
    scaled = u * len(allowed)
    said = allowed[min(int(scaled), len(allowed) - 1)]
    rest = scaled - int(scaled)  # another uniform, for the name
    mission = space.mission
    service: str | None = None
    detail: str | None = None
    if said is Response.ANSWERED and act.kind is ActionKind.QUERY_TYPE:
        names = [s.name for s in mission.services]
        service = names[min(int(rest * len(names)), len(names) - 1)]
    elif said is Response.ANSWERED:  # query_detail: a detail of the service asked about
        assert act.service is not None
        details = next(s.details for s in mission.services if s.name == act.service)
        detail = details[min(int(rest * len(details)), len(details) - 1)]
    result = outcome(space, action, said, service=service, detail=detail)
    return Reaction(said, result.reward, result.next_state, result.signal, service, detail)


# -- the oracle -------------------------------------------------------------------------------


def oracle_action(space: NegotiationSpace, need: Need | None, available: bool, state: int) -> int:
    """The oracle's action in ``state``, knowing the person's current ``need``.

    OBSERVE: initiate when there is a need and the person is available, else pass. ENGAGED:
    infer the needed service. TYPE_KNOWN(k): infer the needed detail (when a random answer led
    to another service than the need's, or there is no need, the first detail: a question
    would cost more). It never asks: it knows the answer.
    """
    mission = space.mission
    info = space.states[state]
    if state == space.OBSERVE:
        return space.INITIATE if need is not None and available else space.PASS
    if info.kind is StateKind.ENGAGED:
        k = need.service if need is not None else 0
        return space.action_index(Action(ActionKind.INFER_TYPE, mission.services[k].name))
    if info.kind is StateKind.TYPE_KNOWN:
        assert info.service is not None
        service = next(s for s in mission.services if s.name == info.service)
        wanted = need is not None and mission.services[need.service].name == info.service
        d = need.detail if wanted and need is not None else 0
        return space.action_index(Action(ActionKind.INFER_DETAIL, info.service, service.details[d]))
    actions = space.actions_of(state)  # REQUEST: respond; DETAIL_KNOWN: perform
    return actions.start


def run_oracle(space: NegotiationSpace, person: Person, uniforms: np.ndarray) -> FloatArray:
    """The oracle's reward per episode through ``person``'s events (silent steps included)."""
    mission = space.mission
    out = np.zeros(person.n_events, dtype=np.float64)
    for e in range(person.n_events):
        context = int(person.contexts[e])
        need = person.profile_at(e).need_at(context)
        available = mission.context_names(context)[1] not in mission.unavailable_situations
        state, step, total = space.OBSERVE, 0, 0.0
        while state != space.END:
            action = oracle_action(space, need, available, state)
            if space.silent[action]:
                total += float(space.silent_reward[action])
                state = int(space.silent_next[action])
                continue
            cols = uniforms[e, STEP_UNIFORMS * step : STEP_UNIFORMS * (step + 1)]
            reaction, _ = person.respond(space, e, state, action, cols)
            total += reaction.reward
            state, step = reaction.next_state, step + 1
        out[e] = total
    return out


def run_one_miss(space: NegotiationSpace, person: Person, uniforms: np.ndarray) -> FloatArray:
    """The one-miss oracle's reward per episode: the oracle, except at the first visit of each
    changed context after each change point, where it acts on the need the context had just
    before the change (it performs the old routine and is refused, or offers where nothing is
    wanted any more, or waits where a new routine begins); from then on it knows every need.
    For a person whose routines never change it is the oracle."""
    mission = space.mission
    points = person.change_points
    out = np.zeros(person.n_events, dtype=np.float64)
    missed: set[tuple[int, int]] = set()
    for e in range(person.n_events):
        context = int(person.contexts[e])
        need = person.profile_at(e).need_at(context)
        regime = sum(1 for p in points if p <= e)
        if regime:
            old = person.profile_at(points[regime - 1] - 1).need_at(context)
            if old != need and (regime, context) not in missed:
                missed.add((regime, context))
                need = old
        available = mission.context_names(context)[1] not in mission.unavailable_situations
        state, step, total = space.OBSERVE, 0, 0.0
        while state != space.END:
            action = oracle_action(space, need, available, state)
            if space.silent[action]:
                total += float(space.silent_reward[action])
                state = int(space.silent_next[action])
                continue
            cols = uniforms[e, STEP_UNIFORMS * step : STEP_UNIFORMS * (step + 1)]
            reaction, _ = person.respond(space, e, state, action, cols)
            total += reaction.reward
            state, step = reaction.next_state, step + 1
        out[e] = total
    return out


def run_learner(
    learner: TabularLearner[Any],
    person: Person,
    uniforms: np.ndarray,
    rng: np.random.Generator,
    *,
    changes: list[tuple[int, ContextChange]] | None = None,
    on_decision: Callable[[int, Decision, list[Transition]], None] | None = None,
) -> FloatArray:
    """A fresh learner through ``person``'s events; its reward per episode (as the paper's
    experiments count it: silent steps included). With ``changes``, the changes decided for
    the person after each update (``app.learning.changes.ChangeWatch``: the learner's own, or
    the profile's for a learner without a mechanism) are appended to it as (event, change).
    ``on_decision(event, decision, transitions)`` is told each decision once the learner has
    learned its transitions (a log of the run: ``app.learning.whatif.log_person``)."""
    watch = ChangeWatch(learner) if changes is not None else None
    out = np.zeros(person.n_events, dtype=np.float64)
    for e in range(person.n_events):

        def learned(batch: list[Transition], decision: Decision, e: int = e) -> None:
            if on_decision is not None:
                on_decision(e, decision, batch)
            if watch is not None and changes is not None:
                changes.extend((e, change) for change in watch.observe(batch))

        out[e] = serve_event(learner, person, uniforms, e, rng, on_batch=learned)
    return out


def serve_event(
    learner: TabularLearner[Any],
    person: Person,
    uniforms: np.ndarray,
    e: int,
    rng: np.random.Generator,
    *,
    on_batch: Callable[[list[Transition], Decision], None] | None = None,
) -> float:
    """``learner`` serves ``person``'s event ``e`` (episode ``e + 1``), learning each decision's
    transitions as it goes, as :func:`run_learner` does at each event; the episode's reward.
    ``on_batch(transitions, decision)`` is told each decision once it is learned."""
    space = learner.space
    context, episode = int(person.contexts[e]), e + 1
    state, step = space.OBSERVE, 0
    tally = Tally()
    while state != space.END:
        assert STEP_UNIFORMS * (step + 1) <= uniforms.shape[1], "too long an episode"
        decision = learner.select_action(Observation(context, state, episode), rng)
        cols = uniforms[e, STEP_UNIFORMS * step : STEP_UNIFORMS * (step + 1)]
        reaction, _ = person.respond(space, e, decision.state, decision.action, cols)
        batch = decision.transitions(episode, reaction.reward, reaction.next_state, reaction.signal)
        learner.update(batch)
        if on_batch is not None:
            on_batch(batch, decision)
        for t in batch:
            tally.step(space, t.state, t.action, t.reward, t.next_state, t.signal)
        state, step = reaction.next_state, step + 1
    return float(tally.reward)


@dataclass(frozen=True)
class TrueChange:
    """A change of a person's routine in one context: from ``start`` (the change point) until
    ``stop`` (the next change point, or the end), the routine ``before`` is replaced by
    ``after`` (None: nothing is wanted there any more). A gradual drift's ``after`` is the
    routine it ends at."""

    context: int
    start: int
    stop: int
    before: Need
    after: Need | None


def true_changes(person: Person) -> list[TrueChange]:
    """The contexts whose routine each change point replaced or ended (a context that gains a
    routine where it had none is a new routine to learn, not a change to detect)."""
    out = []
    points = person.change_points
    for i, start in enumerate(points):
        stop = points[i + 1] if i + 1 < len(points) else person.n_events
        before = person.profile_at(start - 1)
        after = person.profile_at(stop - 1)
        for need in before.needs:
            now = after.need_at(need.context)
            if now != need:
                out.append(TrueChange(need.context, start, stop, need, now))
    return out


@dataclass
class Detection:
    """Changes decided for persons, counted against their true changes (:func:`match_changes`).

    ``caught``: per true change caught, (events after its change point, visits of its context
    from the change point up to and including the one whose update decided it); ``missed``:
    true changes not caught before the next change point or the end; ``false_alarms``: decided
    changes that match no true change; ``events``: the persons' events in all.
    """

    caught: list[tuple[int, int]] = field(default_factory=list)
    missed: int = 0
    false_alarms: int = 0
    events: int = 0
    persons: int = 0
    source: str = ""  # "learner" (its own mechanism) or "profile"

    @property
    def true(self) -> int:
        return len(self.caught) + self.missed

    def caught_within(self, visits: int = CAUGHT_VISITS) -> int:
        """The true changes caught within ``visits`` visits of their context from their change
        point (the visit whose update decided it included)."""
        return sum(1 for _, v in self.caught if v <= visits)

    def false_alarms_per(self, events: int = EVENTS_PER_MONTH) -> float | None:
        """False alarms per person per ``events`` events (None when no event was counted)."""
        return events * self.false_alarms / self.events if self.events else None

    def add(self, other: Detection) -> None:
        self.caught += other.caught
        self.missed += other.missed
        self.false_alarms += other.false_alarms
        self.events += other.events
        self.persons += other.persons
        self.source = self.source or other.source


def match_changes(person: Person, decided: Sequence[tuple[int, ContextChange]]) -> Detection:
    """Count the changes decided for ``person`` ((event, change), in order) against its true
    changes: a true change is caught by the first change decided in its context from its change
    point until the next one; every other decided change is a false alarm."""
    return match_contexts(person, [(e, ch.context) for e, ch in decided])


def match_contexts(person: Person, decided: Sequence[tuple[int, int]]) -> Detection:
    """:func:`match_changes` of changes given as (event of the update that decided it, context
    index), in order."""
    out = Detection(events=person.n_events, persons=1)
    used: set[int] = set()
    for true in true_changes(person):
        hit = next(
            (
                i
                for i, (e, context) in enumerate(decided)
                if i not in used and context == true.context and true.start <= e < true.stop
            ),
            None,
        )
        if hit is None:
            out.missed += 1
            continue
        used.add(hit)
        e = decided[hit][0]
        visits = int(np.count_nonzero(person.contexts[true.start : e + 1] == true.context))
        out.caught.append((e - true.start, visits))
    out.false_alarms = len(decided) - len(used)
    return out


def uniforms_for(rng: np.random.Generator, n_events: int) -> np.ndarray:
    """A person's coin flips: (events, 16) uniforms, four per visible step."""
    return rng.random((n_events, STEP_COLUMNS))


# -- the families -----------------------------------------------------------------------------

Generator = Callable[[Mission, np.random.Generator, int, int], tuple[Person, ...]]


@dataclass(frozen=True)
class Family:
    """A kind of simulated person: ``generate(mission, rng, n_persons, n_events)`` draws them.

    ``changes``: the family's routines change at :func:`change_event`, so the windows before
    and after the change apply to it. ``held_out``: kept for evaluation only (nothing was
    chosen on it) and not in the suite's default families. ``gradual``: its change is a drift
    rather than a switch. ``random_answers``: some of its answers are given at random.
    """

    name: str
    description: str
    generate: Generator = field(repr=False)
    changes: bool = False
    held_out: bool = False
    gradual: bool = False
    random_answers: bool = False

    @property
    def key(self) -> int:
        return zlib.crc32(self.name.encode())


def _available(mission: Mission) -> list[int]:
    return [
        c
        for c in range(mission.n_contexts)
        if mission.context_names(c)[1] not in mission.unavailable_situations
    ]


def _steady(
    profile: UserProfile, mission: Mission, rng: np.random.Generator, n_events: int
) -> Person:
    """A person whose routines never change."""
    contexts = event_stream([profile], [0], mission, n_events, rng, p_need=P_NEED)
    return Person((profile,), np.zeros(n_events, dtype=np.int64), contexts)


def _switched(
    before: UserProfile,
    after: UserProfile,
    mission: Mission,
    rng: np.random.Generator,
    n_events: int,
) -> Person:
    """A person whose routines are ``before`` until the change event and ``after`` from it."""
    at = change_event(n_events)
    contexts = event_stream([before, after], [0, at], mission, n_events, rng, p_need=P_NEED)
    schedule = (np.arange(n_events) >= at).astype(np.int64)
    return Person((before, after), schedule, contexts, change_at=at)


def _paper(mission: Mission, rng: np.random.Generator, n: int, n_events: int) -> tuple[Person, ...]:
    out = []
    for _ in range(n):
        before = random_profile(mission, rng)
        out.append(_switched(before, drift(before, mission, rng), mission, rng, n_events))
    return tuple(out)


def _individual(
    mission: Mission, rng: np.random.Generator, n: int, n_events: int
) -> tuple[Person, ...]:
    out = []
    for _ in range(n):
        profile = random_profile(mission, rng, n_needs=(2, 3, 4, 5, 6))
        profile = replace(
            profile,
            p_acc=float(rng.uniform(0.85, 1.0)),
            p_self=float(rng.uniform(0.3, 0.7)),
            eps_fb=float(rng.uniform(0.0, 0.1)),
        )
        out.append(_steady(profile, mission, rng, n_events))
    return tuple(out)


def _random_need(mission: Mission, rng: np.random.Generator, context: int) -> Need:
    k = int(rng.integers(len(mission.services)))
    return Need(context, k, int(rng.integers(len(mission.services[k].details))))


def _home(mission: Mission, rng: np.random.Generator, n: int, n_events: int) -> tuple[Person, ...]:
    available = _available(mission)
    n_shared = min(int(rng.integers(3, 5)), max(1, len(available) - 2))
    chosen = [int(c) for c in rng.permutation(np.asarray(available))]
    shared = [_random_need(mission, rng, c) for c in chosen[:n_shared]]
    rest = chosen[n_shared:]
    out = []
    for _ in range(n):
        own_count = min(int(rng.integers(1, 3)), n_shared - 1, len(rest))
        own_contexts = (
            rng.choice(np.asarray(rest), size=own_count, replace=False)
            if own_count
            else np.zeros(0, dtype=np.int64)
        )
        own = [_random_need(mission, rng, int(c)) for c in own_contexts]
        out.append(_steady(UserProfile(tuple(shared + own)), mission, rng, n_events))
    return tuple(out)


def _changed(need: Need, mission: Mission, rng: np.random.Generator) -> Need:
    """The same context, and surely something else: another detail of the same service (half
    the time, when it has one) or another service with a random detail."""
    details = mission.services[need.service].details
    if (rng.random() < 0.5 or len(mission.services) == 1) and len(details) > 1:
        others = [d for d in range(len(details)) if d != need.detail]
        return replace(need, detail=int(rng.choice(others)))
    if len(mission.services) == 1:
        return need
    k = int(rng.choice([k for k in range(len(mission.services)) if k != need.service]))
    return replace(need, service=k, detail=int(rng.integers(len(mission.services[k].details))))


def _abrupt(
    mission: Mission, rng: np.random.Generator, n: int, n_events: int
) -> tuple[Person, ...]:
    out = []
    for _ in range(n):
        before = random_profile(mission, rng)
        needs = list(before.needs)
        for i in rng.choice(len(needs), size=math.ceil(len(needs) / 2), replace=False):
            needs[int(i)] = _changed(needs[int(i)], mission, rng)
        after = replace(before, needs=tuple(needs))
        out.append(_switched(before, after, mission, rng, n_events))
    return tuple(out)


def _gradual(
    mission: Mission, rng: np.random.Generator, n: int, n_events: int
) -> tuple[Person, ...]:
    at = change_event(n_events)
    ramp = max(1, min(RAMP, n_events - at))
    out = []
    for _ in range(n):
        base = random_profile(mission, rng)
        drifting = sorted(
            int(i)
            for i in rng.choice(len(base.needs), size=math.ceil(len(base.needs) / 2), replace=False)
        )
        new = {i: _changed(base.needs[i], mission, rng) for i in drifting}
        # One profile per subset of drifting routines already changed (bit j: drifting[j]).
        profiles = []
        for mask in range(2 ** len(drifting)):
            needs = list(base.needs)
            for j, i in enumerate(drifting):
                if mask >> j & 1:
                    needs[i] = new[i]
            profiles.append(replace(base, needs=tuple(needs)))
        # Event at + j (0 <= j < ramp) has each drifting routine changed with chance (j+1)/ramp.
        chance = np.clip((np.arange(n_events) - at + 1) / ramp, 0.0, 1.0)
        flips = rng.random((n_events, len(drifting))) < chance[:, None]
        schedule = (flips * (1 << np.arange(len(drifting)))).sum(axis=1).astype(np.int64)
        contexts = event_stream([base], [0], mission, n_events, rng, p_need=P_NEED)
        out.append(Person(tuple(profiles), schedule, contexts, change_at=at))
    return tuple(out)


def restless_points(n_events: int) -> tuple[int, ...]:
    """The change points of ``restless``: 3/8, 5/8 (the suite's change event) and 7/8 of the
    way (events 60, 100 and 140 of 160, 0-based)."""
    return tuple(sorted({(3 * n_events) // 8, change_event(n_events), (7 * n_events) // 8}))


def _restless(
    mission: Mission, rng: np.random.Generator, n: int, n_events: int
) -> tuple[Person, ...]:
    """Held out (docs/method.md §12): more routines, their own answering habits, and three
    changes, each of two routines, mostly to another service in the same context."""
    points = tuple(p for p in restless_points(n_events) if 0 < p < n_events)
    out = []
    for _ in range(n):
        profile = random_profile(mission, rng, n_needs=(5, 6, 7, 8))
        profile = replace(
            profile,
            p_acc=float(rng.uniform(0.85, 1.0)),
            p_self=float(rng.uniform(0.2, 0.6)),
            eps_fb=float(rng.uniform(0.0, 0.08)),
        )
        profiles = [profile]
        for _ in points:
            needs = list(profiles[-1].needs)
            for i in rng.choice(len(needs), size=min(2, len(needs)), replace=False):
                need = needs[int(i)]
                others = [k for k in range(len(mission.services)) if k != need.service]
                if others and rng.random() < 0.7:
                    k = int(rng.choice(others))
                    d = int(rng.integers(len(mission.services[k].details)))
                    needs[int(i)] = replace(need, service=k, detail=d)
                else:
                    needs[int(i)] = _changed(need, mission, rng)
            profiles.append(replace(profile, needs=tuple(needs)))
        schedule = np.searchsorted(np.asarray(points), np.arange(n_events), side="right")
        contexts = event_stream(profiles, [0, *points], mission, n_events, rng, p_need=P_NEED)
        at = change_event(n_events)
        out.append(
            Person(
                tuple(profiles),
                schedule.astype(np.int64),
                contexts,
                change_at=at if at in points else None,
                change_points=points,
            )
        )
    return tuple(out)


def _with(
    params: Callable[[np.random.Generator], Mapping[str, float]],
    n_needs: Sequence[int] = (3, 4, 5),
    p_random: Callable[[np.random.Generator], float] | None = None,
) -> Generator:
    """A steady family: random routines, response parameters drawn by ``params``."""

    def generate(
        mission: Mission, rng: np.random.Generator, n: int, n_events: int
    ) -> tuple[Person, ...]:
        out = []
        for _ in range(n):
            profile = replace(random_profile(mission, rng, n_needs=n_needs), **params(rng))  # type: ignore[arg-type]
            person = _steady(profile, mission, rng, n_events)
            if p_random is not None:
                person = replace(person, p_random=p_random(rng))
            out.append(person)
        return tuple(out)

    return generate


FAMILIES: Mapping[str, Family] = MappingProxyType(
    {
        f.name: f
        for f in (
            Family(
                "paper",
                "the simulated users of the paper's experiments (§11): 3–5 routines; about "
                "half of them change at the change event",
                _paper,
                changes=True,
            ),
            Family(
                "individual",
                "2–6 routines drawn at random per person, and their own answering "
                "habits (accepts offers 85–100 %, speaks first 30–70 %, refuses the right service "
                "0–10 %); no change",
                _individual,
            ),
            Family(
                "home",
                "residents of one home: 3–4 routines shared by all, plus 1–2 of their own "
                "in other contexts (never as many as the shared ones); no change",
                _home,
            ),
            Family(
                "abrupt",
                "3–5 routines; at the change event half of them (rounded up) switch at "
                "once to another detail or service in the same context",
                _abrupt,
                changes=True,
            ),
            Family(
                "gradual",
                "3–5 routines; from the change event half of them drift: over 40 events "
                "the new routine is wanted ever more often (at event change+j with chance "
                "(j+1)/40), then always",
                _gradual,
                changes=True,
                gradual=True,
            ),
            Family(
                "noisy",
                "3–5 routines; 10–20 % of their answers (to offers, questions and "
                "services) are random; no change",
                _with(lambda rng: {}, p_random=lambda rng: float(rng.uniform(*NOISE_RANGE))),
                random_answers=True,
            ),
            Family(
                "shy",
                "3–5 routines; never speak first (they wait to be offered); no change",
                _with(lambda rng: {"p_self": 0.0}),
            ),
            Family(
                "refusing",
                "3–5 routines; often refuse an offer even when they need something "
                "(accept 40–60 %); no change",
                _with(lambda rng: {"p_acc": float(rng.uniform(*REFUSE_RANGE))}),
            ),
            Family(
                "many",
                "6–9 routines (in as many contexts, when the mission has them); no change",
                _with(lambda rng: {}, n_needs=(6, 7, 8, 9)),
            ),
            Family(
                "restless",
                "held out: 5–8 routines and their own answering habits (accepts offers "
                "85–100 %, speaks first 20–60 %, refuses the right service 0–8 %); three "
                "changes (3/8, 5/8 and 7/8 of the way), each of two routines, to another "
                "service (70 %) or detail in the same context",
                _restless,
                changes=True,
                held_out=True,
            ),
        )
    }
)
"""The families of the robustness suite, by name (docs/method.md §12, "Robustness")."""
DEFAULT_FAMILIES = tuple(name for name, f in FAMILIES.items() if not f.held_out)
"""The families the suite runs by default: all but the held-out ones."""


# -- one run ----------------------------------------------------------------------------------


@dataclass
class FamilyRun:
    """Rewards per episode, shape (persons, events): the oracle's, the one-miss oracle's
    (``bound``) and each learner's; and per learner the changes decided for the persons,
    counted against their true changes (``detection``)."""

    family: str
    seed: int
    oracle: FloatArray
    learners: dict[str, FloatArray]
    change_at: int | None
    bound: FloatArray | None = None
    detection: dict[str, Detection] = field(default_factory=dict)


def _seq(*words: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(w) for w in words]))


def people(
    family: Family, mission: Mission, seed: int, n_persons: int, n_events: int
) -> tuple[tuple[Person, ...], list[np.ndarray]]:
    """The persons of ``family`` for ``seed`` and their coin flips (the same for every learner)."""
    persons = family.generate(mission, _seq(seed, family.key, 0), n_persons, n_events)
    flips = [uniforms_for(_seq(seed, family.key, 1, p), n_events) for p in range(n_persons)]
    return persons, flips


def run_family(
    family: Family,
    seed: int,
    methods: Sequence[tuple[str, str, Mapping[str, Any]]],
    mission: Mission,
    *,
    n_persons: int,
    n_events: int,
) -> FamilyRun:
    """The oracle and every method (label, algorithm, params) through the same persons.

    A learner's generator depends on (seed, family, person, label) only, so adding a method
    changes no other's numbers.
    """
    space = space_for(mission)
    persons, flips = people(family, mission, seed, n_persons, n_events)
    oracle = np.stack([run_oracle(space, p, u) for p, u in zip(persons, flips, strict=True)])
    bound = np.stack([run_one_miss(space, p, u) for p, u in zip(persons, flips, strict=True)])
    learners: dict[str, FloatArray] = {}
    detection: dict[str, Detection] = {}
    for label, algorithm, params in methods:
        key = zlib.crc32(label.encode())
        rows = []
        counted = Detection()
        for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
            learner = make_learner(algorithm, params, mission)
            decided: list[tuple[int, ContextChange]] = []
            rng = _seq(seed, family.key, 2, i, key)
            rows.append(run_learner(learner, person, u, rng, changes=decided))
            counted.add(match_changes(person, decided))
            counted.source = "learner" if learner.decides_changes else "profile"
        learners[label] = np.stack(rows)
        detection[label] = counted
    change = change_event(n_events) if family.changes else None
    return FamilyRun(family.name, seed, oracle, learners, change, bound, detection)
