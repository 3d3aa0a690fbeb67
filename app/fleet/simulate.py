"""Simulated robots playing simulated people against a live service.

Each simulated person has a seeded event stream and seeded coin flips (``app.learning.simulation``),
with an optional change of needs at event ``change_at``. Robots (threads, each with its own
client) take the next event of whichever person is free, play its episode to the end through the
v1 API, and hand the person back: one person's events are played in order, never two at once,
and the same person is served by different robots over the run, as in a fleet.

Every robot keeps its own tally of what it saw (who initiated, what was accepted, the queries, the
rewards the person's reactions are worth); ``local_stats`` turns that tally into the paper's
metrics so they can be compared with what the service's stats endpoint says.
"""

from __future__ import annotations

import datetime as dt
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from app.learning import Action, ActionKind, Interaction, Mission, NegotiationSpace
from app.learning.evaluation import episode_metrics
from app.learning.negotiation import INTERACTION_CODE, Tally
from app.learning.simulation import STEP_COLUMNS, UserProfile, drift, event_stream, random_profile
from app.learning.simulation import respond as person_responds

__all__ = [
    "FleetError",
    "FleetRun",
    "Person",
    "PlayedEpisode",
    "local_stats",
    "make_people",
    "occurred_at",
    "overall_stats",
    "play_event",
    "run_fleet",
    "state_before",
]

FIRST_DAY = dt.date(2026, 11, 2)
OFFSETS = ("+08:00", "-05:00", "+00:00", "+05:30")  # people live in several time zones
MAX_VISIBLE_STEPS = STEP_COLUMNS // 2
METRICS = (
    "episodes",
    "missions",
    "interaction_rate",
    "success_rate",
    "queries_per_mission",
    "total_reward",
)


class FleetError(RuntimeError):
    """The run stopped: a robot hit an error it could not get past (the message says which)."""


class RobotClient(Protocol):
    """What a robot needs of ``attune_client.Client``."""

    def start_episode(
        self,
        user_id: str,
        *,
        event_id: str,
        occurred_at: dt.datetime | str,
        situation: str,
        initiator: str = ...,
        request: Any = ...,
        robot_id: str | None = ...,
    ) -> Any: ...

    def report_outcome(
        self,
        episode_id: str,
        *,
        decision_id: str,
        response: str,
        service: str | None = ...,
        detail: str | None = ...,
        feedback: str | None = ...,
    ) -> Any: ...


@dataclass
class Person:
    """A simulated person: needs (changing at ``change_points``), events and coin flips."""

    user_id: str
    profiles: list[UserProfile]
    change_points: list[int]
    contexts: np.ndarray  # (events,) context index of each event
    uniforms: np.ndarray  # (events, STEP_COLUMNS) the person's coin flips
    offset: str  # the person's UTC offset: events carry their local time

    def profile_at(self, event: int) -> UserProfile:
        active = sum(1 for cp in self.change_points if cp <= event) - 1
        return self.profiles[active]

    @property
    def events(self) -> int:
        return int(self.contexts.shape[0])


@dataclass(frozen=True, slots=True)
class PlayedEpisode:
    """One event as a robot played it."""

    user_id: str
    event: int
    episode_id: str
    robot_id: str
    initiated: bool  # the robot chose initiate
    interaction: Interaction
    success: bool  # a performed service was accepted
    queries: int  # query_type and query_detail actions
    reward: float  # what the person's reactions (and the service's replies) are worth
    service_reward: float  # the episode's total_reward as the service last reported it
    steps: int  # visible decisions answered


@dataclass
class FleetRun:
    """Everything the robots played, per person in event order."""

    people: list[Person]
    robots: int
    episodes: dict[str, list[PlayedEpisode]] = field(default_factory=dict)
    elapsed_s: float = 0.0

    @property
    def played(self) -> int:
        return sum(len(v) for v in self.episodes.values())

    @property
    def requests(self) -> int:
        """Requests the robots made: one start and one outcome per visible step."""
        return sum(1 + ep.steps for v in self.episodes.values() for ep in v)


