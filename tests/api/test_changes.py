"""Changes in what a person wants, told to staff (``GET /v1/users/{id}/changes``, ``GET
/v1/admin/fleets/{fleet}/changes``), on every engine.

Lin wants tea in the afternoon while stretching, episode after episode (a picky person: she
takes tea, turns down anything else); then she wants coffee. The episodes that end after the
switch are weighed against what came before, as her profile weighs them: the second one in a
row that contradicts tea decides the change, which is recorded with when it began, where, what
she wanted before and now, and the episodes that showed it, in words for staff. A person whose
wishes hold still gives none. The record stays through a rebuild, a mission change and a
retention run, and goes when she is erased.
"""

from __future__ import annotations

import copy
import datetime as dt
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from app.db.models import ChangeEvent, ContextBelief
from app.db.session import Database
from app.learning import office_mission
from app.services import audit as audit_service
from app.services import retention
from app.services.models import rebuild_model
from tests.support.episodes import play
from tests.support.people import person

LIN, BO = "lin", "bo"
TEA = ("ProvideDrink", "tea")
COFFEE = ("ProvideDrink", "coffee")


def _meet(robot: TestClient, user_id: str, first: int, last: int, need: Any) -> None:
    for i in range(first, last):
        when = dt.datetime(2026, 11, 20, 15, 10) + dt.timedelta(days=i)
        play(
            robot,
            user_id,
            f"{user_id}-{i}",
            person(need=need, picky=True),
            situation="stretching",
            occurred_at=when.strftime("%Y-%m-%dT%H:%M:%S+08:00"),
        )


def _changes(client: TestClient, user_id: str = LIN, **params: Any) -> list[dict[str, Any]]:
    r = client.get(f"/v1/users/{user_id}/changes", params=params)
    assert r.status_code == 200, r.text
    items: list[dict[str, Any]] = r.json()["items"]
    return items


# The learners: the default decides changes itself (its routine per context); one without a
# mechanism of its own is told by the profile's belief.
SOURCES = {"dts-routine": "routine", "hri": "profile"}


@pytest.fixture(params=sorted(SOURCES))
def learner(request: pytest.FixtureRequest) -> str:
    name: str = request.param
    return name


@pytest.fixture
def changed(robot: TestClient, staff: TestClient, learner: str) -> None:
    """Lin: tea for 12 episodes, then coffee for 6; Bo: tea all along."""
    for user_id in (LIN, BO):
        r = staff.put(f"/v1/users/{user_id}", json={"learner": {"algorithm": learner}})
        assert r.status_code == 201, r.text
    _meet(robot, LIN, 0, 12, TEA)
    _meet(robot, LIN, 12, 18, COFFEE)
    _meet(robot, BO, 0, 18, TEA)


@pytest.mark.usefixtures("changed")
def test_a_changed_wish_is_recorded_once_with_its_evidence_and_words(
    staff: TestClient, robot: TestClient, learner: str
) -> None:
    items = _changes(staff)
    assert len(items) == 1, items
    (change,) = items
    assert change["source"] == SOURCES[learner]
    assert (change["time_slot"], change["situation"]) == ("afternoon", "stretching")
    assert change["before"] == {"service": "ProvideDrink", "detail": "tea"}
    # now: what her latest answers chose (a drink, or coffee itself), or nothing yet
    assert change["now"] is None or change["now"]["detail"] in (None, "coffee")
    # It began with the first episode after the switch, and that one or a later one decided it.
    assert change["since"]["episode"] == 13
    assert 13 <= change["decided"]["episode"] <= 18
    assert change["since"]["at"].startswith("2026-12-02T15:10:00+08:00")  # her local time
    shown = [e["episode"] for e in change["evidence"]]
    assert shown[0] == 13
    assert shown == sorted(shown)
    assert all(
        {"service": "ProvideDrink", "detail": "tea"} in e["turned_down"]
        or e["chose"] not in (None, {"service": "ProvideDrink", "detail": "tea"})
        for e in change["evidence"]
    )
    assert change["summary"].startswith("Since 2 December, this person")
    assert "tea" in change["summary"]
    assert "in the afternoon, while stretching" in change["summary"]
    # A person whose wish holds still: nothing to tell.
    assert _changes(staff, BO) == []
    # Staff and admins read it; robots do not.
    assert robot.get(f"/v1/users/{LIN}/changes").status_code == 403


