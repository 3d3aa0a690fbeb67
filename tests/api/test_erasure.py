"""Erasing a person (``DELETE /v1/users/{id}``) leaves nothing of them, on both engines: every
table and column of the database is read (``tests/support/erasure``), after a history with
feedback, staff corrections with notes, a lifted correction, an export, an import, a change of
their prior, a mission change, an episode left open and a retention run that folded
their oldest episodes, a shadow that decided at her decisions, a rollout that moved her to
another learner, and an evaluation whose result has a row for her. Their audit entries keep who
did what, when and to which id, and nothing else; the database refuses to blank anyone else's. Their
number is never given to a newcomer. And the check finds a table that keeps something of them.
"""

from __future__ import annotations

import copy
import datetime as dt
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select, text
from sqlalchemy.exc import DBAPIError

from app.db.models import Episode
from app.db.session import Database
from app.learning import office_mission
from app.services import evaluation_jobs as jobs
from app.services import retention, rollouts, shadows
from tests.support.episodes import play, start
from tests.support.erasure import Subject, remains
from tests.support.people import person
from tests.support.rows import user_pk

ADA = "zw-resident-7c1f"  # the person erased
BO = "bo-resident"  # a neighbour in the same fleet, who keeps everything
NAME = "Adelaide Zwicky-Marsh"
NOTE = "Zwicky: takes her tea at four, her daughter says"
TEA = {"service": "ProvideDrink", "detail": "tea"}


def _correction(cid: str, note: str | None = None) -> dict[str, Any]:
    body: dict[str, Any] = {
        "correction_id": cid,
        "time_slot": "afternoon",
        "situation": "stretching",
        "kind": "prefers",
        **TEA,
    }
    if note is not None:
        body["note"] = note
    return body


def _history(robot: TestClient, user_id: str, prefix: str, count: int, n: int = 0) -> list[str]:
    """``count`` episodes of ``user_id`` played to their end; their ids."""
    episodes = []
    for i in range(n, n + count):
        played = play(
            robot,
            user_id,
            f"{prefix}-evt-{i}",
            person(picky=False),
            robot_id=f"{prefix}-robot",
            situation=("stretching", "arriving", "working")[i % 3],
        )
        episodes.append(played.episode_id)
    return episodes


def _fill(robot: TestClient, staff: TestClient, admin: TestClient) -> None:
    """Everything the service can hold about ADA (and a little about BO, made before her)."""
    assert staff.put(f"/v1/users/{BO}", json={}).status_code == 201
    _history(robot, BO, "bo", 3)
    assert staff.put(f"/v1/users/{BO}", json={"fleet_prior": False}).status_code == 200
    made = staff.put(f"/v1/users/{ADA}", json={"display_name": NAME})
    assert made.status_code == 201, made.text
    done = _history(robot, ADA, "zw", 6)
    r = robot.post(
        f"/v1/episodes/{done[0]}/feedback", json={"feedback_id": "zw-fb-1", "feedback": "positive"}
    )
    assert r.status_code == 200, r.text
    for body in (_correction("zw-corr-1", NOTE), _correction("zw-corr-2")):
        r = staff.post(f"/v1/users/{ADA}/corrections", json=body)
        assert r.status_code == 201, r.text
    assert staff.delete(f"/v1/users/{ADA}/corrections/zw-corr-2").status_code in (200, 204)
    exported = admin.get(f"/v1/users/{ADA}/model/export")
    assert exported.status_code == 200, exported.text
    assert admin.put(f"/v1/users/{ADA}/model", json=exported.json()).status_code == 200
    assert staff.put(f"/v1/users/{ADA}", json={"fleet_prior": False}).status_code == 200
    doc = copy.deepcopy(office_mission().to_dict())
    doc["services"][0]["details"].append("cocoa")
    r = staff.put(
        "/v1/admin/fleets/default/mission", json={"change_id": "zw-cocoa", "mission": doc}
    )
    assert r.status_code == 200, r.text
    _history(robot, ADA, "zw", 2, n=6)
    # A shadow decides beside the robots; a rollout moves everyone to a candidate (her arm).
    r = staff.put("/v1/admin/fleets/default/shadow", json={"candidate": {"algorithm": "dts"}})
    assert r.status_code == 201, r.text
    rollout = {"candidate": {"algorithm": "hri", "params": {"tau": 0.005}}, "share": 1.0}
    r = staff.put("/v1/admin/fleets/default/rollout", json=rollout)
    assert r.status_code == 201, r.text
    # Her wish in one context changes: told to staff (a change, and the context's walk).
    wishes = [("ProvideDrink", "tea")] * 4 + [("ProvideDrink", "coffee")] * 3
    for i, need in enumerate(wishes, start=20):
        play(
            robot,
            ADA,
            f"zw-evt-{i}",
            person(need=need),
            robot_id="zw-robot",
            situation="stretching",
        )
    assert staff.get(f"/v1/users/{ADA}/changes").json()["items"], "her wish changed"
    start(robot, ADA, "zw-evt-open", situation="stretching", robot_id="zw-robot")


