"""A person's export (``GET /v1/users/{id}/export``): everything stored about them in one
documented JSON document, streamed a page of episodes at a time; staff of the fleet and admins
only, audited and recorded as a read."""

from __future__ import annotations

import json
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.services import subject
from tests.support.contract import assert_error
from tests.support.episodes import play
from tests.support.people import person

LIN = "lin"
NOTE = "Her son says: tea, never coffee"


def _lin(robot: TestClient, staff: TestClient, episodes: int) -> list[str]:
    assert staff.put(f"/v1/users/{LIN}", json={"display_name": "Mrs. Lin"}).status_code == 201
    ids = [play(robot, LIN, f"e{i}", person(picky=False)).episode_id for i in range(episodes)]
    r = robot.post(
        f"/v1/episodes/{ids[0]}/feedback", json={"feedback_id": "f1", "feedback": "positive"}
    )
    assert r.status_code == 200, r.text
    r = staff.post(
        f"/v1/users/{LIN}/corrections",
        json={
            "correction_id": "c1",
            "time_slot": "afternoon",
            "situation": "stretching",
            "kind": "prefers",
            "service": "ProvideDrink",
            "detail": "tea",
            "note": NOTE,
        },
    )
    assert r.status_code == 201, r.text
    return ids


def _export(client: TestClient, user_id: str = LIN, **params: Any) -> dict[str, Any]:
    r = client.get(f"/v1/users/{user_id}/export", params=params)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/json"
    assert r.headers["content-disposition"] == (
        f'attachment; filename="attune-person-default-{user_id}.json"'
    )
    doc: dict[str, Any] = json.loads(r.content)
    return doc


def test_the_export_holds_everything_stored_about_the_person(
    robot: TestClient, staff: TestClient, admin: TestClient
) -> None:
    ids = _lin(robot, staff, 3)
    assert staff.get(f"/v1/users/{LIN}/profile").status_code == 200  # a look, in the export
    doc = _export(staff)
    assert (doc["format"], doc["format_version"]) == (subject.FORMAT, subject.FORMAT_VERSION)
    assert doc["exported_by"]["role"] == "staff"
    assert doc["person"] == staff.get(f"/v1/users/{LIN}").json()
    assert doc["fleet_prior"]["takes_part"] is True
    assert doc["fleet_prior"]["model_started_from"]["kind"] in ("fresh", "fleet_prior")
    assert doc["profile"]["user_id"] == LIN
    assert [c["note"] for c in doc["corrections"]] == [NOTE]
    assert [e["action"] for e in doc["audit"]] == ["correction.add"]
    assert "profile" in [v["what"] for v in doc["views"]]
    assert doc["episode_count"] == 3
    assert [e["episode_id"] for e in doc["episodes"]] == list(reversed(ids))  # newest first
    for episode in doc["episodes"]:
        assert episode["user_id"] == LIN
        assert episode["decisions"], episode["episode_id"]
    assert [f["feedback_id"] for f in doc["episodes"][-1]["feedback"]] == ["f1"]
    # The model part is the model's own export document: another person can start from it.
    assert admin.put("/v1/users/twin", json={}).status_code == 201
    assert admin.put("/v1/users/twin/model", json=doc["model"]).status_code == 200
    # Audited, and recorded as a read.
    audit = admin.get("/v1/admin/audit").json()["items"]
    assert ("user.export", LIN) in [(e["action"], e["target"]) for e in audit]
    assert "subject" in [v["what"] for v in staff.get(f"/v1/users/{LIN}/views").json()["items"]]


def test_the_episodes_stream_a_page_at_a_time(
    robot: TestClient, staff: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    ids = _lin(robot, staff, 5)
    monkeypatch.setattr(subject, "PAGE", 2)
    doc = _export(staff)
    assert [e["episode_id"] for e in doc["episodes"]] == list(reversed(ids))
    monkeypatch.setattr(subject, "PAGE", 5)  # a last page that is full
    assert len(_export(staff)["episodes"]) == 5


def test_a_person_without_episodes(staff: TestClient) -> None:
    assert staff.put("/v1/users/new", json={}).status_code == 201
    doc = _export(staff, "new")
    assert (doc["episode_count"], doc["episodes"], doc["corrections"]) == (0, [], [])


def test_who_may_export(
    robot: TestClient, staff: TestClient, other_staff: TestClient, admin: TestClient
) -> None:
    _lin(robot, staff, 1)
    assert_error(robot.get(f"/v1/users/{LIN}/export"), 403, "Forbidden")
    assert_error(other_staff.get(f"/v1/users/{LIN}/export"), 404, "NotFound")
    assert_error(staff.get("/v1/users/nobody/export"), 404, "NotFound")
    assert _export(admin)["exported_by"]["role"] == "admin"
    assert staff.delete(f"/v1/users/{LIN}").status_code == 204
    assert_error(staff.get(f"/v1/users/{LIN}/export"), 404, "NotFound")
