"""The model's journal, typed (``app.db.repositories.journal``), on both engines: every kind of
entry is stored and read back with its named fields; a person's journal, made through the API,
says what happened to their model version by version (steps, feedback, corrections and lifts,
a mission move, a reset, an import, a retention fold), each field meaning what its name says;
and the model rebuilds from it identically at every stage.
"""

from __future__ import annotations

import copy
import datetime as dt
import random
from collections import defaultdict

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from app.db.models import Correction, Decision, Episode
from app.db.repositories import journal
from app.db.session import Database
from app.learning import office_mission
from app.schemas.users import LearnerSpec
from app.services import audit as audit_service
from app.services import retention
from app.services.models import rebuild_model
from tests.support.episodes import play
from tests.support.people import person
from tests.support.rows import user_pk

BEN = "journal-ben"
SLOT, SITUATION = "afternoon", "stretching"


def _entries(db: Database, user_id: str) -> list[journal.Entry]:
    with db.transaction(write=False) as session:
        return journal.entries_since(session, user_pk(session, user_id), -1)


def _rebuilt(app: FastAPI, user_id: str) -> None:
    with app.state.db.transaction() as session:
        report = rebuild_model(session, app.state.ctx, audit_service.CLI, user_id)
    assert report.identical, report.mismatched_decisions


def _version(staff: TestClient, user_id: str) -> int:
    version: int = staff.get(f"/v1/users/{user_id}/model").json()["version"]
    return version


def test_every_kind_is_stored_and_read_back_with_its_fields(
    db: Database, staff: TestClient
) -> None:
    assert staff.put(f"/v1/users/{BEN}", json={}).status_code == 201
    r = staff.post(
        f"/v1/users/{BEN}/corrections",
        json={
            "correction_id": "c",
            "time_slot": SLOT,
            "situation": SITUATION,
            "kind": "quiet",
        },
    )
    assert r.status_code == 201, r.text
    at = dt.datetime(2026, 3, 1, 8, 30, tzinfo=dt.UTC)
    with db.transaction() as session:
        pk = user_pk(session, BEN)
        row = session.scalar(select(Correction.id).where(Correction.user_pk == pk))
        assert row is not None
        written: list[journal.Entry] = [
            journal.Transition(101, 2, 7, 3, 0, 4, -0.25, 9, -1),
            journal.Transition(101, 2, 7, 3, 9, 12, 1.5, 1, 1),
            journal.Feedback(102, 2, 7, 3, 9, 12, 2.0),
            journal.Correction(103, 2, row, 7, 3),
            journal.Lift(104, 2, row, 8, 3),
            journal.MissionMove(105, 3),
            journal.Reset(
                106, 3, actor="key_x", algorithm="dts", cause="reset", corrections_kept=1
            ),
            journal.Import(107, 3, actor="cli", algorithm="hri", episodes=40),
            journal.Fold(108, 3, upto_seq=12, kept_from=at),
        ]
        journal.append(session, pk, written)
    with db.transaction(write=False) as session:
        read = journal.entries_since(session, user_pk(session, BEN), 100)
    assert read == written
    assert [e.kind for e in read] == [
        "transition",
        "transition",
        "feedback",
        "correction",
        "lift",
        "mission",
        "reset",
        "import",
        "fold",
    ]


