"""Shadows (``/v1/admin/fleets/{fleet}/shadow``), on both engines: a candidate decides beside
the fleet's learners without acting, after each episode ends; what it decided is stored with its
distribution and its probability of the robot's action; how often it agrees and its off-policy
estimate are read back in words; only the shadow's share of people, only since it started, and
nothing after it stopped."""

from __future__ import annotations

import datetime as dt
import time
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.db.models import Decision, ShadowDecision
from app.db.repositories import shadows as repo
from app.db.repositories import users as users_repo
from app.services import shadows
from app.services.evaluation import ReplayCache, shadow_decisions
from app.services.rollouts import hash_place
from tests.support import people
from tests.support.episodes import play, start

URL = "/v1/admin/fleets/default/shadow"
TEA = ("ProvideDrink", "tea")
WAIT_S = 120.0  # a bound on how long the pass process may take to start and pass


def _later() -> dt.datetime:
    return dt.datetime.now(dt.UTC) + dt.timedelta(seconds=10)


def _fill(robot: TestClient, users: list[str], episodes: int, tag: str, **kw: Any) -> None:
    for e in range(episodes):
        for user in users:
            play(robot, user, f"{user}-{tag}{e}", people.person(need=TEA), **kw)


def _now() -> str:
    """An event's time after the shadow started (the estimate counts those)."""
    return (dt.datetime.now(dt.UTC) + dt.timedelta(minutes=1)).isoformat()


def _stored(app: FastAPI) -> list[tuple[Any, ...]]:
    with app.state.db.transaction(write=False) as session:
        return list(
            session.execute(
                select(
                    ShadowDecision.decision_id,
                    ShadowDecision.probabilities,
                    ShadowDecision.logged_action,
                    ShadowDecision.logged_probability,
                    ShadowDecision.state,
                    Decision.action,
                    Decision.probabilities,
                    Decision.forced,
                ).join(Decision, Decision.id == ShadowDecision.decision_id)
            ).all()
        )


