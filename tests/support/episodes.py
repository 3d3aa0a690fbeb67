"""Episodes through the v1 API, for the tests that talk HTTP to the service (a ``TestClient``
of the app, or an ``httpx.Client`` of a live service: the first is the second).

``event(...)`` is the body of an event; ``start(client, user_id, event_id, ...)`` sends it and
returns the new episode with its first decision; ``report(client, episode_id, decision_id,
response, ...)`` reports what the person did and returns the service's answer (the reward and
the next decision). Each asserts its status, so a test reads as the exchange it makes. What
the person answers is ``tests/support/people.py``'s ``answer``.
"""

from __future__ import annotations

from typing import Any

import httpx

__all__ = ["EVENT_TIME", "event", "report", "start"]

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
