from __future__ import annotations

from fastapi.testclient import TestClient

from tests.support import people
from tests.support.episodes import report, start


def test_an_episode_runs_to_its_end(robot: TestClient) -> None:
    ep = start(robot, "lin", "e1")
    decision = ep["decision"]
    while decision is not None:  # a person who goes along with the robot but never asks
        out = report(
            robot,
            ep["episode_id"],
            decision["decision_id"],
            **people.answer(decision["action"], picky=False, asks=0.0),
        )
        decision = out["decision"]
    trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
    assert trace["status"] == "closed"
