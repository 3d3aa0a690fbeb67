"""Evaluations of candidate learners as background jobs (``/v1/admin/fleets/{fleet}/
evaluations``), on both engines: a fleet filled through the real API, an evaluation started by
staff and run by the service's own runner, its result read back; one at a time per fleet,
idempotent, cancelled, stopped when too long, failed when its process stopped, audited, looks
recorded, and an erased person's row gone from the stored result."""

from __future__ import annotations

import dataclasses
import datetime as dt
import random
import time
from typing import Any

import numpy as np
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select, update

from app.db.models import DataView, Evaluation
from app.learning.offpolicy import Steps, estimate, unseen_margins
from app.services import evaluation_jobs as jobs
from app.services.evaluation import _difference, evaluate_fleet, parse_candidate
from tests.support import people
from tests.support.episodes import play

PEOPLE = 5
EPISODES = 4
NEEDS = (("ProvideDrink", "tea"), ("BriefInformation", "news"), ("ProvideDrink", "coffee"))
BODY: dict[str, Any] = {
    "request_id": "review-1",
    "candidates": [{"algorithm": "hri", "params": {"tau": 0.005}}, {"algorithm": "dts"}],
}
WAIT_S = 120.0  # a bound on how long a test waits for a job of this small fleet


def _fill(robot: TestClient) -> list[str]:
    users = [f"person-{p}" for p in range(PEOPLE)]
    for user in users:
        r = robot.put(f"/v1/users/{user}", json={"learner": {"algorithm": "hri"}})
        assert r.status_code == 201, r.text
    for e in range(EPISODES):
        for p, user in enumerate(users):
            need = NEEDS[p % len(NEEDS)]
            rng = random.Random(p * 100 + e)
            answer = people.person(need=need, rng=rng, yes=0.8, asks=0.6, precise=0.5)
            play(robot, user, f"{user}-e{e}", answer)
    return users


def _wait(staff: TestClient, location: str, *, persons: bool = False) -> dict[str, Any]:
    """The job once it has ended (bounded)."""
    deadline = time.monotonic() + WAIT_S
    while True:
        r = staff.get(location, params={"persons": "true" if persons else "false"})
        assert r.status_code == 200, r.text
        found: dict[str, Any] = r.json()
        if found["status"] not in ("queued", "running"):
            return found
        assert time.monotonic() < deadline, f"still {found['status']} after {WAIT_S} s"
        time.sleep(0.05)


def _views(app: FastAPI, what: str = "evaluation") -> list[str]:
    with app.state.db.transaction(write=False) as session:
        rows = session.execute(select(DataView.user_pk).where(DataView.what == what)).all()
    return [str(r[0]) for r in rows]


