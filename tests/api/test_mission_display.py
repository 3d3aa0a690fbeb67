"""A fleet's display settings, on both engines: labels and a time zone in the mission document
change neither its fingerprint nor its version; the profile's sentences and the console's pages
use the labels, and show times in the fleet's time zone."""

from __future__ import annotations

import html
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from tests.support import people
from tests.support.episodes import report, start
from tests.support.fixtures import MakeKey

FLEET = "care"
CARE_HOME = json.loads(
    (Path(__file__).parents[2] / "docs" / "examples" / "care-home-mission.json").read_text()
)
PLAIN = {k: v for k, v in CARE_HOME.items() if k not in ("labels", "time_zone")}


def _set(api: TestClient, change_id: str, mission: dict[str, Any]) -> dict[str, Any]:
    r = api.put(
        f"/v1/admin/fleets/{FLEET}/mission", json={"change_id": change_id, "mission": mission}
    )
    assert r.status_code == 200, r.text
    out: dict[str, Any] = r.json()
    return out


@pytest.fixture
def staff(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    with TestClient(app, headers={"Authorization": f"Bearer {make_key('staff', FLEET)}"}) as c:
        yield c


def test_labels_and_time_zone_keep_the_version_and_the_fingerprint(
    staff: TestClient, app: FastAPI, make_key: MakeKey
) -> None:
    first = _set(staff, "plain", PLAIN)
    assert first["changed"] is True
    with TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"}) as robot:
        assert robot.put("/v1/users/okafor", json={"display_name": "Mr. Okafor"}).status_code == 201
        model = robot.get("/v1/users/okafor/model").json()
        labelled = _set(staff, "labels", CARE_HOME)
        assert labelled["changed"] is False
        assert labelled["version"] == first["version"]
        assert labelled["fingerprint"] == first["fingerprint"]
        assert labelled["users_moved"] == 0
        # The model did not move; the mission in force shows the labels and the time zone.
        assert robot.get("/v1/users/okafor/model").json()["version"] == model["version"]
        got = robot.get("/v1/mission").json()
        assert got["version"] == first["version"]
        assert got["fingerprint"] == first["fingerprint"]
        assert got["labels"] == CARE_HOME["labels"]
        assert got["time_zone"] == CARE_HOME["time_zone"]
        listed = staff.get(f"/v1/admin/fleets/{FLEET}/missions").json()["items"]
        assert [i["version"] for i in listed] == [2, 1]  # the default, then the plain one
        assert listed[0]["mission"]["labels"] == CARE_HOME["labels"]


def test_a_bad_time_zone_or_label_is_the_contracts_422(staff: TestClient) -> None:
    for mission, where in (
        ({**PLAIN, "time_zone": "Mars/Olympus"}, "time_zone"),
        ({**PLAIN, "labels": {"cha": "tea"}}, "labels.cha"),
    ):
        r = staff.put(
            f"/v1/admin/fleets/{FLEET}/mission", json={"change_id": "bad", "mission": mission}
        )
        assert r.status_code == 422, r.text
        body = r.json()
        assert set(body) >= {"error", "detail", "request_id"}
        assert where in body["detail"]


def test_the_profile_and_the_console_use_the_labels(
    staff: TestClient, app: FastAPI, make_key: MakeKey
) -> None:
    _set(staff, "care", CARE_HOME)
    with TestClient(app, headers={"Authorization": f"Bearer {make_key('robot', FLEET)}"}) as robot:
        assert robot.put("/v1/users/okafor", json={"display_name": "Mr. Okafor"}).status_code == 201
        call: people.Need = ("CallFamily", "phone_call")
        for n in range(3):
            episode = start(
                robot,
                "okafor",
                f"e{n}",
                situation="meal",
                occurred_at=f"2026-11-2{n}T12:30:00+00:00",
            )
            decision = episode["decision"]
            while decision is not None:
                fields = people.answer(decision["action"], need=call)
                decision = report(robot, episode["episode_id"], decision["decision_id"], **fields)[
                    "decision"
                ]
        profile = robot.get("/v1/users/okafor/profile").json()
    lunch = next(
        c for c in profile["contexts"] if (c["time_slot"], c["situation"]) == ("lunch", "meal")
    )
    assert lunch["summary"].startswith("Lunchtime, at a meal, Mr. Okafor")
    assert "a phone call" in lunch["summary"]
    client = TestClient(app, follow_redirects=False)
    client.cookies.set("attune_console", make_key("staff", FLEET), path="/admin")
    with client:
        page = html.unescape(client.get("/admin/users/okafor").text)
        offers = page.split('id="offers"')[1].split("</table>")[0]
        assert "A call to the family" in offers
        assert "a video call, a phone call" in offers
        assert "CallFamily" not in re.sub(r'data-service="[^"]*"', "", offers)
        assert ">Lunchtime<" in page
        episodes = html.unescape(client.get("/admin/users/okafor/episodes").text)
        # 12:30 UTC is 12:30 in London in November; the page says which zone it uses.
        assert "2026-11-22 12:30" in episodes
        assert "Times are in the fleet's time zone, Europe/London." in episodes
        mission = html.unescape(client.get("/admin/mission").text)
        assert "(Europe/London)" in mission