def test_a_shadow_decides_beside_the_robots_and_says_how_often_it_agrees(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    users = [f"p{i}" for i in range(6)]
    for user in users:
        assert (
            robot.put(f"/v1/users/{user}", json={"learner": {"algorithm": "hri"}}).status_code
            == 201
        )
    _fill(robot, users, 2, "before")
    r = staff.put(URL, json={"candidate": {"algorithm": "hri"}})
    assert r.status_code == 201, r.text
    assert r.json()["decisions"] == 0
    assert "has not decided yet" in r.json()["summary"]
    _fill(robot, users, 3, "after", occurred_at=_now())
    opened = start(robot, users[0], "left-open")  # not decided by the shadow until it ends
    assert opened["decision"] is not None

    added = shadows.shadow_pass(app.state.db, app.state.ctx, now=_later())
    stored = _stored(app)
    assert added == {"default": len(stored)}
    assert stored
    with app.state.db.transaction(write=False) as session:
        before_start = session.execute(
            select(Decision.id).where(Decision.decided_at < dt.datetime.now(dt.UTC))
        ).all()
    assert len(before_start) > len(stored)  # the decisions before the start were left
    assert opened["decision"]["decision_id"] not in {row[0] for row in stored}
    # The same HRI as the robots', taught the same history: its distribution at each decision
    # is the one the robot's decision was drawn from.
    space = app.state.ctx.space
    for _, mine, logged_action, p_logged, state, action, theirs, forced in stored:
        assert not forced
        assert logged_action == action
        assert mine == pytest.approx(theirs, abs=1e-9)
        first = space.actions_of(state).start
        assert p_logged == pytest.approx(theirs[action - first], abs=1e-9)

    # The person's export holds what the shadow decided at their decisions, per episode.
    export = staff.get(f"/v1/users/{users[0]}/export").json()
    theirs = [d for e in export["episodes"] for d in e["shadow_decisions"]]
    mine_ids = {row[0] for row in stored}
    assert theirs
    assert len(theirs) == sum(
        1 for e in export["episodes"] for d in e["decisions"] if d["decision_id"] in mine_ids
    )

    # A second pass adds nothing; the look says it in words, with the estimate.
    assert shadows.shadow_pass(app.state.db, app.state.ctx, now=_later()) == {"default": 0}
    look = staff.get(URL).json()
    assert look["decisions"] == len(stored)
    assert 0 < look["agreeing"] <= look["decisions"]
    assert look["agreement"] == pytest.approx(look["agreeing"] / look["decisions"])
    assert 0 < look["expected_agreement"] <= 1
    assert look["people"] == len(users)
    assert "would have done what the robots did in" in look["summary"]
    assert look["estimate"] is not None
    (candidate,) = look["estimate"]["candidates"]
    assert candidate["verdict"] in look["summary"]
    assert look["estimate"]["episodes"] == 3 * len(users)  # those since the shadow started

    # Stopped: nothing more is decided.
    r = staff.delete(URL)
    assert r.status_code == 200
    assert r.json()["status"] == "stopped"
    _fill(robot, users, 1, "stopped")
    assert shadows.shadow_pass(app.state.db, app.state.ctx, now=_later()) == {}
    assert staff.delete(URL).status_code == 409
    actions = [e["action"] for e in staff.get("/v1/admin/audit").json()["items"]]
    assert actions.count("shadow.start") == 1
    assert actions.count("shadow.stop") == 1


def test_a_share_shadows_only_the_people_below_it(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    users = [f"q{i:02d}" for i in range(12)]
    for user in users:
        assert robot.put(f"/v1/users/{user}", json={}).status_code == 201
    r = staff.put(URL, json={"candidate": {"algorithm": "dts"}, "share": 0.5})
    assert r.status_code == 201
    salt = _salt(app)
    _fill(robot, users, 1, "e")
    shadows.shadow_pass(app.state.db, app.state.ctx, now=_later(), estimate=False)
    with app.state.db.transaction(write=False) as session:
        pks = {r[0] for r in session.execute(select(ShadowDecision.user_pk)).all()}
    from app.db.repositories import users as users_repo

    with app.state.db.transaction(write=False) as session:
        shadowed = {users_repo.by_pk(session, pk).user_id for pk in pks}  # type: ignore[union-attr]
    assert shadowed == {u for u in users if hash_place(salt, u) < 0.5}
    assert 0 < len(shadowed) < len(users)
    # Another candidate while one runs: 409; the same one with another share: 200.
    assert staff.put(URL, json={"candidate": {"algorithm": "hri"}}).status_code == 409
    r = staff.put(URL, json={"candidate": {"algorithm": "dts"}, "share": 1.0})
    assert r.status_code == 200
    assert r.json()["share"] == 1.0


def _salt(app: FastAPI) -> str:
    from app.db.models import Shadow

    with app.state.db.transaction(write=False) as session:
        return str(session.execute(select(Shadow.salt)).scalar_one())


@pytest.mark.parametrize(
    "body",
    [
        {"candidate": {"algorithm": "nope"}},
        {"candidate": {"algorithm": "dts"}, "share": 0},
        {"candidate": {"algorithm": "dts"}, "share": 2},
        {"share": 0.5},
        {"candidate": {"algorithm": "dts"}, "extra": True},
    ],
)
def test_bad_shadows_get_422(app: FastAPI, staff: TestClient, body: dict[str, Any]) -> None:
    assert staff.put(URL, json=body).status_code == 422


def test_who_may_shadow(
    app: FastAPI, robot: TestClient, staff: TestClient, other_staff: TestClient
) -> None:
    body = {"candidate": {"algorithm": "dts"}}
    assert staff.get(URL).status_code == 404
    assert robot.put(URL, json=body).status_code == 403
    assert other_staff.put(URL, json=body).status_code == 403
    assert staff.put(URL, json=body).status_code == 201
    assert other_staff.get(URL).status_code == 403
    assert robot.delete(URL).status_code == 403


def test_the_service_runs_the_pass_in_a_process_of_its_own(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    """What the worker runs (``pass_in_process``): a Python process of its own, with the
    service's database and settings; it stores what the pass in this process would."""
    users = [f"r{i}" for i in range(3)]
    for user in users:
        assert robot.put(f"/v1/users/{user}", json={}).status_code == 201
    assert staff.put(URL, json={"candidate": {"algorithm": "dts"}}).status_code == 201
    _fill(robot, users, 2, "e", occurred_at=_now())
    time.sleep(shadows.SETTLE.total_seconds() + 0.5)  # past the pass's settling time
    assert shadows.pass_in_process(app.state.settings, timeout=120) == 0
    look = staff.get(URL).json()
    assert look["decisions"] > 0
    assert look["people"] == len(users)
    assert look["estimate"] is not None
    assert shadows.shadow_pass(app.state.db, app.state.ctx, now=_later()) == {"default": 0}


def test_a_pass_that_keeps_its_candidates_decides_as_a_replay_from_the_base(
    app: FastAPI, robot: TestClient, staff: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The pass process keeps each person's candidate between its passes (``ReplayCache``) and
    teaches it only what is new: what it stores is what a replay of the whole history decides."""
    monkeypatch.setattr(shadows, "SETTLE", dt.timedelta(0))
    users = [f"k{i}" for i in range(4)]
    for user in users:
        assert robot.put(f"/v1/users/{user}", json={}).status_code == 201
    _fill(robot, users, 2, "before")
    assert staff.put(URL, json={"candidate": {"algorithm": "dts"}}).status_code == 201
    cache = ReplayCache()
    for round_ in range(3):
        _fill(robot, users, 2, f"r{round_}-", occurred_at=_now())
        if round_ == 1:  # a staff correction of one of them, taught between two passes
            quiet = {
                "correction_id": "c1",
                "time_slot": "afternoon",
                "situation": "stretching",
                "kind": "quiet",
            }
            r = staff.post(f"/v1/users/{users[0]}/corrections", json=quiet)
            assert r.status_code == 201, r.text
            _fill(robot, users[:1], 1, "quiet", occurred_at=_now())
        time.sleep(0.01)
        added = shadows.shadow_pass(app.state.db, app.state.ctx, cache=cache, estimate=False)
        assert added["default"] > 0
    assert len(cache) == len(users)
    assert cache.hits >= 2 * len(users)  # the later passes took up where the first left off
    assert cache.rereads == 0  # ...and read only what was new
    db, ctx = app.state.db, app.state.ctx
    with db.transaction(write=False) as session:
        (row,) = repo.running(session)
        stored = {
            d: (action, probabilities)
            for d, action, probabilities in session.execute(
                select(
                    ShadowDecision.decision_id, ShadowDecision.action, ShadowDecision.probabilities
                )
            )
        }
        fresh = {}
        for user in users:
            found = users_repo.get(session, "default", user)
            assert found is not None
            for d in shadow_decisions(
                session, ctx, found, shadows._spec_of(row), since=row.started_at, done=set()
            ):
                fresh[d.decision_id] = (d.action, d.probabilities)
    assert stored.keys() == fresh.keys()
    for decision_id, (action, probabilities) in fresh.items():
        assert stored[decision_id][0] == action
        assert stored[decision_id][1] == pytest.approx(probabilities, abs=1e-12)


def test_the_worker_starts_the_pass_process_only_while_a_shadow_runs(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    """What each worker runs (``PassProcess``): without a shadow it starts nothing; with one, a
    pass process of its own, which stores the shadow's decisions and holds the lease (another
    worker starts none meanwhile); it ends when the shadow stops, and with the worker."""
    settings = app.state.settings.model_copy(update={"shadow_seconds": 1.0})
    worker = shadows.PassProcess(app.state.db, settings)
    other = shadows.PassProcess(app.state.db, settings)
    try:
        assert not worker.tick()  # no shadow
        assert not worker.running()
        users = [f"w{i}" for i in range(3)]
        for user in users:
            assert robot.put(f"/v1/users/{user}", json={}).status_code == 201
        assert staff.put(URL, json={"candidate": {"algorithm": "dts"}}).status_code == 201
        _fill(robot, users, 2, "e", occurred_at=_now())
        assert worker.tick()
        assert worker.running()
        assert not worker.tick()  # it runs: no second one
        deadline = time.monotonic() + WAIT_S
        while staff.get(URL).json()["decisions"] == 0:
            assert time.monotonic() < deadline, "the pass process stored nothing"
            time.sleep(0.2)
        assert not other.tick()  # the lease is held
        _fill(robot, users, 1, "more", occurred_at=_now())  # passed again, by the same process
        seen = staff.get(URL).json()["decisions"]
        while staff.get(URL).json()["decisions"] == seen:
            assert time.monotonic() < deadline, "the pass process did not pass again"
            time.sleep(0.2)
        assert staff.delete(URL).status_code == 200
        while worker.running():  # no shadow: it ends on its own
            assert time.monotonic() < deadline, "the pass process did not end"
            time.sleep(0.2)
        assert not worker.tick()
    finally:
        worker.stop()
        other.stop()
    assert not worker.running()


def test_a_stopping_worker_ends_its_pass_process(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    settings = app.state.settings.model_copy(update={"shadow_seconds": 60.0})
    assert robot.put("/v1/users/s0", json={}).status_code == 201
    assert staff.put(URL, json={"candidate": {"algorithm": "dts"}}).status_code == 201
    worker = shadows.PassProcess(app.state.db, settings)
    assert worker.tick()
    began = time.monotonic()
    worker.stop()  # the pipe closed: it ends without waiting out its 60 s
    assert not worker.running()
    assert time.monotonic() - began < shadows.STOP_WAIT_S
