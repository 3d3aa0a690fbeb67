"""Small builders shared by the API tests."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient

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
    return {
        "event_id": event_id,
        "occurred_at": occurred_at,
        "situation": situation,
        "initiator": initiator,
        "request": request,
        "robot_id": robot_id,
    }


def start(client: TestClient, user_id: str, event_id: str, **kw: Any) -> dict[str, Any]:
    r = client.post(f"/v1/users/{user_id}/episodes", json=event(event_id, **kw))
    assert r.status_code == 201, r.text
    body: dict[str, Any] = r.json()
    return body


def answer(
    client: TestClient, episode_id: str, decision_id: str, response: str, **kw: Any
) -> dict[str, Any]:
    r = client.post(
        f"/v1/episodes/{episode_id}/outcomes",
        json={"decision_id": decision_id, "response": response, **kw},
    )
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body
