"""Episodes through the v1 API, for the tests that talk HTTP to the service (a ``TestClient``
of the app, or an ``httpx.Client`` of a live service: the first is the second).

``event(...)`` is the body of an event; ``start(client, user_id, event_id, ...)`` sends it and
returns the new episode with its first decision; ``report(client, episode_id, decision_id,
response, ...)`` reports what the person did and returns the service's answer (the reward and
the next decision). Each asserts its status, so a test reads as the exchange it makes.

``play(client, user_id, event_id, person, ...)`` is a whole episode: the event, then each
decision answered by ``person`` (a decision in, the outcome's fields out: ``people.person(...)``
is the tests' person, ``people.answer`` with its settings) until the episode closes; it returns
every step, so a test reads what it needs (the decisions, the responses, the last answer).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import httpx

__all__ = ["EVENT_TIME", "Person", "Played", "Step", "event", "play", "report", "start"]

Person = Callable[[dict[str, Any]], dict[str, Any]]
"""Who answers the robot: a decision (the API's JSON) in, the outcome's fields out (``response``
and, where it needs them, ``service``, ``detail``, ``feedback``)."""

EVENT_TIME = "2026-11-22T15:10:00+08:00"  # afternoon, local time


def event(
    event_id: str,
    situation: str = "stretching",
    *,
    occurred_at: str = EVENT_TIME,
    initiator: str = "robot",
    request: dict[str, Any] | None = None,
    robot_id: str | None = "robot7",
) -> dict[str, Any]:
    """The body of ``POST /v1/users/{user_id}/episodes``."""
    return {
        "event_id": event_id,
        "occurred_at": occurred_at,
        "situation": situation,
        "initiator": initiator,
        "request": request,
        "robot_id": robot_id,
    }


def start(client: httpx.Client, user_id: str, event_id: str, **kw: Any) -> dict[str, Any]:
    """An event of ``user_id`` (``event(event_id, **kw)``), answered 201: the episode and its
    first decision."""
    r = client.post(f"/v1/users/{user_id}/episodes", json=event(event_id, **kw))
    assert r.status_code == 201, r.text
    body: dict[str, Any] = r.json()
    return body


def report(
    client: httpx.Client, episode_id: str, decision_id: str, response: str, **kw: Any
) -> dict[str, Any]:
    """The outcome of ``decision_id``: ``response`` and its other fields (``service``,
    ``detail``, ``feedback``), answered 200: the reward, the episode and the next decision."""
    r = client.post(
        f"/v1/episodes/{episode_id}/outcomes",
        json={"decision_id": decision_id, "response": response, **kw},
    )
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


@dataclass(frozen=True)
class Step:
    """One decision of an episode, what the person said to it, and the service's answer."""

    decision: dict[str, Any]
    said: dict[str, Any]
    answer: dict[str, Any]


@dataclass(frozen=True)
class Played:
    """An episode played to its end: the service's answer to the event, and every step."""

    started: dict[str, Any]
    steps: list[Step]

    @property
    def episode_id(self) -> str:
        return str(self.started["episode_id"])

    @property
    def decisions(self) -> list[dict[str, Any]]:
        return [step.decision for step in self.steps]

    @property
    def last(self) -> dict[str, Any]:
        """The service's last answer: the last outcome's (the event's if nothing was asked)."""
        return self.steps[-1].answer if self.steps else self.started


MAX_STEPS = 8  # a negotiation has at most four visible steps: more is a loop


def play(client: httpx.Client, user_id: str, event_id: str, person: Person, **kw: Any) -> Played:
    """The event ``event_id`` of ``user_id`` (``event(event_id, **kw)``), then each decision
    answered by ``person`` until the episode closes."""
    started = start(client, user_id, event_id, **kw)
    steps: list[Step] = []
    decision = started["decision"]
    while decision is not None:
        assert len(steps) < MAX_STEPS, f"{event_id}: an episode longer than a negotiation"
        said = person(decision)
        answer = report(client, started["episode_id"], decision["decision_id"], **said)
        steps.append(Step(decision, said, answer))
        decision = answer["decision"]
    return Played(started, steps)