def _what_if(app: FastAPI, staff: TestClient) -> None:
    """The shadow's candidate decides at her decisions, and an evaluation's result has a row
    for her."""
    app.state.rollout_mover.join()
    rollouts.complete_moves(app.state.db, app.state.ctx)  # the rollout moved her
    later = dt.datetime.now(dt.UTC) + dt.timedelta(seconds=10)
    assert shadows.shadow_pass(app.state.db, app.state.ctx, now=later, estimate=False)["default"]
    app.state.evaluations = None  # run here, not by the worker's runner
    body = {"request_id": "zw-review", "candidates": [{"algorithm": "dts"}]}
    job = staff.post("/v1/admin/fleets/default/evaluations", json=body).json()
    assert jobs.run_job(app.state.db, app.state.ctx, job["evaluation_id"]) == "done"
    found = staff.get(f"/v1/admin/fleets/default/evaluations/{job['evaluation_id']}").json()
    assert ADA in {p["user_id"] for p in found["result"]["persons"]}


def _retention_run(app: FastAPI, staff: TestClient, db: Database) -> None:
    """A retention run that folds and removes ADA's first four episodes (and BO's)."""
    r = staff.put("/v1/admin/fleets/default/history", json={"history_days": 30})
    assert r.status_code == 200, r.text
    with db.transaction(write=False) as session:
        pk = user_pk(session, ADA)
        at = session.scalar(
            select(Episode.created_at).where(Episode.user_pk == pk, Episode.seq == 5)
        )
    assert at is not None
    report = retention.run(app.state.db, app.state.ctx, now=at + dt.timedelta(days=30))
    assert report.episodes_removed >= 4


@pytest.fixture
def erased(
    app: FastAPI, robot: TestClient, staff: TestClient, admin: TestClient, db: Database
) -> Subject:
    """ADA, filled, her oldest history folded by a retention run, and then erased by her
    fleet's staff."""
    _fill(robot, staff, admin)
    _what_if(app, staff)
    _retention_run(app, staff, db)
    with db.transaction() as session:
        pk = user_pk(session, ADA)
    subject = Subject(
        pk=pk, user_id=ADA, markers=(NAME, NOTE, "zw-evt-", "zw-robot", "zw-corr-", "zw-fb-")
    )
    assert remains(db.engine, subject), "the check sees nothing of a person who is there"
    assert staff.delete(f"/v1/users/{ADA}").status_code == 204
    return subject


def test_nothing_of_an_erased_person_remains(
    erased: Subject, db: Database, robot: TestClient, staff: TestClient
) -> None:
    assert remains(db.engine, erased) == []
    assert robot.get(f"/v1/users/{ADA}").status_code == 404
    # The neighbour keeps all of theirs.
    assert staff.get(f"/v1/users/{BO}").json()["episodes"] == 3
    assert staff.get(f"/v1/users/{BO}/model").status_code == 200
    assert staff.get(f"/v1/users/{BO}/profile").json()["episodes"] == 3  # folded, not erased


def test_the_audit_log_keeps_who_did_what_and_nothing_of_the_person(
    erased: Subject, admin: TestClient
) -> None:
    items = admin.get("/v1/admin/audit", params={"limit": 500}).json()["items"]
    about = [e for e in items if e["target"] == ADA]
    assert [e["action"] for e in about] == [
        "user.delete",
        "user.learner",  # the rollout moved her
        "user.prior",
        "model.import",
        "model.export",
        "correction.lift",
        "correction.add",
        "correction.add",
    ]
    for entry in about:
        assert entry["detail"] == {"erased": True}, entry
        assert entry["fleet"] == "default"
        assert entry["actor"]["role"] in ("staff", "admin")
    assert about[0]["actor"]["role"] == "staff"
    # The fleet's own entries stay whole: the mission change says what it did.
    [mission] = [e for e in items if e["action"] == "mission.set"]
    assert mission["detail"]["users_moved"] == 2


