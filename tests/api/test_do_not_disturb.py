"""Do not disturb, through the API: in a situation of the fleet's mission's
``unavailable_situations`` the robot never initiates, for every learner, from the first event
on and after a mission change that adds the situation to a model that had learned to offer
there; a person who asks is served; the model view and the profile agree; rebuild stays
identical; a change that removes the situation lets learning resume."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.learning import ALGORITHMS
from app.settings import Settings
from tests.support.commands import rebuild

CARE = json.loads(
    (Path(__file__).parents[2] / "docs" / "examples" / "care-home-mission.json").read_text()
)
OPEN = {**CARE, "name": "care-home-open", "unavailable_situations": []}
NIGHT = "2026-11-22T23:10:00+01:00"  # local 23:10: the care-home mission's "night"


def _mission(staff: TestClient, change_id: str, doc: dict[str, Any]) -> None:
    r = staff.put("/v1/admin/fleets/default/mission", json={"change_id": change_id, "mission": doc})
    assert r.status_code == 200, r.text


def _p(decision: dict[str, Any]) -> dict[str, float]:
    return {p["action"]["kind"]: p["p"] for p in decision["probabilities"]}


def _episode(
    robot: TestClient, uid: str, event_id: str, *, accept: bool, ask: bool, quiet: bool = True
) -> list[str]:
    """One robot-noticed episode at night in personal care; the person accepts every offer (or
    not), asks for tea when the robot stays passive (or not), and takes tea. The kinds of the
    robot's decisions, in order. ``quiet``: the first decision must be a pass drawn with
    probability exactly 1."""
    r = robot.post(
        f"/v1/users/{uid}/episodes",
        json={"event_id": event_id, "occurred_at": NIGHT, "situation": "personal_care"},
    )
    assert r.status_code == 201, r.text
    ep = r.json()
    kinds: list[str] = []
    decision = ep["decision"]
    while decision is not None:
        action = decision["action"]
        kinds.append(action["kind"])
        if quiet and len(kinds) == 1:
            assert _p(decision) == {"initiate": 0.0, "pass": 1.0}, decision
        if action["kind"] == "pass":
            body: dict[str, Any] = (
                {"response": "human_request", "service": "ProvideDrink"}
                if ask
                else {"response": "none"}
            )
        elif action["kind"] == "initiate":
            body = {"response": "accepted" if accept else "rejected"}
        elif action["kind"] == "query_type":
            body = {"response": "answered", "service": "ProvideDrink"}
        elif action["kind"] == "query_detail":
            tea = action["service"] == "ProvideDrink"
            body = {"response": "answered", "detail": "tea"} if tea else {"response": "terminated"}
        else:
            wanted = (action.get("service"), action.get("detail")) == ("ProvideDrink", "tea")
            body = {"response": "accepted" if wanted else "rejected"}
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/outcomes",
            json={"decision_id": decision["decision_id"], **body},
        )
        assert r.status_code == 200, r.text
        decision = r.json()["decision"]
    return kinds


def _p_initiate(client: TestClient, uid: str) -> float:
    r = client.get(
        f"/v1/users/{uid}/model", params={"time_slot": "night", "situation": "personal_care"}
    )
    assert r.status_code == 200, r.text
    [context] = r.json()["contexts"]
    observe = next(s for s in context["states"] if s["state"] == "OBSERVE")
    return float(next(a["p"] for a in observe["actions"] if a["action"]["kind"] == "initiate"))


def _will(client: TestClient, uid: str) -> str:
    r = client.get(f"/v1/users/{uid}/profile")
    assert r.status_code == 200, r.text
    ctx = next(
        c
        for c in r.json()["contexts"]
        if (c["time_slot"], c["situation"]) == ("night", "personal_care")
    )
    return str(ctx["robot_will"]["action"])


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_a_new_person_is_never_disturbed(
    algorithm: str, robot: TestClient, staff: TestClient
) -> None:
    _mission(staff, "care", CARE)
    uid = f"new-{algorithm}"
    r = staff.put(f"/v1/users/{uid}", json={"learner": {"algorithm": algorithm}})
    assert r.status_code == 201, r.text
    assert _p_initiate(robot, uid) == 0.0
    asked = 0
    for e in range(24):
        kinds = _episode(robot, uid, f"{uid}-{e}", accept=True, ask=e % 3 == 0)
        assert kinds[0] == "pass", kinds
        assert "initiate" not in kinds
        if e % 3 == 0:  # she asked: served as usual, up to a perform
            asked += 1
            assert kinds[-1] == "perform", kinds
    assert asked == 8
    assert _p_initiate(robot, uid) == 0.0
    assert _will(staff, uid) == "stay_away"


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_a_mission_change_applies_at_once_and_is_undone_by_the_next(
    algorithm: str, robot: TestClient, staff: TestClient, settings: Settings
) -> None:
    _mission(staff, "open", OPEN)
    uid = f"eager-{algorithm}"
    r = staff.put(f"/v1/users/{uid}", json={"learner": {"algorithm": algorithm}})
    assert r.status_code == 201, r.text
    offered = 0
    for e in range(40):
        kinds = _episode(robot, uid, f"{uid}-a{e}", accept=True, ask=False, quiet=False)
        offered += kinds.count("initiate")
    learned = _p_initiate(robot, uid)
    # without the rule it offers here
    assert offered > 0
    assert learned > 0.0

    _mission(staff, "care", CARE)  # adds personal_care to the unavailable situations
    assert _p_initiate(robot, uid) == 0.0
    assert _will(staff, uid) == "stay_away"
    for e in range(12):
        kinds = _episode(robot, uid, f"{uid}-b{e}", accept=True, ask=e % 2 == 0)
        assert "initiate" not in kinds
    summary = rebuild(settings.database_url, uid, pooler=settings.database_pooler).summary
    assert summary["identical"] is True, summary

    _mission(staff, "open-again", {**OPEN, "name": "care-home-open-2"})
    assert _p_initiate(robot, uid) > 0.0  # learning decides again
    summary = rebuild(settings.database_url, uid, pooler=settings.database_pooler).summary
    assert summary["identical"] is True, summary


def test_a_quiet_correction_holds_for_one_person_and_one_context(
    robot: TestClient, staff: TestClient
) -> None:
    _mission(staff, "open", OPEN)
    for uid in ("quiet", "loud"):
        assert staff.put(f"/v1/users/{uid}", json={}).status_code == 201
        for e in range(30):
            _episode(robot, uid, f"{uid}-{e}", accept=True, ask=False, quiet=False)
        assert _p_initiate(robot, uid) > 0.0
    r = staff.post(
        "/v1/users/quiet/corrections",
        json={
            "correction_id": "quiet-at-night",
            "kind": "quiet",
            "time_slot": "night",
            "situation": "personal_care",
        },
    )
    assert r.status_code == 201, r.text
    assert _p_initiate(robot, "quiet") == 0.0
    assert _p_initiate(robot, "loud") > 0.0
    for e in range(10):
        assert "initiate" not in _episode(robot, "quiet", f"quiet-x{e}", accept=True, ask=False)
    assert _will(staff, "quiet") == "stay_away"
