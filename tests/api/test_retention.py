"""Retention (``PUT /v1/admin/fleets/{fleet}/history``, ``attune retention run``): the history
older than a fleet's window is folded into the people's models and profiles and removed, and
nothing they say changes, on both engines.

The person here has a history with answers that change their mind, feedback, a staff
correction that their answers later override, a lifted correction, a mission change and an
episode left open. After runs that cut the history in the middle, at the mission change and
after it: their model (its document and its action distributions), their profile and the
robot's next decision are those of a twin who kept everything; ``models rebuild`` replays
from the moved base into the identical model and redraws every kept decision; the episodes
listed start where the window does and the statistics say from when. A run stopped in the
middle of its removals loses nothing that should stay, and the next one finishes.
"""

from __future__ import annotations

import copy
import datetime as dt
import random
from collections.abc import Callable
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from app.db.models import Episode, HistoryFold, JournalEntry
from app.db.repositories import retention as retention_repo
from app.db.session import Database
from app.learning import office_mission
from app.services import audit as audit_service
from app.services import retention
from app.services.models import rebuild_model
from tests.support.episodes import play, start
from tests.support.people import answer
from tests.support.rows import user_pk

ADA = "ret-ada"
TEA = {"service": "ProvideDrink", "detail": "tea"}
SITUATIONS = ("stretching", "arriving", "working")


def _who(i: int) -> Callable[[dict[str, Any]], dict[str, Any]]:
    """The person's answers at their ``i``-th episode: tea at first, then coffee, with noise."""
    rng = random.Random(i)
    need = ("ProvideDrink", "tea") if i < 14 else ("ProvideDrink", "coffee")
    return lambda d: answer(d["action"], need=need, rng=rng, yes=0.85, smiles=0.3)


def _episodes(robot: TestClient, user_id: str, first: int, last: int) -> None:
    for i in range(first, last):
        played = play(
            robot,
            user_id,
            f"{user_id}-evt-{i}",
            _who(i),
            robot_id="ret-robot",
            situation=SITUATIONS[i % 3],
        )
        if i % 5 == 0:
            r = robot.post(
                f"/v1/episodes/{played.episode_id}/feedback",
                json={"feedback_id": f"fb-{i}", "feedback": "negative" if i % 2 else "positive"},
            )
            assert r.status_code == 200, r.text


def _correction(cid: str) -> dict[str, Any]:
    return {
        "correction_id": cid,
        "time_slot": "afternoon",
        "situation": "stretching",
        "kind": "prefers",
        **TEA,
    }


def _fill(robot: TestClient, staff: TestClient, user_id: str) -> None:
    """A history of 30 episodes with a mission change after the 16th (the fleet's mission is
    changed once, by the caller, between the two halves)."""
    assert staff.put(f"/v1/users/{user_id}", json={}).status_code == 201
    _episodes(robot, user_id, 0, 6)
    for cid in ("c1", "c2"):
        r = staff.post(f"/v1/users/{user_id}/corrections", json=_correction(f"{user_id}-{cid}"))
        assert r.status_code == 201, r.text
    assert staff.delete(f"/v1/users/{user_id}/corrections/{user_id}-c2").status_code in (200, 204)
    _episodes(robot, user_id, 6, 16)


def _change_mission(staff: TestClient) -> None:
    doc = copy.deepcopy(office_mission().to_dict())
    doc["services"][0]["details"].append("cocoa")
    r = staff.put(
        "/v1/admin/fleets/default/mission", json={"change_id": "ret-cocoa", "mission": doc}
    )
    assert r.status_code == 200, r.text


def _said(staff: TestClient, user_id: str) -> dict[str, Any]:
    """Everything the service says about the person's learning (not the raw history)."""
    model = staff.get(f"/v1/users/{user_id}/model").json()
    doc = staff.get(f"/v1/users/{user_id}/model/export").json()
    profile = staff.get(f"/v1/users/{user_id}/profile").json()
    for d in (model, doc, profile):
        d.pop("user_id", None)
        d.pop("exported_at", None)
        d.pop("updated_at", None)
    return {"model": model, "doc": doc, "profile": profile}


def _received(db: Database, user_id: str, seq: int) -> dt.datetime:
    with db.transaction(write=False) as session:
        at = session.scalar(
            select(Episode.created_at).where(
                Episode.user_pk == user_pk(session, user_id), Episode.seq == seq
            )
        )
    assert at is not None
    return at


def _rebuilds(app: FastAPI, user_id: str) -> int:
    with app.state.db.transaction() as session:
        report = rebuild_model(session, app.state.ctx, audit_service.CLI, user_id)
    assert report.identical, report.mismatched_decisions
    return report.decisions


def _kept(db: Database, user_id: str) -> tuple[int, int, int]:
    """(episodes, the first kept episode's number, journal entries) of the person."""
    with db.transaction(write=False) as session:
        pk = user_pk(session, user_id)
        n, first = session.execute(
            select(func.count(), func.min(Episode.seq)).where(Episode.user_pk == pk)
        ).one()
        entries = session.scalar(select(func.count()).where(JournalEntry.user_pk == pk))
    return int(n), int(first or 0), int(entries or 0)


@pytest.fixture
def filled(app: FastAPI, robot: TestClient, staff: TestClient) -> None:
    """ADA's history of 30 episodes and an open one, the mission changed after the 16th."""
    _fill(robot, staff, ADA)
    _change_mission(staff)
    _episodes(robot, ADA, 16, 30)
    start(robot, ADA, f"{ADA}-evt-open", situation="stretching", robot_id="ret-robot")


