"""Each fleet's versioned mission: reading it, changing it through the API, and what a change
does to the fleet's models, episodes, feedback, exports and history (docs/method.md, "When a
mission changes")."""

from __future__ import annotations

import copy
import random
from collections.abc import Callable
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.learning import Mission, MissionError, office_mission
from app.services import audit as audit_service
from app.services.missions import LIMITS
from app.services.models import rebuild_model
from tests.support.contract import assert_error
from tests.support.episodes import play, start
from tests.support.people import Need, person

OFFICE = office_mission()
Edit = Callable[[dict[str, Any]], None]
Key = tuple[Any, ...]


# -- missions ----------------------------------------------------------------------------------
def office(*edits: Edit) -> dict[str, Any]:
    """The office mission's document, edited."""
    doc = copy.deepcopy(OFFICE.to_dict())
    for edit in edits:
        edit(doc)
    return doc


def add_cocoa(d: dict[str, Any]) -> None:
    d["services"][0]["details"].append("cocoa")  # ProvideDrink


def drop_stocks(d: dict[str, Any]) -> None:
    d["services"][1]["details"].remove("stocks")  # BriefInformation


def tea_is_cha(d: dict[str, Any]) -> None:
    d["services"][0]["details"][0] = "cha"


def add_visiting(d: dict[str, Any]) -> None:
    d["situations"].append("visiting")


def fingerprint(doc: dict[str, Any]) -> str:
    return Mission.from_dict(doc).fingerprint


# -- clients -----------------------------------------------------------------------------------
# -- calls -------------------------------------------------------------------------------------
def change(
    client: TestClient,
    doc: dict[str, Any],
    change_id: str = "c1",
    *,
    fleet: str = "default",
    renames: dict[str, Any] | None = None,
) -> dict[str, Any]:
    body: dict[str, Any] = {"change_id": change_id, "mission": doc}
    if renames is not None:
        body["renames"] = renames
    r = client.put(f"/v1/admin/fleets/{fleet}/mission", json=body)
    assert r.status_code == 200, r.text
    assert "Idempotent-Replay" not in r.headers
    out: dict[str, Any] = r.json()
    return out


def put_raw(
    client: TestClient,
    doc: Any,
    change_id: str = "c1",
    *,
    fleet: str = "default",
    renames: Any = None,
) -> Any:
    body: dict[str, Any] = {"change_id": change_id, "mission": doc}
    if renames is not None:
        body["renames"] = renames
    return client.put(f"/v1/admin/fleets/{fleet}/mission", json=body)


def versions(client: TestClient, fleet: str = "default") -> dict[str, Any]:
    r = client.get(f"/v1/admin/fleets/{fleet}/missions")
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def mission(client: TestClient, **params: str) -> dict[str, Any]:
    r = client.get("/v1/mission", params=params)
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def model(client: TestClient, user_id: str) -> dict[str, Any]:
    r = client.get(f"/v1/users/{user_id}/model")
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def beliefs(
    view: dict[str, Any], renames: dict[str, str] | None = None
) -> dict[Key, dict[str, Any]]:
    """Every action's belief by names: (slot, situation, state kind, state service, state detail,
    action kind, action service, action detail); details renamed by ``renames``."""
    ren = renames or {}
    out = {}
    for c in view["contexts"]:
        for s in c["states"]:
            for a in s["actions"]:
                act = a["action"]
                key = (
                    c["time_slot"],
                    c["situation"],
                    s["state"],
                    s["service"],
                    ren.get(s["detail"], s["detail"]),
                    act["kind"],
                    act.get("service"),
                    ren.get(act.get("detail"), act.get("detail")),
                )
                out[key] = {k: a[k] for k in ("visits", "q", "p", "since_last", "kept_visits")}
    return out


def detail_names(view: dict[str, Any]) -> set[str]:
    return {
        a["action"]["detail"]
        for c in view["contexts"]
        for s in c["states"]
        for a in s["actions"]
        if a["action"].get("detail")
    }


