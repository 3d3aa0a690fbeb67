"""Acceptance: many robots at once, over a real HTTP server, retrying and conflicting.

Eight threads drive 80 episodes of two users in each of two fleets that use the same user ids
and the same event ids (20 per user, shuffled so that several threads act for the same user, and
for both fleets' users of the same id, at the same time) through uvicorn on a free local port.
Every 5th write is sent twice (a robot's retry), and one write in ten is followed by a
conflicting body under the same client id. Afterwards every acknowledged write must be stored
exactly once, every retry must have been an identical replay, every conflict a 409, nothing a
5xx, nothing of one fleet's user visible in the other's, and each user's model must equal what
its history teaches (visit counts, and ``attune models rebuild``).
"""

from __future__ import annotations

import random
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import httpx
from fastapi import FastAPI
from sqlalchemy import func, select

from app.db.models import Decision, Episode, User
from app.db.session import Database
from app.settings import Settings
from tests.support import people
from tests.support.commands import rebuild
from tests.support.fixtures import MakeKey
from tests.support.live import serving
from tests.support.office import MISSION
from tests.support.rows import user_pk

FLEETS = ("default", "east")
USERS = ("conc-a", "conc-b")
PER_USER = 20
THREADS = 8
DEADLINE_S = 150.0  # the whole run; each request may also wait out the SQLite busy timeout
SLOT_TIMES = {"morning": "09:30", "noon": "12:15", "afternoon": "15:10", "evening": "20:45"}
SITUATIONS = MISSION.situations
OTHER_RESPONSE = {
    "accepted": "rejected",
    "rejected": "accepted",
    "terminated": "accepted",
    "answered": "terminated",
    "none": "human_request",
    "human_request": "none",
}


Who = tuple[str, str]  # (fleet, user id)


@dataclass
class Record:
    """What one robot (thread) saw."""

    writes: int = 0
    statuses: list[tuple[str, int, str]] = field(default_factory=list)  # (url, status, body)
    replays: list[tuple[dict[str, Any], int, str | None, Any]] = field(default_factory=list)
    conflicts: list[tuple[int, Any]] = field(default_factory=list)
    # Keyed by (fleet, user id):
    episodes: dict[Who, list[str]] = field(default_factory=dict)  # episode ids
    decisions: dict[Who, list[str]] = field(default_factory=dict)  # decision ids seen
    answered: dict[Who, dict[str, str]] = field(default_factory=dict)  # decision id -> response


class Robot:
    """One thread: a robot of each fleet (one key per fleet), taking turns."""

    def __init__(self, base_url: str, keys: dict[str, str], seed: int, deadline: float) -> None:
        self.https = {
            fleet: httpx.Client(
                base_url=base_url, timeout=60.0, headers={"Authorization": f"Bearer {key}"}
            )
            for fleet, key in keys.items()
        }
        self.http = self.https[FLEETS[0]]
        self.rng = random.Random(seed)
        self.deadline = deadline
        self.rec = Record()

    def post(self, url: str, body: dict[str, Any]) -> httpx.Response:
        assert time.monotonic() < self.deadline, "past the deadline"
        r = self.http.post(url, json=body)
        self.rec.statuses.append((url, r.status_code, r.text if r.status_code >= 500 else ""))
        return r

    def write(
        self, url: str, body: dict[str, Any], conflicting: dict[str, Any], status: int
    ) -> dict[str, Any]:
        """One acknowledged write; every 5th sent twice, one in ten followed by a conflict."""
        self.rec.writes += 1
        n = self.rec.writes
        r = self.post(url, body)
        assert r.status_code == status, (url, body, r.status_code, r.text)
        assert "Idempotent-Replay" not in r.headers
        first: dict[str, Any] = r.json()
        if n % 5 == 0:
            again = self.post(url, body)
            self.rec.replays.append(
                (first, again.status_code, again.headers.get("Idempotent-Replay"), again.json())
            )
        if n % 10 == 3:
            clash = self.post(url, conflicting)
            self.rec.conflicts.append((clash.status_code, clash.json()))
        return first

    def respond(self, decision: dict[str, Any]) -> dict[str, Any]:
        """Seeded answers of a cooperative person that always run the episode to its end."""
        return {
            "decision_id": decision["decision_id"],
            **people.answer(decision["action"], picky=False, rng=self.rng, asks=0.5, precise=0.5),
        }

    def episode(self, fleet: str, user_id: str, k: int) -> None:
        self.http = self.https[fleet]
        who = (fleet, user_id)
        slot = list(SLOT_TIMES)[k % len(SLOT_TIMES)]
        situation = SITUATIONS[k % len(SITUATIONS)]
        body = {
            "event_id": f"{user_id}-{k:03d}",
            "occurred_at": f"2026-11-{1 + k % 28:02d}T{SLOT_TIMES[slot]}:00+08:00",
            "situation": situation,
            "initiator": "robot",
            "request": None,
            "robot_id": f"robot-{threading.get_ident()}",
        }
        other = {**body, "situation": SITUATIONS[(k + 1) % len(SITUATIONS)]}
        ep = self.write(f"/v1/users/{user_id}/episodes", body, other, 201)
        assert ep["context"] == {"time_slot": slot, "situation": situation}
        episode_id = ep["episode_id"]
        self.rec.episodes.setdefault(who, []).append(episode_id)
        seen = self.rec.decisions.setdefault(who, [])
        answered = self.rec.answered.setdefault(who, {})
        decision = ep["decision"]
        for _ in range(6):  # an episode has at most four visible steps
            if decision is None:
                return
            seen.append(decision["decision_id"])
            sent = self.respond(decision)
            clash = {**sent, "response": OTHER_RESPONSE[sent["response"]]}
            clash.pop("service", None)
            clash.pop("detail", None)
            out = self.write(f"/v1/episodes/{episode_id}/outcomes", sent, clash, 200)
            answered[decision["decision_id"]] = sent["response"]
            decision = out["decision"]
            if decision is None:
                assert out["episode"]["status"] == "closed"
        raise AssertionError(f"episode {episode_id} did not end within 6 steps")


