"""A person's import (``attune people import``, ``app.services.subject_import``): an export of
one deployment put into another restores the person, history included, on both engines.

Deployment A (the test's app) serves a person with a history of episodes, feedback, staff
corrections (one lifted), and a retention run that folded their oldest episodes. Their export is
imported into deployment B (a database of its own, another seed): B then says of them what A
said (the profile, the model and its distributions, the corrections, the statistics, every
episode with its decisions and feedback), rebuilds their model identically, and goes on serving
them; and the import refuses, with one sentence each, what it cannot put back.
"""

from __future__ import annotations

import copy
import datetime as dt
import io
import json
import random
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from app import cli
from app.db import migrate
from app.errors import AppError, Conflict, ValidationFailed
from app.learning import office_mission
from app.main import create_app
from app.services import audit as audit_service
from app.services import retention
from app.services.models import rebuild_model
from app.services.subject_import import import_subject
from app.settings import Settings
from tests.support.episodes import play
from tests.support.live import fresh_database, make_keys
from tests.support.people import person

LIN = "lin"
NOTE = "Her son says: tea, never coffee"
CORRECTION = {
    "time_slot": "afternoon",
    "situation": "stretching",
    "kind": "prefers",
    "service": "ProvideDrink",
    "detail": "tea",
}


@pytest.fixture
def exported(app: FastAPI, robot: TestClient, staff: TestClient) -> bytes:
    """Lin's export from deployment A: 14 episodes (feedback on some), a correction in force
    and one lifted, the oldest six episodes folded by a retention run, and a change of her
    wish in the afternoon while stretching (coffee, no longer tea)."""
    assert staff.put(f"/v1/users/{LIN}", json={"display_name": "Mrs. Lin"}).status_code == 201
    who = person(picky=False, yes=0.8, asks=0.6, rng=random.Random(5))
    then = person(need=("ProvideDrink", "coffee"))  # from the 11th on: coffee, not tea
    for i in range(14):
        where = ("stretching", "arriving")[i % 2] if i < 10 else "stretching"
        played = play(robot, LIN, f"e{i}", who if i < 10 else then, situation=where)
        if i % 4 == 1:
            r = robot.post(
                f"/v1/episodes/{played.episode_id}/feedback",
                json={"feedback_id": f"f{i}", "feedback": "positive"},
            )
            assert r.status_code == 200, r.text
        if i == 4:
            for cid in ("c1", "c2"):
                r = staff.post(
                    f"/v1/users/{LIN}/corrections",
                    json={**CORRECTION, "correction_id": cid, "note": NOTE},
                )
                assert r.status_code == 201, r.text
            assert staff.delete(f"/v1/users/{LIN}/corrections/c2").status_code in (200, 204)
        if i == 5:
            r = staff.put("/v1/admin/fleets/default/history", json={"history_days": 1})
            assert r.status_code == 200, r.text
            later = dt.datetime.now(dt.UTC) + dt.timedelta(days=2)
            assert retention.run(app.state.db, app.state.ctx, now=later).episodes_removed == 6
            r = staff.put("/v1/admin/fleets/default/history", json={"history_days": None})
            assert r.status_code == 200, r.text
    r = staff.get(f"/v1/users/{LIN}/export")
    assert r.status_code == 200, r.text
    content: bytes = r.content
    return content


@pytest.fixture
def other(database_url: str) -> Iterator[tuple[FastAPI, TestClient, TestClient, str]]:
    """Deployment B: a database of its own (of the same engine), another seed; (app, staff,
    robot, its database's URL)."""
    engine = "sqlite" if database_url.startswith("sqlite") else "postgresql"
    with fresh_database(engine) as url:
        migrate.upgrade(url)
        staff_key = make_keys(url, 1, role="staff")[0]
        robot_key = make_keys(url, 1, role="robot")[0]
        app = create_app(Settings(database_url=url, seed=99, _env_file=None))  # type: ignore[call-arg]
        try:
            with (
                TestClient(app, headers={"Authorization": f"Bearer {staff_key}"}) as staff,
                TestClient(app, headers={"Authorization": f"Bearer {robot_key}"}) as robot,
            ):
                yield app, staff, robot, url
        finally:
            app.state.db.dispose()


def _import(app: FastAPI, doc: bytes, **kw: Any) -> Any:
    with app.state.db.transaction() as session:
        return import_subject(
            session, app.state.ctx, audit_service.CLI, io.BytesIO(doc), fleet="default", **kw
        )


def _said(client: TestClient, user_id: str = LIN) -> dict[str, Any]:
    """What a deployment says of the person, without what is its own (ids, times of the export,
    its audit and who looked, where the model came from)."""
    doc: dict[str, Any] = json.loads(client.get(f"/v1/users/{user_id}/export").content)
    for name in ("exported_at", "exported_by", "audit", "views", "restore"):
        doc.pop(name)
    doc["person"].pop("created_at")
    doc["person"].pop("user_id")
    doc["profile"].pop("user_id")
    doc["profile"].pop("started_from", None)
    doc["fleet_prior"].pop("model_started_from")
    for change in doc["changes"]:
        change.pop("change_id")
    for episode in doc["episodes"]:
        for name in ("episode_id", "user_id"):
            episode.pop(name)
        for decision in episode["decisions"]:
            decision.pop("decision_id")
    model = client.get(f"/v1/users/{user_id}/model").json()
    for name in ("user_id", "version", "started_from"):
        model.pop(name)
    doc["model_view"] = model
    doc["stats"] = client.get(f"/v1/users/{user_id}/stats").json()
    return doc


