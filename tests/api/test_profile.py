"""The profile: a simulated person with a known routine, served through the API, shows it in
plain words, tentative after one episode and confident after enough; counts agree with the
history (open episodes included), the robot's intention with ``GET /model``, times are the
person's local time, and a change of mind is reported."""

from __future__ import annotations

import datetime as dt
from typing import Any

from fastapi.testclient import TestClient

from tests.api.test_corrections import SITUATION, SLOT, TEA, _cell, make_user, meet
from tests.support.episodes import start


def test_a_routine_becomes_confident(staff: TestClient, robot: TestClient) -> None:
    make_user(staff)
    staff.put("/v1/users/chen", json={"display_name": "Mrs. Chen"})
    first = _cell(robot.get("/v1/users/chen/profile").json())
    assert first["certainty"] == "unknown"
    assert first["wants"] is None
    assert "not enough to say yet" in first["summary"]

    start(robot, "chen", "one", initiator="human", request=TEA)  # she asks for tea herself
    one = _cell(robot.get("/v1/users/chen/profile").json())
    assert one["wants"] == TEA
    assert one["certainty"] == "tentative"
    assert one["evidence"]["support"] == 1
    assert one["evidence"]["recent"] == 1
    assert one["evidence"]["asked_for"] == 1
    assert "may want tea" in one["summary"]
    assert "tentative" in one["summary"]

    meet(robot, "chen", 14, "more", seed=3)
    cell = _cell(robot.get("/v1/users/chen/profile").json())
    assert cell["wants"] == TEA
    assert cell["certainty"] == "confident"
    assert cell["source"] == "person"
    assert cell["episodes"] == 15
    assert cell["open_episodes"] == 1
    said = cell["summary"]
    assert said.startswith("In the afternoon, while stretching, Mrs. Chen usually wants tea")
    assert "confident" in said
    ev = cell["evidence"]
    assert ev["accepted"] + ev["asked_for"] + ev["answered"] >= 15
    assert ev["support"] >= 3
    assert ev["support"] <= ev["recent"] <= 8
    # elsewhere nothing is known yet
    other = _cell(robot.get("/v1/users/chen/profile").json(), "morning", "arriving")
    assert other["certainty"] == "unknown"
    assert other["episodes"] == 0


def test_counts_times_and_the_model_agree(staff: TestClient, robot: TestClient) -> None:
    make_user(staff)
    meet(robot, "chen", 3, "done")
    start(robot, "chen", "open-one")  # left open
    profile = robot.get("/v1/users/chen/profile").json()
    cell = _cell(profile)
    assert profile["episodes"] == 4
    assert profile["open_episodes"] == 1
    assert cell["episodes"] == 4
    assert cell["open_episodes"] == 1
    assert profile["utc_offset"] == 8 * 60
    seen = dt.datetime.fromisoformat(cell["evidence"]["last_seen"])
    assert seen.utcoffset() == dt.timedelta(hours=8)
    assert seen.hour == 15
    model = robot.get(f"/v1/users/chen/model?time_slot={SLOT}&situation={SITUATION}").json()
    [context] = model["contexts"]
    initiate = context["states"][0]["actions"][0]
    assert initiate["action"]["kind"] == "initiate"
    assert cell["robot_will"]["probability"] == initiate["p"]
    assert (cell["robot_will"]["action"] == "offer") == (initiate["p"] >= 0.5)
    traces = [
        robot.get(f"/v1/episodes/{e['episode_id']}").json()
        for e in robot.get("/v1/users/chen/episodes").json()["items"]
    ]
    accepted = sum(
        1
        for t in traces
        for d in t["decisions"]
        if d["action"]["kind"] == "perform" and d.get("response") == "accepted"
    )
    assert cell["evidence"]["accepted"] == accepted


def test_a_change_of_mind_is_reported(staff: TestClient, robot: TestClient) -> None:
    make_user(staff)
    meet(robot, "chen", 8, "tea")
    meet(robot, "chen", 2, "coffee", need=("ProvideDrink", "coffee"), seed=5)
    cell = _cell(robot.get("/v1/users/chen/profile").json())
    assert cell["wants"] == {"service": "ProvideDrink", "detail": "coffee"}
    assert cell["certainty"] == "tentative"
    changed: dict[str, Any] = cell["changed"]
    assert changed["before"] == TEA
    assert changed["now"]["detail"] == "coffee"
    assert changed["episode"] == 9
    assert "changed from tea" in cell["summary"]


def test_a_change_of_mind_is_reported_while_recent(staff: TestClient, robot: TestClient) -> None:
    make_user(staff)
    meet(robot, "chen", 8, "tea")
    meet(robot, "chen", 2, "coffee", need=("ProvideDrink", "coffee"), seed=5)
    assert _cell(robot.get("/v1/users/chen/profile").json())["changed"] is not None
    # once the episode it began with is no longer among the latest 8 there, it is old news
    meet(robot, "chen", 8, "more-coffee", need=("ProvideDrink", "coffee"), seed=6)
    cell = _cell(robot.get("/v1/users/chen/profile").json())
    assert cell["wants"] == {"service": "ProvideDrink", "detail": "coffee"}
    assert cell["changed"] is None
    assert "changed from" not in cell["summary"]