def run_robot(
    base_url: str,
    keys: dict[str, str],
    seed: int,
    jobs: list[tuple[str, str, int]],
    deadline: float,
) -> Record:
    robot = Robot(base_url, keys, seed, deadline)
    try:
        for fleet, user_id, k in jobs:
            robot.episode(fleet, user_id, k)
    finally:
        for http in robot.https.values():
            http.close()
    return robot.rec


def test_concurrent_robots_with_retries_and_conflicts(
    app: FastAPI, db: Database, make_key: MakeKey, settings: Settings, engine_name: str
) -> None:
    everyone = [(fleet, user) for fleet in FLEETS for user in USERS]
    jobs = [(fleet, user, k) for fleet, user in everyone for k in range(PER_USER)]
    random.Random(2026).shuffle(jobs)
    per_thread = [jobs[t::THREADS] for t in range(THREADS)]
    # Several threads act for each user, and every thread for both fleets.
    assert all(
        sum(who in {(f, u) for f, u, _ in chunk} for chunk in per_thread) >= THREADS // 2
        for who in everyone
    )
    assert all({f for f, _, _ in chunk} == set(FLEETS) for chunk in per_thread)
    keys = [{fleet: make_key("robot", fleet) for fleet in FLEETS} for _ in range(THREADS)]
    began = time.monotonic()
    deadline = began + DEADLINE_S
    with serving(app) as base_url:
        initial = {}
        for fleet, user_id in everyone:
            with httpx.Client(
                base_url=base_url,
                timeout=60.0,
                headers={"Authorization": f"Bearer {keys[0][fleet]}"},
            ) as http:
                made = http.put(f"/v1/users/{user_id}", json={})
                assert made.status_code == 201, made.text
                assert made.json()["fleet"] == fleet
                initial[fleet, user_id] = http.get(f"/v1/users/{user_id}/model").json()["version"]
        with ThreadPoolExecutor(max_workers=THREADS) as pool:
            futures = [
                pool.submit(run_robot, base_url, keys[t], t, per_thread[t], deadline)
                for t in range(THREADS)
            ]
            records = [f.result(timeout=max(1.0, deadline - time.monotonic())) for f in futures]
        driven = time.monotonic() - began
        views = {}
        for fleet, user_id in everyone:
            (elsewhere,) = set(FLEETS) - {fleet}
            with (
                httpx.Client(
                    base_url=base_url,
                    timeout=60.0,
                    headers={"Authorization": f"Bearer {keys[0][fleet]}"},
                ) as http,
                httpx.Client(
                    base_url=base_url,
                    timeout=60.0,
                    headers={"Authorization": f"Bearer {keys[0][elsewhere]}"},
                ) as other,
            ):
                traces = []
                for rec in records:
                    for episode_id in rec.episodes.get((fleet, user_id), []):
                        r = http.get(f"/v1/episodes/{episode_id}")
                        assert r.status_code == 200, r.text
                        traces.append(r.json())
                        # The other fleet's robot finds no such episode.
                        assert other.get(f"/v1/episodes/{episode_id}").status_code == 404
                user = http.get(f"/v1/users/{user_id}")
                model = http.get(f"/v1/users/{user_id}/model")
                stats = http.get(f"/v1/users/{user_id}/stats")
                assert user.status_code == model.status_code == stats.status_code == 200
                views[fleet, user_id] = (traces, user.json(), model.json(), stats.json())
    print(
        f"\n{engine_name}: {sum(r.writes for r in records)} acknowledged writes, "
        f"{sum(len(r.statuses) for r in records)} requests by {THREADS} threads in "
        f"{driven:.1f} s"
    )

    # No server errors (on SQLite, a 503 would mean a writer waited out the busy timeout).
    errors = [s for rec in records for s in rec.statuses if s[1] >= 500]
    assert errors == []

    # Every retry was an identical replay, every conflict a 409.
    replays = [x for rec in records for x in rec.replays]
    conflicts = [x for rec in records for x in rec.conflicts]
    assert len(replays) >= 20
    assert len(conflicts) >= 10
    for first, status, header, body in replays:
        assert (status, header) == (200, "true")
        assert body == first
    for status, body in conflicts:
        assert status == 409, body
        assert body["error"] == "Conflict"
        assert body["detail"]

    with db.transaction(write=False) as s:
        assert s.scalar(select(func.count()).select_from(User)) == len(everyone)
    for fleet, user_id in everyone:
        who = (fleet, user_id)
        episode_ids = [e for rec in records for e in rec.episodes.get(who, [])]
        decision_ids = [d for rec in records for d in rec.decisions.get(who, [])]
        answered = {d: resp for rec in records for d, resp in rec.answered.get(who, {}).items()}
        assert len(episode_ids) == len(set(episode_ids)) == PER_USER
        assert len(decision_ids) == len(set(decision_ids)) == len(answered)
        with db.transaction(write=False) as s:
            pk = user_pk(s, user_id, fleet)
            stored_eps = s.scalars(select(Episode).where(Episode.user_pk == pk)).all()
            stored = s.scalars(
                select(Decision)
                .join(Episode, Episode.id == Decision.episode_id)
                .where(Episode.user_pk == pk)
            ).all()
            count = s.scalar(select(func.count()).select_from(Episode).where(Episode.user_pk == pk))
            # Stored exactly once, and what was stored is the acknowledged body, not a conflict.
            assert count == PER_USER
            assert sorted(e.id for e in stored_eps) == sorted(episode_ids)
            assert sorted(e.seq for e in stored_eps) == list(range(1, PER_USER + 1))
            assert all(e.status == "closed" for e in stored_eps)
            assert sorted(d.id for d in stored) == sorted(decision_ids)
            assert {d.id: d.response for d in stored} == answered
            draws = sorted(d.draw if d.draw is not None else -1 for d in stored)
            assert draws == list(range(len(stored)))  # one draw each, none lost or doubled
            silent = sum(len(d.chain) for d in stored)

        traces, user, model, stats = views[who]
        assert user["episodes"] == PER_USER
        assert model["episodes"] == PER_USER
        assert stats["episodes"] == PER_USER
        assert all(t["status"] == "closed" for t in traces)
        trace_answered = sum(d["response"] is not None for t in traces for d in t["decisions"])
        trace_silent = sum(len(d["chain"]) for t in traces for d in t["decisions"])
        assert (trace_answered, trace_silent) == (len(answered), silent)
        visits = sum(
            a["visits"] for c in model["contexts"] for st in c["states"] for a in st["actions"]
        )
        assert visits == trace_answered + trace_silent
        # One model change per acknowledged outcome (an episode's start from OBSERVE teaches
        # nothing: its first decision has no silent steps); replays and conflicts change nothing.
        assert model["version"] == initial[who] + len(answered)

        code, summary = rebuild(
            settings.database_url, user_id, fleet=fleet, pooler=settings.database_pooler
        )
        assert summary["identical"] is True, summary
        assert code == 0, summary
        assert summary["decisions_redrawn"] == len(decision_ids)