@pytest.mark.usefixtures("changed")
def test_the_fleet_page_lists_changes_newest_first_since_a_time(
    staff: TestClient, robot: TestClient, admin: TestClient
) -> None:
    _meet(robot, BO, 18, 24, COFFEE)
    r = staff.get("/v1/admin/fleets/default/changes")
    assert r.status_code == 200, r.text
    items = r.json()["items"]
    assert [i["user_id"] for i in items] == [BO, LIN]  # newest first
    page = staff.get("/v1/admin/fleets/default/changes", params={"limit": 1}).json()
    assert [i["user_id"] for i in page["items"]] == [BO]
    rest = staff.get(
        "/v1/admin/fleets/default/changes", params={"limit": 1, "cursor": page["next_cursor"]}
    ).json()
    assert [i["user_id"] for i in rest["items"]] == [LIN]
    assert rest["next_cursor"] is None
    later = (dt.datetime.now(dt.UTC) + dt.timedelta(minutes=5)).isoformat()
    assert (
        staff.get("/v1/admin/fleets/default/changes", params={"since": later}).json()["items"] == []
    )
    earlier = (dt.datetime.now(dt.UTC) - dt.timedelta(days=7)).isoformat()
    assert (
        len(
            staff.get("/v1/admin/fleets/default/changes", params={"since": earlier}).json()["items"]
        )
        == 2
    )
    assert admin.get("/v1/admin/fleets/default/changes").status_code == 200
    # Every person it names was looked at, by whom.
    looks = staff.get("/v1/admin/views", params={"limit": 100}).json()["items"]
    assert {v["user_id"] for v in looks if v["what"] == "changes"} == {LIN, BO}
    assert robot.get("/v1/admin/fleets/default/changes").status_code == 403
    assert staff.get("/v1/admin/fleets/elsewhere/changes").status_code == 403
    bad = staff.get("/v1/admin/fleets/default/changes", params={"since": "yesterday"})
    assert bad.status_code == 422


@pytest.mark.usefixtures("changed")
def test_reading_a_persons_changes_is_recorded_as_a_look(staff: TestClient) -> None:
    _changes(staff)
    views = staff.get(f"/v1/users/{LIN}/views").json()["items"]
    assert "changes" in [v["what"] for v in views]


@pytest.mark.usefixtures("changed")
def test_the_record_stays_through_a_rebuild_a_mission_change_and_a_retention_run(
    app: FastAPI, db: Database, staff: TestClient, robot: TestClient
) -> None:
    before = _changes(staff)
    with app.state.db.transaction() as session:
        report = rebuild_model(session, app.state.ctx, audit_service.CLI, LIN, save=True)
    assert report.identical
    mission = copy.deepcopy(office_mission().to_dict())
    mission["services"][0]["details"].append("cocoa")
    r = staff.put(
        "/v1/admin/fleets/default/mission", json={"change_id": "cocoa", "mission": mission}
    )
    assert r.status_code == 200, r.text
    assert _changes(staff) == before
    r = staff.put("/v1/admin/fleets/default/history", json={"history_days": 1})
    assert r.status_code == 200, r.text
    later = dt.datetime.now(dt.UTC) + dt.timedelta(days=2)
    assert retention.run(db, app.state.ctx, now=later).episodes_removed == 36
    assert _changes(staff) == before
    # Her coffee holds from here on: no new change.
    _meet(robot, LIN, 18, 22, COFFEE)
    assert _changes(staff) == before


@pytest.mark.usefixtures("changed")
def test_an_erased_person_leaves_no_change_and_no_belief(
    db: Database, staff: TestClient, learner: str
) -> None:
    assert staff.delete(f"/v1/users/{LIN}").status_code == 204
    with db.transaction(write=False) as session:
        assert session.scalar(select(func.count()).select_from(ChangeEvent)) == 0
        beliefs = session.scalar(select(func.count()).select_from(ContextBelief))
    # Bo's one context, where the profile's walk tells changes (a learner that decides them
    # itself needs no walk)
    assert beliefs == (1 if SOURCES[learner] == "profile" else 0)