def test_an_imported_person_is_said_of_and_served_as_before(
    exported: bytes, staff: TestClient, other: tuple[FastAPI, TestClient, TestClient, str]
) -> None:
    before = _said(staff)
    assert before["changes"], "her wishes changed in A: B must say so too"
    app, staff_b, robot_b, _ = other
    done = _import(app, exported)
    assert (done.user_id, done.episodes, done.corrections) == (LIN, 8, 2)
    assert done.feedback > 0
    assert done.model_version == json.loads(exported)["restore"]["model_version"] + 1
    assert _said(staff_b) == before
    with app.state.db.transaction() as session:
        report = rebuild_model(session, app.state.ctx, audit_service.CLI, LIN)
    assert report.identical, report.mismatched_decisions
    actions = [e["action"] for e in staff_b.get("/v1/admin/audit").json()["items"]]
    assert "user.import" in actions
    # B serves her from here on, and her model still rebuilds.
    who = person(picky=False, yes=0.8, asks=0.6, rng=random.Random(6))
    for i in range(3):
        play(robot_b, LIN, f"b{i}", who, situation="stretching")
    assert staff_b.get(f"/v1/users/{LIN}").json()["episodes"] == 17
    with app.state.db.transaction() as session:
        report = rebuild_model(session, app.state.ctx, audit_service.CLI, LIN)
    assert report.identical, report.mismatched_decisions
    assert report.decisions > 0
    # An event from before the move is one she already had: refused, not played again.
    r = robot_b.post(
        f"/v1/users/{LIN}/episodes",
        json={
            "event_id": "e13",
            "occurred_at": "2026-11-20T15:10:00+08:00",
            "situation": "stretching",
        },
    )
    assert r.status_code == 409, r.text


def test_the_command_line_imports_under_another_id(
    exported: bytes,
    other: tuple[FastAPI, TestClient, TestClient, str],
    tmp_path: Any,
) -> None:
    _, staff_b, _, url = other
    path = tmp_path / "lin.json"
    path.write_bytes(exported)
    env = {"ATTUNE_DATABASE_URL": url}
    result = CliRunner().invoke(
        cli.app, ["people", "import", str(path), "--user-id", "lin-2", "--json"], env=env
    )
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["user_id"] == "lin-2"
    assert staff_b.get("/v1/users/lin-2").json()["display_name"] == "Mrs. Lin"
    again = CliRunner().invoke(
        cli.app, ["people", "import", str(path), "--user-id", "lin-2"], env=env
    )
    assert again.exit_code == 2
    assert "exists" in again.output


def _changed(doc: bytes, change: Any) -> bytes:
    parsed = json.loads(doc)
    change(parsed)
    return json.dumps(parsed).encode()


@pytest.mark.parametrize(
    ("change", "error", "words"),
    [
        (lambda d: None, Conflict, "exists"),  # imported twice
        (lambda d: d.update(format="other"), ValidationFailed, "Not a person's export"),
        (lambda d: d.pop("restore"), ValidationFailed, "export the person again"),
        (
            lambda d: d["restore"]["missions"][0].update(fingerprint="sha256:elsewhere"),
            ValidationFailed,
            "set that mission",
        ),
        (
            lambda d: d["episodes"][0].update(event_id="bad\x00id"),
            ValidationFailed,
            "NUL",
        ),
        (lambda d: d["episodes"][0].pop("stored"), ValidationFailed, "stored"),
    ],
)
def test_what_cannot_be_put_back_is_refused_whole(
    exported: bytes,
    other: tuple[FastAPI, TestClient, TestClient, str],
    change: Any,
    error: type[AppError],
    words: str,
) -> None:
    app, staff_b, _, _ = other
    if error is Conflict:
        _import(app, exported)
    with pytest.raises(error, match=words):
        _import(app, _changed(exported, change))
    if error is not Conflict:  # nothing of her was left behind
        assert staff_b.get(f"/v1/users/{LIN}").status_code == 404


def test_a_document_that_is_not_json_is_refused(
    other: tuple[FastAPI, TestClient, TestClient, str],
) -> None:
    app, _, _, _ = other
    with pytest.raises(ValidationFailed, match="Not a JSON document"):
        _import(app, b'{"format": "attune.subject", "format_version": 1, "person": {')


def test_a_fleet_with_another_mission_refuses_her_history(
    exported: bytes, other: tuple[FastAPI, TestClient, TestClient, str]
) -> None:
    app, staff_b, _, _ = other
    mission = copy.deepcopy(office_mission().to_dict())
    mission["services"][0]["details"].append("cocoa")
    r = staff_b.put(
        "/v1/admin/fleets/default/mission", json={"change_id": "cocoa", "mission": mission}
    )
    assert r.status_code == 200, r.text
    # The fleet keeps its version 1 (the default mission): her history maps onto it.
    done = _import(app, exported)
    assert done.episodes == 8
    assert staff_b.get(f"/v1/users/{LIN}/model").json()["mission_version"] == 2