def served(
    client: TestClient, user_id: str, event_id: str, service: str, detail: str
) -> dict[str, Any]:
    """A closed human-initiated episode: the service asked for with its detail, performed,
    accepted."""
    ep = start(
        client, user_id, event_id, initiator="human", request={"service": service, "detail": detail}
    )
    decision = ep["decision"]
    assert decision["action"] == {"kind": "perform", "service": service, "detail": detail}
    r = client.post(
        f"/v1/episodes/{ep['episode_id']}/outcomes",
        json={"decision_id": decision["decision_id"], "response": "accepted"},
    )
    assert r.status_code == 200, r.text
    assert r.json()["decision"] is None
    return ep


def train(
    client: TestClient,
    user_id: str,
    n: int,
    need: Need = ("ProvideDrink", "tea"),
    prefix: str = "t",
) -> None:
    for i in range(n):
        play(client, user_id, f"{user_id}-{prefix}{i}", person(need=need))


# -- reading the mission -----------------------------------------------------------------------
def with_display(doc: dict[str, Any]) -> dict[str, Any]:
    """A mission document as the API answers it: with its display fields, default or set."""
    return {"labels": {}, "time_zone": "UTC", **doc}


class TestReadMission:
    def test_a_fleet_without_one_has_the_default_as_version_1(
        self, robot: TestClient, admin: TestClient
    ) -> None:
        got = mission(robot)
        assert got.pop("fleet") == "default"
        assert got.pop("version") == 1
        assert got.pop("fingerprint") == OFFICE.fingerprint
        assert got == with_display(OFFICE.to_dict())
        listed = versions(admin)
        assert listed["fleet"] == "default"
        assert listed["current_version"] == 1
        [only] = listed["items"]
        assert set(only) == {
            "version",
            "name",
            "fingerprint",
            "created_at",
            "change_id",
            "renames",
            "set_by",
            "stored",
            "mission",
        }
        assert (only["version"], only["name"], only["fingerprint"], only["stored"]) == (
            1,
            "office",
            OFFICE.fingerprint,
            False,
        )
        assert only["mission"] == with_display(OFFICE.to_dict())

    def test_version_1_is_stored_with_the_first_user(
        self, robot: TestClient, admin: TestClient
    ) -> None:
        assert robot.put("/v1/users/lin").status_code == 201
        [only] = versions(admin)["items"]
        assert (only["version"], only["stored"], only["change_id"], only["set_by"]) == (
            1,
            True,
            None,
            None,
        )
        assert only["fingerprint"] == OFFICE.fingerprint
        assert isinstance(only["created_at"], str)
        assert model(robot, "lin")["mission_version"] == 1
        assert mission(robot)["version"] == 1
        # A second user changes nothing.
        assert robot.put("/v1/users/bo").status_code == 201
        assert len(versions(admin)["items"]) == 1

    def test_admins_may_name_a_fleet_others_only_their_own(
        self, robot: TestClient, admin: TestClient, staff: TestClient, other_robot: TestClient
    ) -> None:
        change(admin, office(add_cocoa), fleet="other")
        other = mission(admin, fleet="other")
        assert (other["fleet"], other["version"]) == ("other", 2)  # 1: the default it had
        assert other["fingerprint"] == fingerprint(office(add_cocoa))
        assert mission(other_robot)["fingerprint"] == other["fingerprint"]
        assert mission(robot, fleet="default")["fingerprint"] == OFFICE.fingerprint
        assert mission(admin)["fleet"] == "default"
        for client in (robot, staff):
            assert_error(client.get("/v1/mission", params={"fleet": "other"}), 403, "Forbidden")
        assert_error(other_robot.get("/v1/mission", params={"fleet": "default"}), 403, "Forbidden")

    def test_who_may_list_and_change_a_fleets_mission(
        self, robot: TestClient, staff: TestClient, other_staff: TestClient, admin: TestClient
    ) -> None:
        doc = office(add_cocoa)
        for client in (robot, other_staff):
            assert_error(client.get("/v1/admin/fleets/default/missions"), 403, "Forbidden")
            assert_error(put_raw(client, doc), 403, "Forbidden")
        assert versions(admin)["items"][0]["stored"] is False  # nothing was changed
        assert versions(staff)["fleet"] == "default"
        assert change(staff, doc)["version"] == 2  # version 1: the default it had
        assert versions(other_staff, "other")["current_version"] == 1
        assert change(other_staff, doc, fleet="other")["fleet"] == "other"
        assert change(admin, office(add_cocoa, drop_stocks), "c2")["version"] == 3
        assert change(admin, office(drop_stocks), fleet="third")["fleet"] == "third"
        assert versions(admin, "third")["current_version"] == 2