def _window(staff: TestClient, days: int | None) -> None:
    r = staff.put("/v1/admin/fleets/default/history", json={"history_days": days})
    assert r.status_code == 200, r.text
    assert r.json()["history_days"] == days


def _run(app: FastAPI, *, now: dt.datetime, batch: int = 7) -> retention.RunReport:
    return retention.run(app.state.db, app.state.ctx, now=now, batch=batch)


@pytest.mark.usefixtures("filled")
def test_runs_remove_old_history_and_change_nothing_the_model_or_profile_says(
    app: FastAPI, db: Database, robot: TestClient, staff: TestClient
) -> None:
    before = _said(staff, ADA)
    journal = _kept(db, ADA)[2]
    days, removed = 30, 0
    received = {seq: _received(db, ADA, seq) for seq in range(1, 32)}
    _window(staff, days)
    # Cuts before the mission change, at it, and after it (all but the open episode, 31).
    for cut in (9, 17, 31):
        report = _run(app, now=received[cut] + dt.timedelta(days=days))
        assert report.episodes_removed == cut - 1 - removed
        removed = cut - 1
        assert _said(staff, ADA) == before, f"a run cutting at episode {cut} changed a word"
        episodes, first, _ = _kept(db, ADA)
        assert (first, episodes) == (cut, 31 - cut + 1), "the history kept starts at the cut"
        assert _rebuilds(app, ADA) > 0
        listed = staff.get(f"/v1/users/{ADA}/episodes", params={"limit": 100}).json()["items"]
        assert min(e["index"] for e in listed) == cut
        stats = staff.get(f"/v1/users/{ADA}/stats").json()
        assert stats["episodes"] == episodes
        kept_from = dt.datetime.fromisoformat(stats["history_from"])
        assert received[cut - 1] < kept_from <= received[cut]
    assert _kept(db, ADA)[2] < journal, "the journal was cut too"
    # Robots go on as before; the model still rebuilds from its moved base.
    _episodes(robot, ADA, 30, 34)
    assert _rebuilds(app, ADA) > 0


@pytest.mark.usefixtures("filled")
def test_a_run_stopped_in_its_removals_loses_nothing_and_the_next_finishes(
    app: FastAPI, db: Database, staff: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = _said(staff, ADA)
    _window(staff, 30)
    now = _received(db, ADA, 21) + dt.timedelta(days=30)
    real = retention_repo.delete_episodes
    calls = {"n": 0}

    def dies_after_one_batch(*args: Any, **kw: Any) -> int:
        calls["n"] += 1
        if calls["n"] > 1:
            raise RuntimeError("the process died")
        return real(*args, **kw)

    monkeypatch.setattr(retention_repo, "delete_episodes", dies_after_one_batch)
    with pytest.raises(RuntimeError):
        _run(app, now=now, batch=3)
    episodes, first, _ = _kept(db, ADA)
    assert 1 < first < 21, "the run stopped half way"
    assert _said(staff, ADA) == before
    assert _rebuilds(app, ADA) > 0
    monkeypatch.setattr(retention_repo, "delete_episodes", real)
    report = _run(app, now=now, batch=3)
    assert report.episodes_removed == 20 - (first - 1)
    assert _kept(db, ADA)[1] == 21
    assert _said(staff, ADA) == before
    assert _rebuilds(app, ADA) > 0
    with db.transaction(write=False) as session:
        assert not retention_repo.leftovers(session, user_pk(session, ADA))
    # Nothing more to do: a third run removes nothing.
    assert _run(app, now=now).episodes_removed == 0


@pytest.mark.usefixtures("filled")
def test_a_fleet_without_a_window_keeps_everything(
    app: FastAPI, db: Database, staff: TestClient, admin: TestClient
) -> None:
    far = dt.datetime.now(dt.UTC) + dt.timedelta(days=10_000)
    assert _run(app, now=far).fleets == []
    _window(staff, 30)
    _window(staff, None)
    assert _run(app, now=far).fleets == []
    assert _kept(db, ADA)[0] == 31
    with db.transaction(write=False) as session:
        assert session.scalar(select(func.count()).select_from(HistoryFold)) == 0
    actions = [e["action"] for e in admin.get("/v1/admin/audit").json()["items"]]
    assert actions.count("fleet.history") == 2


def test_the_window_is_the_fleet_staffs_and_checked(
    staff: TestClient, other_staff: TestClient, robot: TestClient, admin: TestClient
) -> None:
    assert staff.get("/v1/admin/fleets/default/history").json()["history_days"] is None
    assert (
        other_staff.put("/v1/admin/fleets/default/history", json={"history_days": 3}).status_code
        == 403
    )
    assert (
        robot.put("/v1/admin/fleets/default/history", json={"history_days": 3}).status_code == 403
    )
    for bad in (0, -1, 36_501, 2.5, "30", True):
        r = staff.put("/v1/admin/fleets/default/history", json={"history_days": bad})
        assert r.status_code == 422, (bad, r.text)
    assert staff.put("/v1/admin/fleets/default/history", json={}).status_code == 422
    assert admin.put("/v1/admin/fleets/default/history", json={"history_days": 90}).json() == {
        "fleet": "default",
        "history_days": 90,
    }
    assert staff.get("/v1/admin/fleets/default/history").json()["history_days"] == 90
