"""Rollouts of a candidate learner (``/v1/admin/fleets/{fleet}/rollout``), on both engines: arms
by a salted stable hash, stored, and moved only when staff say so; a person moved keeps what was
learned; newcomers get an arm; the arms compared with the always-valid interval; promote, roll
back and the guard's automatic roll back; the arm in the profile and the export; who may."""

from __future__ import annotations

import copy
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.db.models import RolloutArm
from app.db.repositories import rollouts as rollouts_repo
from app.db.repositories import users as users_repo
from app.services import rollouts
from app.services.person_model import PersonModel
from tests.support import people
from tests.support.episodes import play
from tests.support.office import MISSION

URL = "/v1/admin/fleets/default/rollout"
CANDIDATE = {"algorithm": "hri", "params": {"tau": 0.005}}
TEA = ("ProvideDrink", "tea")


def _people(robot: TestClient, n: int, episodes: int = 1, prefix: str = "p") -> list[str]:
    users = [f"{prefix}{i:02d}" for i in range(n)]
    for user in users:
        r = robot.put(f"/v1/users/{user}", json={"learner": {"algorithm": "hri"}})
        assert r.status_code == 201, r.text
        for e in range(episodes):
            play(robot, user, f"{user}-e{e}", people.person(need=TEA))
    return users


def _settle(app: FastAPI) -> None:
    """The moves the rollout owes, done (the worker's mover does them in the background)."""
    app.state.rollout_mover.join()
    rollouts.complete_moves(app.state.db, app.state.ctx)
    with app.state.db.transaction(write=False) as session:
        assert (
            session.execute(select(RolloutArm).where(RolloutArm.pending.is_(True))).first() is None
        )


def _learner(api: TestClient, user: str) -> dict[str, Any]:
    learner: dict[str, Any] = api.get(f"/v1/users/{user}").json()["learner"]
    return learner


def _arms(app: FastAPI) -> dict[str, str]:
    """Every stored arm, by person id."""
    with app.state.db.transaction(write=False) as session:
        rows = session.execute(select(RolloutArm.user_pk, RolloutArm.arm)).all()
        return {users_repo.by_pk(session, pk).user_id: arm for pk, arm in rows}  # type: ignore[union-attr]


def _tables(app: FastAPI, user: str) -> dict[str, Any]:
    """The person's learned tables (the model's state without its parameters)."""
    with app.state.db.transaction(write=False) as session:
        row = users_repo.get(session, "default", user)
        assert row is not None
        state = PersonModel.open(session, app.state.ctx, row).learner.to_state()
    return {k: v for k, v in state.items() if k not in ("params", "algorithm", "version")}