def test_the_database_blanks_only_an_erased_persons_entries(erased: Subject, db: Database) -> None:
    blank = "UPDATE audit_log SET detail = :d WHERE target = :t"
    for statement, params in (
        (blank, {"d": '{"erased": true}', "t": BO}),  # a living person's
        (blank, {"d": '{"something": "else"}', "t": ADA}),  # anything but the blank
        ("UPDATE audit_log SET actor_role = 'robot' WHERE target = :t", {"t": ADA}),
        ("DELETE FROM audit_log WHERE target = :t", {"t": ADA}),
    ):
        with db.engine.connect() as conn:  # there are rows to refuse
            where = statement[statement.index(" WHERE ") :]
            assert conn.execute(text(f"SELECT COUNT(*) FROM audit_log{where}"), params).scalar()
        with db.engine.begin() as conn, pytest.raises(DBAPIError, match="append only"):
            conn.execute(text(statement), params)
    with db.engine.begin() as conn:  # blanking an erased person's entry again is allowed
        again = conn.execute(text(blank), {"d": '{"erased": true}', "t": ADA})
        assert again.rowcount == 8


def test_a_newcomer_with_the_same_id_starts_fresh_under_a_new_number(
    erased: Subject, db: Database, staff: TestClient
) -> None:
    assert staff.put(f"/v1/users/{ADA}", json={}).status_code == 201
    with db.transaction() as session:
        assert user_pk(session, ADA) > erased.pk  # never the erased person's number
    assert staff.get(f"/v1/users/{ADA}").json()["episodes"] == 0
    assert staff.get(f"/v1/users/{ADA}/corrections").json()["items"] == []


def test_erasing_in_one_fleet_leaves_the_same_id_in_another(
    robot: TestClient,
    staff: TestClient,
    other_robot: TestClient,
    other_staff: TestClient,
    db: Database,
) -> None:
    for client, robots in ((staff, robot), (other_staff, other_robot)):
        assert client.put(f"/v1/users/{ADA}", json={}).status_code == 201
        _history(robots, ADA, "zw", 2)
    with db.transaction() as session:
        pk, other_pk = user_pk(session, ADA), user_pk(session, ADA, "other")
    assert staff.delete(f"/v1/users/{ADA}").status_code == 204
    assert remains(db.engine, Subject(pk=pk, user_id=ADA, id_is_marker=False)) == []
    assert other_staff.get(f"/v1/users/{ADA}").json()["episodes"] == 2
    left = remains(db.engine, Subject(pk=other_pk, user_id=ADA, id_is_marker=False))
    assert any(line.startswith("episodes:") for line in left)  # the other fleet's is whole


@pytest.fixture
def extra_table(db: Database) -> Iterator[str]:
    """A table the product does not have, keeping something of a person by their number and by
    text, with no foreign key: what a new feature that forgot erasure would add."""
    with db.engine.begin() as conn:
        conn.execute(
            text(
                "CREATE TABLE resident_extras (id INTEGER PRIMARY KEY, user_pk INTEGER, note TEXT)"
            )
        )
    try:
        yield "resident_extras"
    finally:
        with db.engine.begin() as conn:
            conn.execute(text("DROP TABLE resident_extras"))


def test_the_check_finds_a_table_that_keeps_something_of_the_person(
    extra_table: str, robot: TestClient, staff: TestClient, db: Database
) -> None:
    assert staff.put(f"/v1/users/{ADA}", json={"display_name": NAME}).status_code == 201
    _history(robot, ADA, "zw", 1)
    with db.transaction() as session:
        pk = user_pk(session, ADA)
    with db.engine.begin() as conn:
        conn.execute(
            text(f"INSERT INTO {extra_table} (id, user_pk, note) VALUES (1, :pk, :r)"),
            {"pk": pk, "r": f"{NAME} likes the window seat"},
        )
    assert staff.delete(f"/v1/users/{ADA}").status_code == 204
    left = remains(db.engine, Subject(pk=pk, user_id=ADA, markers=(NAME,)))
    assert len(left) == 2, left
    assert left[0].startswith(f"{extra_table}: a row that refers to the person")
    assert left[1].startswith(f"{extra_table}.note: holds {NAME!r}")