# -- changing it -------------------------------------------------------------------------------
class TestChangeMission:
    def test_a_change_before_any_user_follows_the_default_as_version_2(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        # Version 1 was the default the fleet had (GET /v1/mission said so): it is stored as
        # such, so a version never changes meaning.
        doc = office(add_cocoa)
        out = change(staff, doc, "first")
        assert (out["version"], out["previous_version"], out["users_moved"]) == (2, 1, 0)
        assert "ProvideDrink/cocoa" in out["diff"]["details"]["added"]
        new, default = versions(staff)["items"]
        assert (new["version"], new["stored"], new["change_id"]) == (2, True, "first")
        assert new["mission"] == with_display(doc)
        assert (default["version"], default["stored"], default["change_id"]) == (1, True, None)
        assert default["fingerprint"] == OFFICE.fingerprint
        assert robot.put("/v1/users/lin").status_code == 201
        view = model(robot, "lin")
        assert view["mission_version"] == 2
        assert "cocoa" in detail_names(view)
        assert mission(robot)["version"] == 2

    def test_a_change_moves_the_fleets_models(self, robot: TestClient, staff: TestClient) -> None:
        train(robot, "lin", 3)
        assert robot.put("/v1/users/bo").status_code == 201
        doc = office(add_cocoa)
        out = change(staff, doc, "add-cocoa")
        assert set(out) == {
            "fleet",
            "version",
            "previous_version",
            "fingerprint",
            "changed",
            "users_moved",
            "episodes_interrupted",
            "diff",
        }
        assert (out["fleet"], out["version"], out["previous_version"], out["changed"]) == (
            "default",
            2,
            1,
            True,
        )
        assert out["fingerprint"] == fingerprint(doc)
        assert (out["users_moved"], out["episodes_interrupted"]) == (2, 0)
        diff = out["diff"]
        assert "ProvideDrink/cocoa" in diff["details"]["added"]
        assert "ProvideDrink/tea" in diff["details"]["kept"]
        assert diff["details"]["removed"] == []
        assert diff["rewards_changed"] is False
        listed = versions(staff)
        assert listed["current_version"] == 2
        assert [v["version"] for v in listed["items"]] == [2, 1]
        newest = listed["items"][0]
        assert (newest["change_id"], newest["stored"], newest["fingerprint"]) == (
            "add-cocoa",
            True,
            fingerprint(doc),
        )
        assert newest["mission"] == with_display(doc)
        assert isinstance(newest["set_by"], str)
        assert newest["set_by"]
        now = mission(robot)
        assert (now["version"], now["fingerprint"]) == (2, fingerprint(doc))
        for uid in ("lin", "bo"):
            view = model(robot, uid)
            assert view["mission_version"] == 2
            assert "cocoa" in detail_names(view)

    @pytest.mark.parametrize(
        "edit",
        [
            pytest.param(
                lambda d: d["services"][1]["details"].__setitem__(0, "has space"),
                id="bad-detail-name",
            ),
            pytest.param(lambda d: d["situations"].append("working"), id="situation-twice"),
            pytest.param(lambda d: d["rewards"].update(negative=2.0), id="positive-negative"),
            pytest.param(lambda d: d["time_slots"][0].update(start="25:00"), id="bad-time"),
            pytest.param(lambda d: d.pop("services"), id="no-services"),
            pytest.param(lambda d: d.update(gamma="high"), id="gamma-not-a-number"),
        ],
    )
    def test_an_invalid_mission_is_422_with_the_loaders_message(
        self, staff: TestClient, robot: TestClient, edit: Edit
    ) -> None:
        robot.put("/v1/users/lin")
        doc = office(edit)
        with pytest.raises(MissionError) as loader:
            Mission.from_dict(doc, source="mission")
        body = assert_error(put_raw(staff, doc), 422, "ValidationError")
        assert body["detail"] == str(loader.value)
        assert len(versions(staff)["items"]) == 1

    def test_the_loaders_message_names_the_entry(self, staff: TestClient) -> None:
        body = assert_error(
            put_raw(
                staff, office(lambda d: d["services"][1]["details"].__setitem__(0, "has space"))
            ),
            422,
        )
        assert "services[1].details[0]" in body["detail"]

    @pytest.mark.parametrize(
        ("what", "edit"),
        [
            (
                "services",
                lambda d: d["services"].extend(
                    {"name": f"Extra{i}", "details": ["one"]} for i in range(LIMITS["services"])
                ),
            ),
            (
                "details per service",
                lambda d: d["services"][0]["details"].extend(
                    f"drink{i}" for i in range(LIMITS["details_per_service"])
                ),
            ),
            (
                "situations",
                lambda d: d["situations"].extend(f"sit{i}" for i in range(LIMITS["situations"])),
            ),
        ],
    )
    def test_a_mission_over_the_limits_is_422(
        self, staff: TestClient, what: str, edit: Edit
    ) -> None:
        doc = office(edit)
        Mission.from_dict(doc)  # a valid mission, only too large
        body = assert_error(put_raw(staff, doc), 422, "ValidationError")
        assert what in body["detail"]
        assert "more than" in body["detail"]
        assert versions(staff)["items"][0]["stored"] is False

    @pytest.mark.parametrize(
        ("renames", "entry"),
        [
            ({"details": {"chai": "tea"}}, "renames.details.chai"),  # no such old detail
            ({"details": {"cha": "matcha"}}, "renames.details.cha"),  # no such new detail
            ({"services": {"Laundry": "ProvideDrink"}}, "renames.services.Laundry"),
            ({"situations": {"working": "stretching"}}, "renames.situations.working"),
            ({"time_slots": {"dawn": "morning"}}, "renames.time_slots.dawn"),
        ],
    )
    def test_bad_renames_are_422_naming_the_entry(
        self, staff: TestClient, robot: TestClient, renames: dict[str, Any], entry: str
    ) -> None:
        change(staff, office(tea_is_cha), "v1")
        robot.put("/v1/users/lin")
        body = assert_error(put_raw(staff, office(), "v2", renames=renames), 422, "ValidationError")
        assert entry in body["detail"], body["detail"]
        assert versions(staff)["current_version"] == 2
        assert model(robot, "lin")["mission_version"] == 2

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "renames",
        [
            {"details": {"cha": 3}},
            {"colours": {"red": "blue"}},
            {"details": ["cha", "tea"]},
        ],
    )
    def test_renames_that_are_not_maps_of_names_are_422(
        self, staff: TestClient, renames: Any
    ) -> None:
        assert_error(put_raw(staff, office(), renames=renames), 422, "ValidationError")

    def test_a_change_id_is_idempotent(
        self, staff: TestClient, admin: TestClient, robot: TestClient
    ) -> None:
        robot.put("/v1/users/lin")
        doc = office(add_cocoa)
        first = change(staff, doc, "cocoa")
        again = put_raw(admin, doc, "cocoa")  # another key of the fleet: the same answer
        assert again.status_code == 200, again.text
        assert again.headers["Idempotent-Replay"] == "true"
        assert again.json() == first
        assert [v["version"] for v in versions(staff)["items"]] == [2, 1]
        assert_error(put_raw(staff, office(drop_stocks), "cocoa"), 409, "Conflict")
        assert_error(
            put_raw(staff, doc, "cocoa", renames={"details": {"tea": "coffee"}}), 409, "Conflict"
        )
        assert [v["version"] for v in versions(staff)["items"]] == [2, 1]

    def test_the_mission_in_force_again_changes_nothing(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        train(robot, "lin", 2)
        before = model(robot, "lin")
        out = change(staff, office(), "same")
        assert out["changed"] is False
        assert (out["version"], out["users_moved"], out["episodes_interrupted"]) == (1, 0, 0)
        assert out["fingerprint"] == OFFICE.fingerprint
        assert len(versions(staff)["items"]) == 1
        assert model(robot, "lin") == before
        change(staff, office(add_cocoa), "cocoa")
        assert change(staff, office(add_cocoa), "cocoa-again")["changed"] is False
        assert versions(staff)["current_version"] == 2

    def test_open_episodes_are_interrupted(self, staff: TestClient, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1")
        done = served(robot, "lin", "e2", "ProvideDrink", "tea")
        assert ep["mission_version"] == 1
        out = change(staff, office(add_cocoa))
        assert out["episodes_interrupted"] == 1
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert (trace["status"], trace["mission_version"]) == ("interrupted", 1)
        assert robot.get(f"/v1/episodes/{done['episode_id']}").json()["status"] == "closed"
        body = assert_error(
            robot.post(
                f"/v1/episodes/{ep['episode_id']}/outcomes",
                json={"decision_id": ep["decision"]["decision_id"], "response": "accepted"},
            ),
            409,
            "Conflict",
        )
        assert "interrupted" in body["detail"]
        assert "mission" in body["detail"]
        later = start(robot, "lin", "e3")
        assert later["mission_version"] == 2
        listed = robot.get("/v1/users/lin/episodes").json()["items"]
        assert {e["episode_id"]: (e["status"], e["mission_version"]) for e in listed} == {
            ep["episode_id"]: ("interrupted", 1),
            done["episode_id"]: ("closed", 1),
            later["episode_id"]: ("open", 2),
        }

    def test_feedback_on_a_kept_step_reaches_the_model(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        ep = served(robot, "lin", "e1", "ProvideDrink", "tea")
        change(staff, office(add_cocoa, drop_stocks))
        version = model(robot, "lin")["version"]
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/feedback",
            json={"feedback_id": "f1", "feedback": "positive"},
        )
        assert r.status_code == 200, r.text
        assert r.json()["reward"] > 0
        assert model(robot, "lin")["version"] == version + 1
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert [f["feedback_id"] for f in trace["feedback"]] == ["f1"]

    def test_feedback_on_a_removed_step_is_only_stored(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        ep = served(robot, "lin", "e1", "BriefInformation", "stocks")
        total = robot.get(f"/v1/episodes/{ep['episode_id']}").json()["total_reward"]
        change(staff, office(drop_stocks))
        before = model(robot, "lin")
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/feedback",
            json={"feedback_id": "f1", "feedback": "negative"},
        )
        assert r.status_code == 200, r.text
        reward = r.json()["reward"]
        assert reward < 0
        assert model(robot, "lin") == before
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert [f["feedback_id"] for f in trace["feedback"]] == ["f1"]
        assert trace["total_reward"] == pytest.approx(total + reward)

    def test_new_users_are_laid_out_for_the_new_version(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        robot.put("/v1/users/lin")
        change(staff, office(add_cocoa, drop_stocks))
        assert robot.put("/v1/users/bo").status_code == 201
        view = model(robot, "bo")
        assert view["mission_version"] == 2
        names = detail_names(view)
        assert "cocoa" in names
        assert "stocks" not in names
        assert beliefs(view) == beliefs(model(robot, "lin"))
        ep = start(robot, "bo", "e1")
        assert ep["mission_version"] == 2

    def test_another_fleet_is_untouched(
        self, staff: TestClient, robot: TestClient, other_robot: TestClient, admin: TestClient
    ) -> None:
        train(robot, "lin", 2)
        for uid in ("ana", "kim"):
            # HRI: a decision's distribution is exactly the model view's (the DTS family's view
            # is an estimate from posterior draws of its own)
            other_robot.put(f"/v1/users/{uid}", json={"learner": {"algorithm": "hri"}})
            train(other_robot, uid, 3, need=("BriefInformation", "stocks"))
        views = {uid: model(other_robot, uid) for uid in ("ana", "kim")}
        exports = {
            uid: admin.get(f"/v1/users/{uid}/model/export", params={"fleet": "other"}).json()
            for uid in views
        }
        other_mission, other_versions = mission(other_robot), versions(admin, "other")
        out = change(staff, office(add_cocoa, drop_stocks))
        assert out["users_moved"] == 1
        for uid, view in views.items():
            assert model(other_robot, uid) == view  # distributions, visits, versions
            assert (
                admin.get(f"/v1/users/{uid}/model/export", params={"fleet": "other"}).json()
                == exports[uid]
            )
        assert mission(other_robot) == other_mission
        assert versions(admin, "other") == other_versions
        # Its robots' decisions are drawn as before: the next episode is the one it would have
        # been (its first decision's distribution is the model's).
        ep = start(other_robot, "ana", "ana-next")
        assert ep["mission_version"] == 1
        observe = next(
            s
            for c in views["ana"]["contexts"]
            if (c["time_slot"], c["situation"]) == ("afternoon", "stretching")
            for s in c["states"]
            if s["state"] == "OBSERVE"
        )
        assert [(p["action"], p["p"]) for p in ep["decision"]["probabilities"]] == [
            (a["action"], pytest.approx(a["p"])) for a in observe["actions"]
        ]

    def test_renames_carry_statistics(self, staff: TestClient, robot: TestClient) -> None:
        change(staff, office(tea_is_cha), "v1")
        for i in range(8):
            play(  # she asks for a drink, without naming it
                robot,
                "lin",
                f"e{i}",
                person(need=("ProvideDrink", "cha")),
                initiator="human",
                request={"service": "ProvideDrink"},
            )
        before = model(robot, "lin")
        infer_cha = [
            b
            for k, b in beliefs(before).items()
            if k[5:] == ("infer_detail", "ProvideDrink", "cha")
        ]
        assert sum(b["visits"] for b in infer_cha) > 0
        out = change(staff, office(), "v2", renames={"details": {"cha": "tea"}})
        assert out["diff"]["details"]["renamed"] == [
            {"old": "ProvideDrink/cha", "new": "ProvideDrink/tea"}
        ]
        after = model(robot, "lin")
        assert "cha" not in detail_names(after)
        # Only a name changed: every entry, and every decision distribution, is as it was.
        assert beliefs(after) == beliefs(before, {"cha": "tea"})
        infer_tea = [
            b for k, b in beliefs(after).items() if k[5:] == ("infer_detail", "ProvideDrink", "tea")
        ]
        assert infer_tea == infer_cha

    def test_a_detail_renamed_under_one_service(self, staff: TestClient, robot: TestClient) -> None:
        change(staff, office(tea_is_cha), "v1")
        train(robot, "lin", 4, need=("ProvideDrink", "cha"))
        before = beliefs(model(robot, "lin"), {"cha": "tea"})
        change(staff, office(), "v2", renames={"details": {"ProvideDrink/cha": "tea"}})
        assert beliefs(model(robot, "lin")) == before

    def test_an_export_of_an_earlier_version_imports(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        train(robot, "lin", 6)
        exported = staff.get("/v1/users/lin/model/export")
        assert exported.status_code == 200, exported.text
        change(staff, office(add_cocoa, drop_stocks))
        moved = model(robot, "lin")
        train(robot, "lin", 3, prefix="after")
        r = staff.put("/v1/users/lin/model", json=exported.json())
        assert r.status_code == 200, r.text
        imported = r.json()
        assert imported["mission_version"] == 2
        assert "cocoa" in detail_names(imported)
        assert "stocks" not in detail_names(imported)
        # What was learned under version 1, carried to version 2: the visits and values of the
        # model as the change left it.
        drop = ("since_last", "p")  # the clock moved on with the later episodes
        assert {
            k: {f: v for f, v in b.items() if f not in drop} for k, b in beliefs(imported).items()
        } == {k: {f: v for f, v in b.items() if f not in drop} for k, b in beliefs(moved).items()}

    def test_a_reset_after_a_change_is_a_fresh_learner_of_the_new_mission(
        self, staff: TestClient, robot: TestClient
    ) -> None:
        train(robot, "lin", 4)
        change(staff, office(add_cocoa, add_visiting))
        assert staff.delete("/v1/users/lin/model").status_code == 204
        view = model(robot, "lin")
        assert view["mission_version"] == 2
        assert all(b["visits"] == 0 for b in beliefs(view).values())
        assert "cocoa" in detail_names(view)
        assert "visiting" in {c["situation"] for c in view["contexts"]}
        robot.put("/v1/users/fresh")
        assert [(k, b["visits"], b["q"]) for k, b in beliefs(view).items()] == [
            (k, b["visits"], b["q"]) for k, b in beliefs(model(robot, "fresh")).items()
        ]

    def test_rebuild_is_identical_across_two_changes(
        self, app: FastAPI, staff: TestClient, robot: TestClient
    ) -> None:
        rng = random.Random(5)
        for uid in ("lin", "bo"):
            train(robot, uid, 4)
        first = served(robot, "lin", "lin-served", "BriefInformation", "stocks")
        open_one = start(robot, "bo", "bo-open")
        change(staff, office(add_cocoa), "c1")
        for i in range(4):
            play(robot, "lin", f"lin-mid{i}", person(need=("ProvideDrink", "cocoa"), rng=rng))
        robot.post(
            f"/v1/episodes/{first['episode_id']}/feedback",
            json={"feedback_id": "f1", "feedback": "positive"},
        )
        change(
            staff,
            office(add_cocoa, drop_stocks, tea_is_cha),
            "c2",
            renames={"details": {"tea": "cha"}},
        )
        robot.post(
            f"/v1/episodes/{first['episode_id']}/feedback",
            json={"feedback_id": "f2", "feedback": "negative"},
        )
        for uid in ("lin", "bo"):
            play(robot, uid, f"{uid}-late", person(need=("ProvideDrink", "cha")))
        assert open_one["mission_version"] == 1
        ctx = app.state.ctx
        for uid in ("lin", "bo"):
            with app.state.db.transaction() as session:
                report = rebuild_model(session, ctx, audit_service.CLI, uid, fleet="default")
            assert report.identical, (uid, report.mismatched_decisions)
            assert report.decisions > 0
            assert model(robot, uid)["mission_version"] == 3

    def test_a_change_is_audited(
        self, staff: TestClient, admin: TestClient, robot: TestClient
    ) -> None:
        start(robot, "lin", "e1")
        robot.put("/v1/users/bo")
        change(staff, office(add_cocoa))
        entries = admin.get("/v1/admin/audit").json()["items"]
        [entry] = [e for e in entries if e["action"] == "mission.set"]
        assert (entry["target"], entry["fleet"]) == ("default", "default")
        assert entry["detail"] == {
            "version": 2,
            "previous_version": 1,
            "users_moved": 2,
            "episodes_interrupted": 1,
        }
        assert entry["actor"]
        staff_entries = staff.get("/v1/admin/audit").json()["items"]
        assert any(e["action"] == "mission.set" for e in staff_entries)
        change(staff, office(add_cocoa), "again")  # unchanged: no entry
        assert (
            sum(e["action"] == "mission.set" for e in admin.get("/v1/admin/audit").json()["items"])
            == 1
        )