def make_people(
    mission: Mission, *, users: int, events: int, change_at: int | None, seed: int, prefix: str
) -> list[Person]:
    """``users`` people named ``{prefix}-u1`` ...; needs drift at ``change_at`` if given."""
    if change_at is not None and not 0 < change_at < events:
        raise ValueError(f"change_at must be between 1 and {events - 1} (events - 1).")
    rng = np.random.default_rng(seed)
    people = []
    for i in range(users):
        before = random_profile(mission, rng)
        profiles, points = [before], [0]
        if change_at is not None:
            profiles.append(drift(before, mission, rng))
            points.append(change_at)
        contexts = event_stream(profiles, points, mission, events, rng)
        uniforms = rng.random((events, STEP_COLUMNS))
        people.append(
            Person(
                f"{prefix}-u{i + 1}",
                profiles,
                points,
                contexts,
                uniforms,
                OFFSETS[i % len(OFFSETS)],
            )
        )
    return people


def occurred_at(mission: Mission, slot: str, offset: str, event: int) -> str:
    """An RFC 3339 time whose local clock (at ``offset``) is 45 minutes into ``slot``.

    Event ``e`` happens on day ``e`` of the run, so times increase with the events.
    """
    start = next(s for s in mission.time_slots if s.name == slot).start
    local = dt.datetime.combine(FIRST_DAY + dt.timedelta(days=event), start)
    local += dt.timedelta(minutes=45)
    return local.strftime("%Y-%m-%dT%H:%M:%S") + offset


def _action(wire: Any) -> Action:
    return Action(ActionKind(wire.kind), wire.service, wire.detail)


def state_before(space: NegotiationSpace, action: Action) -> int:
    """The state the service is in when it asks the robot for ``action``."""
    if action.kind is ActionKind.PERFORM:
        assert action.service is not None
        assert action.detail is not None
        return space.detail_known_state(action.service, action.detail)
    if action.kind is ActionKind.QUERY_DETAIL:
        assert action.service is not None
        return space.type_known_state(action.service)
    if action.kind is ActionKind.QUERY_TYPE:
        return space.ENGAGED
    return space.OBSERVE


def play_event(
    client: RobotClient, space: NegotiationSpace, person: Person, event: int, robot_id: str
) -> PlayedEpisode:
    """One event of ``person``, from the episode's start to its end, the person simulated."""
    mission = space.mission
    context = int(person.contexts[event])
    slot, situation = mission.context_names(context)
    profile = person.profile_at(event)
    started = client.start_episode(
        person.user_id,
        event_id=f"{person.user_id}-e{event:04d}",
        occurred_at=occurred_at(mission, slot, person.offset, event),
        situation=situation,
        initiator="robot",
        robot_id=robot_id,
    )
    episode_id: str = started.episode_id
    decision = started.decision
    service_reward = float(started.total_reward)
    tally = Tally()
    step = 0
    while decision is not None:
        if step >= MAX_VISIBLE_STEPS:
            raise FleetError(
                f"episode {episode_id} of {person.user_id} asks for more than "
                f"{MAX_VISIBLE_STEPS} visible steps, the most a negotiation has."
            )
        action = _action(decision.action)
        a, s = space.action_index(action), state_before(space, action)
        flips = person.uniforms[event, 2 * step : 2 * step + 2]
        reaction = person_responds(space, profile, context, s, a, flips)
        result = client.report_outcome(
            episode_id,
            decision_id=decision.decision_id,
            response=reaction.response.value,
            service=reaction.service,
            detail=reaction.detail,
        )
        if not hasattr(result, "episode"):  # the client queued it: the service is unreachable
            raise FleetError(f"the outcome of {decision.decision_id} could not be delivered.")
        for silent in decision.chain:  # the service's own steps: respond pays, infer is free
            if silent.action.kind == ActionKind.RESPOND.value:
                tally.reward += mission.rewards.positive
        tally.step(space, s, a, reaction.reward, reaction.next_state, reaction.signal)
        service_reward = float(result.episode.total_reward)
        decision = result.decision
        step += 1
    return PlayedEpisode(
        person.user_id,
        event,
        episode_id,
        robot_id,
        tally.initiated,
        tally.interaction,
        tally.success,
        tally.queries,
        tally.reward,
        service_reward,
        step,
    )