def test_a_rollout_assigns_stores_and_moves_keeping_what_was_learned(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    users = _people(robot, 24, episodes=2)
    before = {u: _tables(app, u) for u in users}
    r = staff.put(URL, json={"candidate": CANDIDATE, "share": 0.3})
    _settle(app)
    assert r.status_code == 201, r.text
    started = r.json()
    assert started["status"] == "running"
    assert started["candidate"]["key"] == "hri:tau=0.005"
    arms = _arms(app)
    assert set(arms) == set(users)
    moved = sorted(u for u, a in arms.items() if a == "candidate")
    assert started["people"] == {"candidate": len(moved), "control": 24 - len(moved)}
    assert 0 < len(moved) < 24
    for user in users:
        learner = _learner(staff, user)
        if user in moved:
            assert learner["params"]["tau"] == 0.005
        else:
            assert learner["params"]["tau"] != 0.005
        # HRI's tables do not depend on τ: taught the same history, the candidate holds what
        # the person's model held.
        assert _tables(app, user) == before[user]
    profile = staff.get(f"/v1/users/{moved[0]}/profile").json()
    assert profile["rollout"]["arm"] == "candidate"
    assert profile["rollout"]["rollout_id"] == started["rollout_id"]
    assert staff.get(f"/v1/users/{users[0]}/profile").json()["rollout"]["arm"] == arms[users[0]]
    export = staff.get(f"/v1/users/{moved[0]}/export").json()
    (arm,) = export["rollout_arms"]
    assert arm["arm"] == "candidate"
    assert arm["previous_learner"]["algorithm"] == "hri"
    audit = [e["action"] for e in staff.get("/v1/admin/audit?limit=200").json()["items"]]
    assert audit.count("rollout.start") == 1
    assert audit.count("user.learner") == len(moved)

    # The same PUT again changes nothing; a lower share moves no one.
    assert staff.put(URL, json={"candidate": CANDIDATE, "share": 0.3}).status_code == 200
    r = staff.put(URL, json={"candidate": CANDIDATE, "share": 0.1})
    assert r.status_code == 200
    assert r.json()["share"] == 0.1
    assert _arms(app) == arms
    # A mission change moves no one either.
    changed = copy.deepcopy(MISSION.to_dict())
    changed["services"][0]["details"].append("cocoa")
    r = staff.put("/v1/admin/fleets/default/mission", json={"change_id": "m2", "mission": changed})
    assert r.status_code == 200, r.text
    assert _arms(app) == arms
    # A higher share moves more people; those in the candidate's arm stay there.
    r = staff.put(URL, json={"candidate": CANDIDATE, "share": 0.8})
    _settle(app)
    wider = _arms(app)
    assert {u for u, a in wider.items() if a == "candidate"} > set(moved)
    assert r.json()["people"]["candidate"] == sum(a == "candidate" for a in wider.values())
    # Another candidate while one runs: 409.
    r = staff.put(URL, json={"candidate": {"algorithm": "dts"}, "share": 0.5})
    assert r.status_code == 409
    assert "running" in r.json()["detail"]


def test_the_arms_survive_a_restart(app: FastAPI, robot: TestClient, staff: TestClient) -> None:
    _people(robot, 10)
    staff.put(URL, json={"candidate": CANDIDATE, "share": 0.5})
    _settle(app)
    arms = _arms(app)
    from app.main import create_app

    again = create_app(app.state.settings)
    try:
        assert _arms(again) == arms
    finally:
        again.state.db.dispose()


def test_newcomers_get_an_arm_unless_their_learner_was_chosen(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    _people(robot, 3)
    staff.put(URL, json={"candidate": CANDIDATE, "share": 0.5})
    _settle(app)
    newcomers = [f"new{i:02d}" for i in range(16)]
    for user in newcomers:
        assert robot.put(f"/v1/users/{user}", json={}).status_code == 201
    chosen = robot.put("/v1/users/chosen", json={"learner": {"algorithm": "dts"}})
    assert chosen.status_code == 201
    arms = _arms(app)
    assert "chosen" not in arms
    assert set(newcomers) <= set(arms)
    for user in newcomers:
        learner = _learner(staff, user)
        if arms[user] == "candidate":
            assert (learner["algorithm"], learner["params"]["tau"]) == ("hri", 0.005)
        else:
            assert learner["algorithm"] == "dts-routine"  # the default
    assert {arms[u] for u in newcomers} == {"candidate", "control"}
    # A robot starting an episode for an unknown person creates them: an arm too.
    play(robot, "walk-in", "walk-in-e0", people.person(need=TEA))
    assert "walk-in" in _arms(app)


def test_promote_and_roll_back(app: FastAPI, robot: TestClient, staff: TestClient) -> None:
    users = _people(robot, 10, episodes=1)
    staff.put(URL, json={"candidate": CANDIDATE, "share": 0.5})
    _settle(app)
    arms = _arms(app)
    r = staff.post(f"{URL}/promote")
    _settle(app)
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "promoted"
    assert r.json()["ended_by"] is not None
    for user in users:
        assert _learner(staff, user)["params"]["tau"] == 0.005
    assert _arms(app) == arms  # the arms are what they were: the record of the rollout
    assert robot.put("/v1/users/late", json={}).status_code == 201
    assert _learner(staff, "late")["params"]["tau"] == 0.005
    assert staff.post(f"{URL}/promote").status_code == 409
    assert staff.post(f"{URL}/rollback").status_code == 409

    # A new rollout after it; rolled back: the candidate people get their learner back.
    r = staff.put(URL, json={"candidate": {"algorithm": "dts"}, "share": 0.5})
    _settle(app)
    assert r.status_code == 201, r.text
    second = r.json()["rollout_id"]
    with app.state.db.transaction(write=False) as session:
        mine = {
            users_repo.by_pk(session, a.user_pk).user_id: a.arm  # type: ignore[union-attr]
            for a, _ in rollouts_repo.arms(session, second)
        }
    r = staff.post(f"{URL}/rollback", json={"reason": "the night staff asked"})
    _settle(app)
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "rolled_back"
    assert r.json()["end_reason"] == "the night staff asked"
    for user, arm in mine.items():
        learner = _learner(staff, user)
        assert learner["algorithm"] == "hri"
        assert learner["params"]["tau"] == 0.005, (user, arm)
    assert robot.put("/v1/users/later", json={}).status_code == 201
    assert _learner(staff, "later")["algorithm"] == "dts-routine"
    actions = [e["action"] for e in staff.get("/v1/admin/audit?limit=200").json()["items"]]
    assert actions.count("rollout.promote") == 1
    assert actions.count("rollout.rollback") == 1


def test_the_guard_rolls_back_a_worse_candidate(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    users = _people(robot, 30)  # each arm gets 5 or more but in 1 rollout in 15,000
    staff.put(URL, json={"candidate": CANDIDATE, "share": 0.5})
    _settle(app)
    arms = _arms(app)
    assert sum(a == "candidate" for a in arms.values()) >= 5
    assert sum(a == "control" for a in arms.values()) >= 5
    # Nothing yet to compare: the guard leaves it.
    assert rollouts.check_guard(app.state.db, app.state.ctx) == []
    # The candidate's people turn everything down; the others get their tea.
    # (Until the comparison says so: how soon depends on the arms the salt gave; bounded.)
    for round_ in range(12):
        for user in users:
            who = people.person(need=None) if arms[user] == "candidate" else people.person(need=TEA)
            play(robot, user, f"{user}-g{round_}", who)
        look = staff.get(URL).json()
        assert look["comparison"]["verdict"] != "better", look
        if look["comparison"]["verdict"] == "worse":
            break
    assert look["comparison"]["verdict"] == "worse", look
    assert look["guard"] is True
    assert "earns less" in look["summary"]
    assert rollouts.check_guard(app.state.db, app.state.ctx) == ["default"]
    ended = staff.get(URL).json()
    assert ended["status"] == "rolled_back"
    assert ended["ended_by"] == "guard"
    assert "guard" in ended["end_reason"]
    (entry,) = [
        e
        for e in staff.get("/v1/admin/audit?limit=200").json()["items"]
        if e["action"] == "rollout.rollback"
    ]
    assert entry["actor"]["key_id"] == "guard"
    for user, arm in arms.items():
        assert _learner(staff, user)["params"]["tau"] != 0.005, (user, arm)
    assert rollouts.check_guard(app.state.db, app.state.ctx) == []


def test_looks_without_enough_evidence_say_so(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    assert staff.get(URL).status_code == 404
    _people(robot, 4)
    look = staff.put(URL, json={"candidate": CANDIDATE, "share": 0.5}).json()
    assert look["comparison"]["enough"] is False
    assert look["comparison"]["verdict"] == "no difference yet"
    assert look["summary"].startswith("Not enough evidence yet")
    assert look["guard"] is False


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"candidate": CANDIDATE, "share": 0}, "share"),
        ({"candidate": CANDIDATE, "share": 1.5}, "share"),
        ({"candidate": {"algorithm": "nope"}, "share": 0.5}, "candidate"),
        ({"candidate": {"algorithm": "hri", "params": {"tau": -1}}, "share": 0.5}, "candidate"),
        ({"candidate": CANDIDATE}, "share"),
        ({"candidate": CANDIDATE, "share": 0.5, "extra": 1}, "extra"),
    ],
)
def test_bad_rollouts_get_422(
    app: FastAPI, staff: TestClient, body: dict[str, Any], field: str
) -> None:
    r = staff.put(URL, json=body)
    assert r.status_code == 422, r.text
    assert field in r.text


