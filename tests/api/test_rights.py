"""What staff set, a robot key cannot undo; and whoever replaces a model or lifts a correction
is recorded, whatever the route (docs/api.md, "Who may set what" and the audit log).

The field-level rights of ``PUT /v1/users/{user_id}`` per caller are rows of the access matrix
(``tests/api/test_fleet_matrix.py``, ``FIELDS``); here: the issue's case (a robot key resetting a
model through a change of learner), what a robot may still send, and the records each route
leaves: the correction rows' ``lifted_at``/``lifted_by`` and the audit log's entries.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.console.auth import COOKIE, csrf_token
from tests.support.contract import assert_error
from tests.support.episodes import report, start
from tests.support.fixtures import MakeKey

QUIET = {
    "correction_id": "c1",
    "time_slot": "afternoon",
    "situation": "stretching",
    "kind": "quiet",
    "note": "She reads after lunch.",
}


class Keys:
    """A robot and a staff key of fleet ``default``, with their ids, and the staff key's
    console session."""

    def __init__(self, app: FastAPI, make_key: MakeKey) -> None:
        self.robot_secret = make_key("robot", "default", "robot")
        self.staff_secret = make_key("staff", "default", "staff")
        self.robot = TestClient(
            app,
            headers={"Authorization": f"Bearer {self.robot_secret}"},
            raise_server_exceptions=False,
        )
        self.staff = TestClient(
            app,
            headers={"Authorization": f"Bearer {self.staff_secret}"},
            raise_server_exceptions=False,
        )
        self.console = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
        self.console.cookies.set(COOKIE, self.staff_secret, path="/admin")
        ids = {k["name"]: k["key_id"] for k in self.admin_keys(app, make_key)}
        self.robot_id, self.staff_id = ids["robot"], ids["staff"]

    @staticmethod
    def admin_keys(app: FastAPI, make_key: MakeKey) -> list[dict[str, Any]]:
        with TestClient(app, headers={"Authorization": f"Bearer {make_key('admin')}"}) as admin:
            items: list[dict[str, Any]] = admin.get("/v1/admin/keys").json()["items"]
        return items

    def audit(self) -> list[dict[str, Any]]:
        items: list[dict[str, Any]] = self.staff.get("/v1/admin/audit?limit=500").json()["items"]
        return [e for e in items if not e["action"].startswith("key.")]

    def correction(self, correction_id: str = "c1") -> dict[str, Any]:
        items = self.staff.get("/v1/users/lin/corrections").json()["items"]
        [found] = [c for c in items if c["correction_id"] == correction_id]
        return dict(found)

    def console_post(self, path: str) -> Any:
        return self.console.post(path, data={"csrf": csrf_token(self.staff_secret)})


@pytest.fixture
def keys(app: FastAPI, make_key: MakeKey) -> Iterator[Keys]:
    """Lin (fleet default) with one answered episode, and staff's quiet correction in force."""
    made = Keys(app, make_key)
    with made.robot, made.staff, made.console:
        ep = start(made.robot, "lin", "e1")
        kind = ep["decision"]["action"]["kind"]
        report(
            made.robot,
            ep["episode_id"],
            ep["decision"]["decision_id"],
            "rejected" if kind == "initiate" else "none",
        )
        assert made.staff.post("/v1/users/lin/corrections", json=QUIET).status_code == 201
        yield made


def _recently(stamp: str | None) -> bool:
    assert stamp is not None
    at = dt.datetime.fromisoformat(stamp)
    return dt.timedelta(0) <= dt.datetime.now(dt.UTC) - at < dt.timedelta(minutes=5)