def test_staff_start_an_evaluation_and_read_its_result(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    users = _fill(robot)
    r = staff.post("/v1/admin/fleets/default/evaluations", json=BODY)
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["status"] in ("queued", "running", "done")
    assert job["evaluation_id"].startswith("ev_")
    location = r.headers["Location"]
    assert location == f"/v1/admin/fleets/default/evaluations/{job['evaluation_id']}"
    assert [c["key"] for c in job["candidates"]] == ["hri:tau=0.005", "dts"]
    assert job["estimator"] == "wpdis"

    done = _wait(staff, location)
    assert done["status"] == "done", done
    assert done["error"] is None
    assert done["progress"] == {"people_done": PEOPLE, "people_total": PEOPLE}
    assert done["started_at"] is not None
    assert done["finished_at"] is not None
    result = done["result"]
    assert "persons" not in result or result["persons"] is None  # persons=false
    assert result["people"] == PEOPLE
    assert result["episodes"] == PEOPLE * EPISODES
    assert result["learners"] == {"hri": PEOPLE}
    # What the robots earn now: the mean return of the episodes counted.
    assert result["logged"]["value"] is not None
    for candidate in result["candidates"]:
        assert candidate["estimate"]["n_episodes"] == PEOPLE * EPISODES
        assert candidate["estimate"]["ess"] > 0
        assert candidate["verdict"]

    # The same numbers as the evaluation run directly on the same logs (it is seeded).
    direct = evaluate_fleet(
        app.state.db,
        app.state.ctx,
        "default",
        [parse_candidate("hri:tau=0.005"), parse_candidate("dts")],
    ).to_dict()
    assert {k: v for k, v in direct.items() if k != "persons"} == {
        k: v for k, v in result.items() if k != "persons"
    }

    # No look recorded so far (persons=false); with the per-person rows, one per person.
    assert _views(app) == []
    whole = staff.get(location).json()
    assert sorted(p["user_id"] for p in whole["result"]["persons"]) == users
    assert whole["result"]["persons"] == direct["persons"]
    assert len(_views(app)) == PEOPLE

    # The list: newest first, without per-person rows; the audit log has the start.
    listed = staff.get("/v1/admin/fleets/default/evaluations").json()
    assert [e["evaluation_id"] for e in listed["items"]] == [job["evaluation_id"]]
    assert listed["items"][0]["result"].get("persons") is None
    audit = staff.get("/v1/admin/audit").json()["items"]
    (entry,) = [e for e in audit if e["action"] == "evaluation.start"]
    assert entry["target"] == job["evaluation_id"]
    assert entry["fleet"] == "default"

    # Cancelling a finished evaluation changes nothing.
    r = staff.post(f"{location}/cancel")
    assert r.status_code == 200
    assert r.json()["status"] == "done"
    assert not [e for e in staff.get("/v1/admin/audit").json()["items"] if "cancel" in e["action"]]

    # A person erased: their row leaves the stored result; the fleet's figures stay.
    assert staff.delete(f"/v1/users/{users[0]}").status_code == 204
    after = staff.get(location).json()["result"]
    assert sorted(p["user_id"] for p in after["persons"]) == users[1:]
    assert after["candidates"] == result["candidates"]


def test_one_at_a_time_idempotent_and_cancelled_while_queued(
    app: FastAPI, robot: TestClient, staff: TestClient, admin: TestClient
) -> None:
    _fill(robot)
    app.state.evaluations = None  # no runner in this worker: the jobs stay queued
    r = staff.post("/v1/admin/fleets/default/evaluations", json=BODY)
    assert r.status_code == 202, r.text
    first = r.json()
    assert first["status"] == "queued"

    again = staff.post("/v1/admin/fleets/default/evaluations", json=BODY)
    assert again.status_code == 200
    assert again.headers["Idempotent-Replay"] == "true"
    assert again.json()["evaluation_id"] == first["evaluation_id"]

    other = {**BODY, "candidates": [{"algorithm": "dts"}]}
    r = staff.post("/v1/admin/fleets/default/evaluations", json=other)
    assert r.status_code == 409
    assert "review-1" in r.json()["detail"]

    r = admin.post("/v1/admin/fleets/default/evaluations", json={**other, "request_id": "r2"})
    assert r.status_code == 409
    assert first["evaluation_id"] in r.json()["detail"]

    r = staff.post(f"/v1/admin/fleets/default/evaluations/{first['evaluation_id']}/cancel")
    assert r.status_code == 200
    assert r.json()["status"] == "cancelled"
    assert r.json()["finished_at"] is not None
    audit = staff.get("/v1/admin/audit").json()["items"]
    assert [e["action"] for e in audit if e["action"].startswith("evaluation.")] == [
        "evaluation.cancel",
        "evaluation.start",
    ]
    r = admin.post("/v1/admin/fleets/default/evaluations", json={**other, "request_id": "r2"})
    assert r.status_code == 202, r.text
    assert r.json()["requested_by"]["role"] == "admin"


def test_a_job_whose_process_stopped_reads_failed_and_frees_the_fleet(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    _fill(robot)
    app.state.evaluations = None
    job = staff.post("/v1/admin/fleets/default/evaluations", json=BODY).json()
    long_ago = dt.datetime.now(dt.UTC) - jobs.STALE_AFTER - dt.timedelta(seconds=1)
    with app.state.db.transaction() as session:
        session.execute(
            update(Evaluation)
            .where(Evaluation.id == job["evaluation_id"])
            .values(status="running", heartbeat_at=long_ago)
        )
    location = f"/v1/admin/fleets/default/evaluations/{job['evaluation_id']}"
    stale = staff.get(location).json()
    assert stale["status"] == "failed"
    assert "stopped" in stale["error"]
    r = staff.post("/v1/admin/fleets/default/evaluations", json={**BODY, "request_id": "r2"})
    assert r.status_code == 202, r.text
    with app.state.db.transaction(write=False) as session:
        status = session.execute(
            select(Evaluation.status).where(Evaluation.id == job["evaluation_id"])
        ).scalar_one()
    assert status == "failed"
    # Its runner, had it come back, finds it no longer its own.
    assert jobs.run_job(app.state.db, app.state.ctx, job["evaluation_id"]) is None


def test_cancelled_while_running_and_stopped_when_too_long(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    _fill(robot)
    app.state.evaluations = None
    job = staff.post("/v1/admin/fleets/default/evaluations", json=BODY).json()
    location = f"/v1/admin/fleets/default/evaluations/{job['evaluation_id']}"
    asked: list[int] = []

    def stopping() -> bool:  # at each person: staff cancel once it runs
        if not asked:
            r = staff.post(f"{location}/cancel")
            asked.append(r.status_code)
            assert r.json()["status"] == "running"
            assert r.json()["cancel_requested"] is True
        return False

    status = jobs.run_job(app.state.db, app.state.ctx, job["evaluation_id"], stopping=stopping)
    assert asked == [200]
    assert status == "cancelled"
    ended = staff.get(location).json()
    assert ended["status"] == "cancelled"
    assert ended["result"] is None

    # ATTUNE_EVALUATION_MAX_MINUTES: a job past it is stopped and says why.
    job = staff.post(
        "/v1/admin/fleets/default/evaluations", json={**BODY, "request_id": "r2"}
    ).json()
    hurried = app.state.ctx.settings.model_copy(update={"evaluation_max_minutes": 1e-9})
    ctx = dataclasses.replace(app.state.ctx, settings=hurried)
    assert jobs.run_job(app.state.db, ctx, job["evaluation_id"]) == "failed"
    ended = staff.get(f"/v1/admin/fleets/default/evaluations/{job['evaluation_id']}").json()
    assert "ATTUNE_EVALUATION_MAX_MINUTES" in ended["error"]

    # A worker that drains stops its job and says so.
    job = staff.post(
        "/v1/admin/fleets/default/evaluations", json={**BODY, "request_id": "r3"}
    ).json()
    status = jobs.run_job(app.state.db, app.state.ctx, job["evaluation_id"], stopping=lambda: True)
    assert status == "failed"
    ended = staff.get(f"/v1/admin/fleets/default/evaluations/{job['evaluation_id']}").json()
    assert "service stopped" in ended["error"]


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({**BODY, "candidates": []}, "candidates"),
        ({**BODY, "candidates": [{"algorithm": "dts"}] * 6}, "candidates"),
        ({**BODY, "candidates": [{"algorithm": "nope"}]}, "candidates"),
        ({**BODY, "candidates": [{"algorithm": "hri", "params": {"tau": -1}}]}, "candidates"),
        ({**BODY, "candidates": [{"algorithm": "hri", "params": {"nope": 1}}]}, "candidates"),
        ({**BODY, "candidates": [{"algorithm": "dts"}, {"algorithm": "dts"}]}, "candidates"),
        ({**BODY, "since": "2026-11-01T00:00:00"}, "since"),
        ({**BODY, "since": "2026-11-02T00:00:00Z", "until": "2026-11-01T00:00:00Z"}, "until"),
        ({**BODY, "estimator": "magic"}, "estimator"),
        ({**BODY, "request_id": "a b"}, "request_id"),
        ({**BODY, "extra": 1}, "extra"),
    ],
)
def test_bad_requests_get_422_naming_the_field(
    app: FastAPI, robot: TestClient, staff: TestClient, body: dict[str, Any], field: str
) -> None:
    assert robot.put("/v1/users/lin", json={}).status_code == 201
    r = staff.post("/v1/admin/fleets/default/evaluations", json=body)
    assert r.status_code == 422, r.text
    assert field in r.text


def test_who_may_evaluate(
    app: FastAPI,
    robot: TestClient,
    staff: TestClient,
    other_staff: TestClient,
    other_robot: TestClient,
    admin: TestClient,
) -> None:
    assert robot.put("/v1/users/lin", json={}).status_code == 201
    app.state.evaluations = None
    url = "/v1/admin/fleets/default/evaluations"
    assert robot.post(url, json=BODY).status_code == 403
    assert robot.get(url).status_code == 403
    assert other_staff.post(url, json=BODY).status_code == 403
    assert other_staff.get(url).status_code == 403
    job = staff.post(url, json=BODY).json()
    one = f"{url}/{job['evaluation_id']}"
    assert other_staff.get(one).status_code == 403
    assert other_staff.post(f"{one}/cancel").status_code == 403
    assert staff.get(f"{url}/ev_{'0' * 32}").status_code == 404
    # A fleet with nobody in it yet has nothing to evaluate.
    r = other_robot.put("/v1/users/someone", json={})
    assert r.status_code == 201
    assert staff.post("/v1/admin/fleets/empty/evaluations", json=BODY).status_code == 403
    r = admin.post("/v1/admin/fleets/empty/evaluations", json=BODY)
    assert r.status_code == 404
    assert "empty" in r.json()["detail"]
    assert other_staff.post("/v1/admin/fleets/other/evaluations", json=BODY).status_code == 202
    r = staff.get(url, params={"cursor": "nope"})
    assert r.status_code == 422


def test_the_difference_reaches_over_what_the_logs_do_not_show() -> None:
    """A candidate the logs show four fifths of (weights averaging 0.8): the difference with
    the logged value reaches as far as the candidate's own interval does for the unseen fifth
    (a fifth of the way to the lowest and the highest return logged, 0 and 3), beyond the
    bootstrap's spread (the logged mean's, about 0.1 here)."""
    a = {"logged": [0.9], "target": [0.8], "reward": [1.0]}
    c = {"logged": [0.1], "target": [0.0], "reward": [3.0]}
    steps = Steps.from_episodes([a] * 180 + [c] * 20, list(range(200)))
    found = estimate(steps, "wpdis")
    assert found.value is not None
    logged = 1.2  # the mean return: 0.9 x 1 + 0.1 x 3
    below, above = unseen_margins(steps, "wpdis", found.value, found.weight_mean)
    assert (below, above) == pytest.approx((0.2, 0.4))
    difference = _difference(steps, found, logged, "wpdis", np.random.default_rng(7))
    assert difference.value == pytest.approx(found.value - logged)
    assert difference.low <= difference.value - below
    assert difference.high >= difference.value + above
    # True difference: 0.8 x 1 + 0.2 x 2.5 - 1.2 = 0.1, inside; the bootstrap alone is not.
    assert difference.low <= 0.1 <= difference.high
    assert difference.high - above < 0.1