def test_a_persons_journal_says_what_happened_to_their_model(
    app: FastAPI, db: Database, robot: TestClient, staff: TestClient
) -> None:
    assert staff.put(f"/v1/users/{BEN}", json={}).status_code == 201
    someone = person(picky=False, yes=0.8, asks=0.7, rng=random.Random(7))

    def meet(first: int, last: int) -> None:
        for i in range(first, last):
            played = play(robot, BEN, f"{BEN}-{i}", someone, situation=SITUATION)
            if i % 3 == 0:
                r = robot.post(
                    f"/v1/episodes/{played.episode_id}/feedback",
                    json={"feedback_id": f"fb-{i}", "feedback": "positive"},
                )
                assert r.status_code == 200, r.text

    meet(0, 4)
    corrected = {"correction_id": "tea", "time_slot": SLOT, "situation": SITUATION}
    r = staff.post(
        f"/v1/users/{BEN}/corrections",
        json={**corrected, "kind": "prefers", "service": "ProvideDrink", "detail": "tea"},
    )
    assert r.status_code == 201, r.text
    made_at = _version(staff, BEN)
    meet(4, 6)
    assert staff.delete(f"/v1/users/{BEN}/corrections/tea").status_code in (200, 204)
    lifted_at = _version(staff, BEN)
    _rebuilt(app, BEN)
    assert staff.delete(f"/v1/users/{BEN}/model").status_code == 204  # a reset
    reset_at = _version(staff, BEN)
    meet(6, 8)
    doc = staff.get(f"/v1/users/{BEN}/model/export").json()
    assert staff.put(f"/v1/users/{BEN}/model", json=doc).status_code == 200  # an import
    import_at = _version(staff, BEN)
    _rebuilt(app, BEN)
    mission = copy.deepcopy(office_mission().to_dict())
    mission["services"][0]["details"].append("cocoa")
    r = staff.put(
        "/v1/admin/fleets/default/mission", json={"change_id": "cocoa", "mission": mission}
    )
    assert r.status_code == 200, r.text
    moved_at = _version(staff, BEN)
    meet(8, 10)
    _rebuilt(app, BEN)

    entries = _entries(db, BEN)
    by_version: dict[int, list[journal.Entry]] = defaultdict(list)
    for e in entries:
        by_version[e.version].append(e)
    # One entry kind per version, every version from the first to the head.
    assert sorted(by_version) == list(range(1, _version(staff, BEN) + 1))
    assert all(len({e.kind for e in es}) == 1 for es in by_version.values())

    with db.transaction(write=False) as session:
        pk = user_pk(session, BEN)
        correction_pk = session.scalar(select(Correction.id).where(Correction.user_pk == pk))
        decisions = session.execute(
            select(Decision.state, Decision.action, Decision.next_state, Decision.reward)
            .join(Episode, Episode.id == Decision.episode_id)
            .where(Episode.user_pk == pk, Decision.response.is_not(None))
        ).all()
    (made,) = by_version[made_at]
    assert isinstance(made, journal.Correction)
    assert made.correction_pk == correction_pk
    assert made.since == 4  # the learner had seen four episodes
    assert made.context == office_mission().context_index(SLOT, SITUATION)
    (lift,) = by_version[lifted_at]
    assert isinstance(lift, journal.Lift)
    assert lift.correction_pk == correction_pk
    assert lift.since == 6
    (reset,) = by_version[reset_at]
    assert isinstance(reset, journal.Reset)
    default = LearnerSpec().algorithm
    assert (reset.cause, reset.algorithm, reset.corrections_kept) == ("reset", default, 0)
    assert reset.actor.startswith("key_")
    (imported,) = by_version[import_at]
    assert isinstance(imported, journal.Import)
    assert (imported.algorithm, imported.episodes) == (default, 8)
    (move,) = by_version[moved_at]
    assert isinstance(move, journal.MissionMove)
    assert move.mission_version == 2
    # Every answered decision is a transition of the journal, field for field.
    steps = {
        (e.state, e.action, e.next_state, e.reward)
        for e in entries
        if isinstance(e, journal.Transition)
    }
    for state, action, next_state, reward in decisions:
        assert (state, action, next_state, reward) in steps
    feedback = [e for e in entries if isinstance(e, journal.Feedback)]
    assert len(feedback) == 4
    assert all(f.reward > 0 for f in feedback)

    # A retention run folds the journal before the cut into the base: a fold entry marks it,
    # nothing older stays, and the model still rebuilds from it.
    r = staff.put("/v1/admin/fleets/default/history", json={"history_days": 1})
    assert r.status_code == 200, r.text
    retention.run(db, app.state.ctx, now=dt.datetime.now(dt.UTC) + dt.timedelta(days=2))
    after = _entries(db, BEN)
    folds = [e for e in after if isinstance(e, journal.Fold)]
    assert len(folds) == 1
    assert folds[0].upto_seq == 10
    assert all(e.version > folds[0].version for e in after if e is not folds[0])
    _rebuilt(app, BEN)
    meet(10, 12)
    _rebuilt(app, BEN)


def test_every_write_works_when_no_learner_is_cached(
    app: FastAPI, robot: TestClient, staff: TestClient
) -> None:
    """Each write loads the learner from the stored snapshot and journal (as a worker that
    never saw the person does): an episode that ends at its first answer, feedback, staff
    corrections; and the model rebuilds from its journal."""
    app.state.ctx.cache.size = 0
    someone = person(picky=True, yes=0.5, asks=0.5, rng=random.Random(3))
    ended_at_once = 0
    for i in range(12):
        played = play(robot, BEN, f"{BEN}-cold-{i}", someone, situation=SITUATION)
        ended_at_once += len(played.steps) == 1
        r = robot.post(
            f"/v1/episodes/{played.episode_id}/feedback",
            json={"feedback_id": f"cold-{i}", "feedback": "negative"},
        )
        assert r.status_code == 200, r.text
        if i == 5:
            r = staff.post(
                f"/v1/users/{BEN}/corrections",
                json={
                    "correction_id": "cold",
                    "time_slot": SLOT,
                    "situation": SITUATION,
                    "kind": "quiet",
                },
            )
            assert r.status_code == 201, r.text
    assert ended_at_once > 0
    _rebuilt(app, BEN)