class TestARobotCannotUndoWhatStaffSet:
    def test_a_change_of_learner_with_reset_model_is_403_and_changes_nothing(
        self, keys: Keys
    ) -> None:
        """The issue's case: before, this reset the model, lifted the staff's correction with
        no one named, and left nothing in the audit log."""
        user = keys.robot.get("/v1/users/lin").json()
        model = keys.robot.get("/v1/users/lin/model").json()
        audit = keys.audit()
        r = keys.robot.put(
            "/v1/users/lin?reset_model=true", json={"learner": {"algorithm": "rmax"}}
        )
        err = assert_error(r, 403, "Forbidden")
        assert "learner" in err["detail"]
        assert "reset_model" in err["detail"]
        assert keys.robot.get("/v1/users/lin").json() == user
        assert keys.robot.get("/v1/users/lin/model").json() == model
        correction = keys.correction()
        assert (correction["status"], correction["lifted_at"], correction["lifted_by"]) == (
            "in_force",
            None,
            None,
        )
        assert keys.audit() == audit

    @pytest.mark.parametrize(
        ("body", "query", "named"),
        [
            ({"display_name": "Lin"}, "", "display_name"),
            ({"fleet_prior": False}, "", "fleet_prior"),
            ({"learner": {"algorithm": "hri"}}, "", "learner"),
            ({"learner": {"algorithm": "nope"}}, "", "learner"),  # not the stored one either
            ({}, "?reset_model=true", "reset_model"),
        ],
    )
    def test_each_change_is_refused_naming_its_field(
        self, keys: Keys, body: dict[str, Any], query: str, named: str
    ) -> None:
        before = keys.robot.get("/v1/users/lin").json()
        err = assert_error(keys.robot.put(f"/v1/users/lin{query}", json=body), 403, "Forbidden")
        assert named in err["detail"]
        assert keys.robot.get("/v1/users/lin").json() == before

    def test_what_is_stored_may_be_sent_again(self, keys: Keys) -> None:
        """A robot that repeats its creating PUT (a lost answer, a restart) changes nothing and
        is answered 200, whatever the staff changed since, as long as it sends what is stored."""
        made = keys.robot.put("/v1/users/ming", json={"display_name": "Ming"})
        assert made.status_code == 201, made.text
        stored = made.json()
        again = keys.robot.put(
            "/v1/users/ming",
            json={
                "display_name": "Ming",
                "fleet_prior": True,
                "learner": {"algorithm": stored["learner"]["algorithm"]},
            },
        )
        assert again.status_code == 200, again.text
        assert again.json() == stored
        assert keys.robot.put("/v1/users/ming", json={}).status_code == 200
        assert keys.robot.put("/v1/users/ming").status_code == 200

    def test_a_robot_creates_a_person_with_any_field_but_reset_model(self, keys: Keys) -> None:
        body = {"display_name": "Ming", "fleet_prior": False, "learner": {"algorithm": "hri"}}
        made = keys.robot.put("/v1/users/ming", json=body)
        assert made.status_code == 201, made.text
        assert (made.json()["display_name"], made.json()["fleet_prior"]) == ("Ming", False)
        assert made.json()["learner"]["algorithm"] == "hri"
        err = assert_error(keys.robot.put("/v1/users/chen?reset_model=true"), 403, "Forbidden")
        assert "reset_model" in err["detail"]
        assert_error(keys.robot.get("/v1/users/chen"), 404, "NotFound")

    def test_staff_change_what_they_set(self, keys: Keys) -> None:
        r = keys.staff.put("/v1/users/lin", json={"display_name": "Mrs. Lin", "fleet_prior": False})
        assert r.status_code == 200, r.text
        assert (r.json()["display_name"], r.json()["fleet_prior"]) == ("Mrs. Lin", False)


