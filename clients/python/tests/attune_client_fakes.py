"""A scripted fake of the service's write endpoints, for ``httpx.MockTransport``."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import httpx
from attune_client import AsyncClient, Client

KEY = "test-key"
BASE_URL = "http://attune.test"

MakeClient = Callable[..., Client]
MakeAsyncClient = Callable[..., AsyncClient]
Failure = int | httpx.TransportError | tuple[int, dict[str, str]]


def decision(decision_id: str, kind: str = "initiate") -> dict[str, Any]:
    return {
        "decision_id": decision_id,
        "action": {"kind": kind},
        "expects": ["accepted", "rejected", "terminated"],
        "probabilities": [{"action": {"kind": kind}, "p": 1.0}],
        "chain": [],
    }


class FakeService:
    """A tiny stand-in for the service's write endpoints, with its idempotency rules.

    ``down`` makes every request fail to connect; ``script`` lists what the next requests get
    instead of an answer (a status, a (status, headers) pair, or a transport error to raise);
    ``refuse`` maps a report key to the status it always gets; ``interrupted`` holds the
    episodes a mission change interrupted (their new outcomes get the service's 409).
    ``applied`` lists the reports that took effect, in order; ``requests`` every request
    received.
    """

    def __init__(self) -> None:
        self.down = False
        self.script: list[Failure] = []
        self.refuse: dict[str, int] = {}
        self.interrupted: set[str] = set()
        self.requests: list[httpx.Request] = []
        self.applied: list[tuple[str, str]] = []
        self._answers: dict[tuple[str, str], tuple[bytes, dict[str, Any]]] = {}
        self.on_request: Callable[[httpx.Request], None] | None = None

    @property
    def posts(self) -> list[httpx.Request]:
        return [r for r in self.requests if r.method == "POST"]

    def handler(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        if self.on_request is not None:
            self.on_request(request)
        if self.down:
            raise httpx.ConnectError("connection refused", request=request)
        if self.script:
            step = self.script.pop(0)
            if isinstance(step, httpx.TransportError):
                raise step
            status, headers = step if isinstance(step, tuple) else (step, {})
            return httpx.Response(
                status, headers=headers, json={"error": "Scripted", "detail": f"scripted {status}"}
            )
        parts = request.url.path.strip("/").split("/")
        if request.method == "POST" and parts[:2] == ["v1", "episodes"] and len(parts) == 4:
            return self._report(request, parts[2], parts[3])
        if request.method == "GET" and request.url.path == "/healthz":
            return httpx.Response(200, json={"status": "ok"})
        if request.method == "GET" and parts[:2] == ["v1", "users"] and len(parts) == 3:
            return httpx.Response(
                200,
                json={
                    "user_id": parts[2],
                    "fleet": "default",
                    "display_name": None,
                    "learner": {"algorithm": "hri", "params": {}},
                    "created_at": "2026-11-22T03:50:31.603058Z",
                    "episodes": 0,
                },
            )
        return httpx.Response(404, json={"error": "NotFound", "detail": "No such endpoint."})

    def _report(self, request: httpx.Request, episode_id: str, what: str) -> httpx.Response:
        body = json.loads(request.content)
        kind = "outcome" if what == "outcomes" else "feedback"
        key = body["decision_id"] if kind == "outcome" else body["feedback_id"]
        if key in self.refuse:
            status = self.refuse[key]
            return httpx.Response(status, json={"error": "Refused", "detail": f"{key} refused"})
        earlier = self._answers.get((kind, key))
        if earlier is None and kind == "outcome" and episode_id in self.interrupted:
            return httpx.Response(
                409,
                json={
                    "error": "Conflict",
                    "detail": f"Episode {episode_id!r} was interrupted when "
                    "its fleet's mission changed; it takes no more outcomes. Start a new episode.",
                },
            )
        if earlier is not None:
            if earlier[0] != request.content:
                return httpx.Response(
                    409, json={"error": "Conflict", "detail": f"{key} reused with another body"}
                )
            return httpx.Response(200, json=earlier[1], headers={"Idempotent-Replay": "true"})
        self.applied.append((kind, key))
        episode = {
            "episode_id": episode_id,
            "status": "open",
            "state": "ENGAGED",
            "total_reward": float(len(self.applied)),
        }
        answer: dict[str, Any] = {"reward": 1.0, "episode": episode}
        if kind == "outcome":
            answer["decision"] = decision(f"next-{key}", "query_type")
        self._answers[(kind, key)] = (request.content, answer)
        return httpx.Response(200, json=answer)