def run_fleet(
    make_client: Callable[[str], Any],
    space: NegotiationSpace,
    people: list[Person],
    *,
    robots: int,
    on_episode: Callable[[PlayedEpisode], None] | None = None,
    deadline_s: float | None = None,
) -> FleetRun:
    """Play every event of ``people`` with ``robots`` concurrent robots.

    ``make_client(robot_id)`` gives each robot its own client (closed at the end if it has
    ``close``). A robot takes the person who has waited longest and is not being served; each
    person's events are played in order. The first error stops the whole fleet (robots finish the
    episode in hand) and is raised as ``FleetError``; so is running past ``deadline_s``.
    """
    run = FleetRun(people, robots, {p.user_id: [] for p in people})
    ready: deque[tuple[Person, int]] = deque((p, 0) for p in people if p.events)
    remaining = sum(p.events for p in people)
    lock = threading.Condition()
    errors: list[str] = []
    began = time.monotonic()

    def robot(index: int) -> None:
        nonlocal remaining
        robot_id = f"sim-robot-{index + 1}"
        client = make_client(robot_id)
        try:
            while True:
                with lock:
                    while not ready and remaining and not errors:
                        lock.wait(timeout=1.0)
                    if errors or not remaining:
                        return
                    person, event = ready.popleft()
                if deadline_s is not None and time.monotonic() - began > deadline_s:
                    raise FleetError(f"the run took longer than {deadline_s:.0f} s.")
                played = play_event(client, space, person, event, robot_id)
                with lock:
                    run.episodes[person.user_id].append(played)
                    remaining -= 1
                    if event + 1 < person.events:
                        ready.append((person, event + 1))
                    lock.notify_all()
                if on_episode is not None:
                    on_episode(played)
        except Exception as exc:  # any robot's failure stops the fleet, with its reason
            with lock:
                errors.append(f"{robot_id}: {type(exc).__name__}: {exc}")
                lock.notify_all()
        finally:
            close = getattr(client, "close", None)
            if close is not None:
                close()

    threads = [
        threading.Thread(target=robot, args=(i,), name=f"sim-robot-{i + 1}", daemon=True)
        for i in range(robots)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    run.elapsed_s = time.monotonic() - began
    if errors:
        raise FleetError(errors[0])
    return run


def local_stats(played: Sequence[PlayedEpisode]) -> dict[str, float | None]:
    """The paper's metrics over ``played``, from the robots' own tally (None where undefined)."""
    m = episode_metrics(
        np.asarray([p.initiated for p in played], dtype=bool),
        np.asarray([INTERACTION_CODE[p.interaction] for p in played], dtype=np.int8),
        np.asarray([p.success for p in played], dtype=bool),
        np.asarray([p.queries for p in played], dtype=np.int64),
        np.asarray([p.reward for p in played], dtype=np.float64),
    )
    return {k: (None if np.isnan(m[k]) else float(m[k])) for k in METRICS}


def overall_stats(per_user: Sequence[dict[str, Any]]) -> dict[str, float | None]:
    """The metrics over all users, from each user's stats as the service reported them.

    Rates are turned back into counts (rate x episodes or x missions) and pooled, so the result
    is what the stats endpoint would say of all the episodes at once.
    """
    episodes = sum(int(s["episodes"]) for s in per_user)
    missions = sum(int(s["missions"]) for s in per_user)
    initiated = sum(round((s["interaction_rate"] or 0.0) * s["episodes"]) for s in per_user)
    successes = sum(round((s["success_rate"] or 0.0) * s["missions"]) for s in per_user)
    queries = sum(round((s["queries_per_mission"] or 0.0) * s["missions"]) for s in per_user)
    return {
        "episodes": float(episodes),
        "missions": float(missions),
        "interaction_rate": initiated / episodes if episodes else None,
        "success_rate": successes / missions if missions else None,
        "queries_per_mission": queries / missions if missions else None,
        "total_reward": float(sum(float(s["total_reward"]) for s in per_user)),
    }