def test_who_may_roll_out(
    app: FastAPI, robot: TestClient, staff: TestClient, other_staff: TestClient
) -> None:
    users = _people(robot, 2)
    body = {"candidate": CANDIDATE, "share": 0.5}
    assert robot.put(URL, json=body).status_code == 403
    assert robot.get(URL).status_code == 403
    assert other_staff.put(URL, json=body).status_code == 403
    assert staff.put(URL, json=body).status_code == 201
    assert other_staff.get(URL).status_code == 403
    assert other_staff.post(f"{URL}/promote").status_code == 403
    assert robot.post(f"{URL}/rollback").status_code == 403
    # Erasing a person erases their arm.
    assert staff.delete(f"/v1/users/{users[0]}").status_code == 204
    assert users[0] not in _arms(app)


def test_moves_are_owed_then_done_a_person_at_a_time_even_after_a_restart(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    users = _people(robot, 14, episodes=1)
    app.state.rollout_mover = None  # this worker's mover stopped before it moved anyone
    started = staff.put(URL, json={"candidate": CANDIDATE, "share": 0.5}).json()
    arms = _arms(app)
    candidates = [u for u in users if arms[u] == "candidate"]
    assert started["moving"] == len(candidates) > 0
    for user in candidates:
        assert _learner(staff, user)["params"]["tau"] != 0.005  # not moved yet
        assert staff.get(f"/v1/users/{user}/profile").json()["rollout"]["moving"] is True
    # The episodes of a person not moved yet are not compared.
    play(robot, candidates[0], "early", people.person(need=TEA))
    assert staff.get(URL).json()["comparison"]["candidate"]["n_episodes"] == 0
    # The next worker to start does the moves left owed.
    from app.main import create_app

    again = create_app(app.state.settings)
    try:
        with TestClient(again):
            again.state.rollout_mover.join(30)
    finally:
        again.state.db.dispose()
    assert staff.get(URL).json()["moving"] == 0
    for user in candidates:
        assert _learner(staff, user)["params"]["tau"] == 0.005
        assert staff.get(f"/v1/users/{user}/profile").json()["rollout"]["moving"] is False
    audit = staff.get("/v1/admin/audit?limit=200").json()["items"]
    moves = [e for e in audit if e["action"] == "user.learner"]
    assert {e["target"] for e in moves} == set(candidates)
    assert {e["actor"]["key_id"] for e in moves} == {"rollout"}
