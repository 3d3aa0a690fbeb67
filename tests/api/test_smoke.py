from __future__ import annotations

from fastapi.testclient import TestClient

from .helpers import answer, start


def test_an_episode_runs_to_its_end(robot: TestClient) -> None:
    ep = start(robot, "lin", "e1")
    decision = ep["decision"]
    while decision is not None:
        kind = decision["action"]["kind"]
        if kind == "pass":
            out = answer(robot, ep["episode_id"], decision["decision_id"], "none")
        elif kind == "query_type":
            out = answer(robot, ep["episode_id"], decision["decision_id"], "answered",
                         service="ProvideDrink")
        elif kind == "query_detail":
            out = answer(robot, ep["episode_id"], decision["decision_id"], "answered",
                         detail=decision["action"].get("service") and "tea")
        else:
            out = answer(robot, ep["episode_id"], decision["decision_id"], "accepted")
        decision = out["decision"]
    trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
    assert trace["status"] == "closed"