class TestEveryChangeIsRecorded:
    """Who and when, in the correction rows and in the audit log, whatever the route."""

    def _lifted_by_staff(self, keys: Keys) -> None:
        correction = keys.correction()
        assert correction["status"] == "lifted"
        assert correction["lifted_by"] == keys.staff_id
        assert _recently(correction["lifted_at"])

    def _entry(self, keys: Keys, action: str) -> dict[str, Any]:
        entry = keys.audit()[0]
        assert (entry["action"], entry["target"], entry["fleet"]) == (action, "lin", "default")
        assert (entry["actor"]["key_id"], entry["actor"]["role"]) == (keys.staff_id, "staff")
        assert _recently(entry["at"])
        return entry

    def test_a_change_of_learner(self, keys: Keys) -> None:
        version = keys.staff.get("/v1/users/lin/model").json()["version"]
        r = keys.staff.put(
            "/v1/users/lin?reset_model=true", json={"learner": {"algorithm": "rmax"}}
        )
        assert r.status_code == 200, r.text
        self._lifted_by_staff(keys)
        entry = self._entry(keys, "user.learner")
        assert entry["detail"] == {
            "algorithm": "rmax",
            "was": "dts-routine",
            "episodes": 1,
            "version": version + 1,
            "corrections_lifted": 1,
        }
        # Changing it again to the same learner changes nothing and records nothing.
        audit = keys.audit()
        again = keys.staff.put("/v1/users/lin", json={"learner": {"algorithm": "rmax"}})
        assert again.status_code == 200, again.text
        assert keys.audit() == audit

    def test_a_change_of_learner_without_history(self, keys: Keys) -> None:
        assert keys.robot.put("/v1/users/ming").status_code == 201
        r = keys.staff.put("/v1/users/ming", json={"learner": {"algorithm": "qlearning"}})
        assert r.status_code == 200, r.text
        [entry] = [e for e in keys.audit() if e["target"] == "ming"]
        assert entry["action"] == "user.learner"
        assert entry["detail"]["corrections_lifted"] == 0

    def test_a_reset_that_drops_the_corrections(self, keys: Keys) -> None:
        assert keys.staff.delete("/v1/users/lin/model?corrections=drop").status_code == 204
        self._lifted_by_staff(keys)
        entry = self._entry(keys, "model.reset")
        assert (entry["detail"]["corrections_kept"], entry["detail"]["corrections_lifted"]) == (
            0,
            1,
        )

    def test_a_reset_in_the_console_keeps_them_and_names_the_staff(self, keys: Keys) -> None:
        r = keys.console_post("/admin/users/lin/reset")
        assert r.status_code == 303, r.text
        correction = keys.correction()
        assert (correction["status"], correction["lifted_at"], correction["lifted_by"]) == (
            "in_force",
            None,
            None,
        )
        entry = self._entry(keys, "model.reset")
        assert (entry["detail"]["corrections_kept"], entry["detail"]["corrections_lifted"]) == (
            1,
            0,
        )

    def test_an_import_of_a_model_without_the_correction(self, keys: Keys) -> None:
        before = keys.staff.get("/v1/users/lin/model/export").json()
        assert keys.staff.delete("/v1/users/lin/corrections/c1").status_code == 204
        without = keys.staff.get("/v1/users/lin/model/export").json()
        # Back in force with the export that holds it (no one lifted it: lifted_* are null) ...
        assert keys.staff.put("/v1/users/lin/model", json=before).status_code == 200
        correction = keys.correction()
        assert (correction["status"], correction["lifted_at"], correction["lifted_by"]) == (
            "in_force",
            None,
            None,
        )
        assert self._entry(keys, "model.import")["detail"]["corrections_lifted"] == 0
        # ... and lifted by whoever imports one that does not.
        assert keys.staff.put("/v1/users/lin/model", json=without).status_code == 200
        self._lifted_by_staff(keys)
        assert self._entry(keys, "model.import")["detail"]["corrections_lifted"] == 1

    @pytest.mark.parametrize("route", ["api", "console"])
    def test_a_lift(self, keys: Keys, route: str) -> None:
        if route == "api":
            assert keys.staff.delete("/v1/users/lin/corrections/c1").status_code == 204
        else:
            assert keys.console_post("/admin/users/lin/corrections/c1/lift").status_code == 303
        self._lifted_by_staff(keys)
        assert self._entry(keys, "correction.lift")["detail"]["correction_id"] == "c1"

    def test_a_persons_prior_switch(self, keys: Keys) -> None:
        r = keys.staff.put("/v1/users/lin", json={"fleet_prior": False})
        assert r.status_code == 200, r.text
        assert self._entry(keys, "user.prior")["detail"] == {"fleet_prior": False}
        audit = keys.audit()
        assert keys.staff.put("/v1/users/lin", json={"fleet_prior": False}).status_code == 200
        assert keys.audit() == audit  # setting what is set records nothing

    def test_the_fleets_prior_switch(self, keys: Keys) -> None:
        r = keys.staff.put("/v1/admin/fleets/default/prior", json={"enabled": False})
        assert r.status_code == 200, r.text
        assert r.json()["updated_by"] == keys.staff_id
        assert _recently(r.json()["updated_at"])
        entry = keys.audit()[0]
        assert (entry["action"], entry["target"], entry["actor"]["key_id"]) == (
            "fleet.prior",
            "default",
            keys.staff_id,
        )
