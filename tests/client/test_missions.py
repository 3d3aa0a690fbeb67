"""The client's mission calls against the real application, in-process, on SQLite and
PostgreSQL: reading a fleet's mission and its versions, changing it (idempotent on the
change_id the client derives), and what a change does to a robot's pending outcomes."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import attune_client as a
import httpx
import pytest
from fastapi import FastAPI

from app.learning import load_mission
from tests.support.fixtures import MakeKey
from tests.support.people import cooperative

from .conftest import BASE_URL, PortalTransport, SwitchTransport, fast
from .helpers import EVENT_TIME

pytestmark = pytest.mark.anyio

CARE_HOME = Path(__file__).parents[2] / "docs" / "examples" / "care-home-mission.json"


def care_home() -> dict[str, Any]:
    document: dict[str, Any] = json.loads(CARE_HOME.read_text(encoding="utf-8"))
    return document


async def staff_client(app: FastAPI, make_key: MakeKey, fleet: str = "default") -> a.AsyncClient:
    client = a.AsyncClient(
        BASE_URL, make_key("staff", fleet=fleet), transport=httpx.ASGITransport(app=app)
    )
    fast(client)
    return client


async def test_set_read_and_list_a_fleets_mission(
    app: FastAPI, make_key: MakeKey, robot: a.AsyncClient, admin: a.AsyncClient
) -> None:
    await robot.put_user("lin")  # the fleet's version 1: the deployment's default
    before = await robot.mission()
    assert (before.fleet, before.version, before.name) == ("default", 1, "office")
    assert before.fingerprint is not None
    assert before.fingerprint.startswith("sha256:")

    async with await staff_client(app, make_key) as staff:
        changed = await staff.set_mission("default", care_home())
        assert changed.changed
        assert (changed.version, changed.previous_version) == (2, 1)
        assert changed.users_moved == 1
        assert not changed.replayed
        assert changed.fingerprint == load_mission(CARE_HOME).fingerprint
        # the same file again: the derived change_id makes it the same change
        again = await staff.set_mission("default", care_home())
        assert again.replayed
        assert again.version == 2
        versions = await staff.missions("default")
    assert versions.current_version == 2
    assert [v.version for v in versions.items] == [2, 1]
    newest = versions.items[0]
    assert newest.change_id == a.mission_change_id(care_home())
    assert newest.mission.services[0].details == ["cocoa", "tea", "water"]
    assert newest.stored
    assert newest.created_at is not None

    now = await robot.mission()
    assert (now.version, now.name) == (2, "care-home")
    assert now.fingerprint == changed.fingerprint
    assert now.document() == load_mission(CARE_HOME).to_dict()
    assert (await admin.mission(fleet="default")).version == 2
    # an equal mission, given as the client read it, changes nothing
    same = await admin.set_mission("default", now, change_id="same-again")
    assert not same.changed
    assert same.version == 2


async def test_errors_are_the_clients_usual_ones(
    app: FastAPI, make_key: MakeKey, robot: a.AsyncClient
) -> None:
    await robot.put_user("lin")  # renames are checked against a stored version
    with pytest.raises(a.PermissionDeniedError):
        await robot.set_mission("default", care_home())
    with pytest.raises(a.PermissionDeniedError):
        await robot.missions("default")
    with pytest.raises(a.PermissionDeniedError):
        await robot.mission(fleet="other")
    async with await staff_client(app, make_key) as staff:
        with pytest.raises(a.PermissionDeniedError):
            await staff.set_mission("other", care_home())
        with pytest.raises(a.UnprocessableEntityError) as bad:
            await staff.set_mission("default", {**care_home(), "situations": []})
        assert "situations" in bad.value.detail
        with pytest.raises(a.UnprocessableEntityError) as renamed:
            await staff.set_mission("default", care_home(), renames={"details": {"chai": "cocoa"}})
        assert "chai" in renamed.value.detail
        await staff.set_mission("default", care_home(), change_id="menu-1")
        other = {**care_home(), "situations": ["waking", "meal", "resting", "personal_care"]}
        other["labels"] = {k: v for k, v in other["labels"].items() if k != "visiting"}
        with pytest.raises(a.ConflictError) as reused:
            await staff.set_mission("default", other, change_id="menu-1")
        assert "menu-1" in reused.value.detail


async def test_an_interrupted_outcome_raises_at_once(
    app: FastAPI, make_key: MakeKey, robot: a.AsyncClient
) -> None:
    started = await robot.start_episode(
        "lin", event_id="e1", occurred_at=EVENT_TIME, situation="stretching"
    )
    assert started.decision is not None
    assert started.mission_version == 1
    async with await staff_client(app, make_key) as staff:
        changed = await staff.set_mission("default", care_home())
    assert changed.episodes_interrupted == 1
    with pytest.raises(a.EpisodeInterruptedError) as caught:
        await robot.report_outcome(
            started.episode_id,
            decision_id=started.decision.decision_id,
            **cooperative(started.decision.action),
        )
    assert caught.value.status_code == 409
    trace = await robot.get_episode(started.episode_id)
    assert trace.status == "interrupted"
    assert trace.mission_version == 1


async def test_an_interrupted_outcome_leaves_the_outbox(
    app: FastAPI, make_key: MakeKey, switch: SwitchTransport, tmp_path: Path
) -> None:
    key = make_key("robot")
    async with fast(
        a.AsyncClient(BASE_URL, key, transport=switch, max_retries=0, outbox=tmp_path / "outbox.db")
    ) as robot:
        started = await robot.start_episode(
            "lin", event_id="e1", occurred_at=EVENT_TIME, situation="stretching"
        )
        assert started.decision is not None
        switch.down = True
        queued = await robot.report_outcome(
            started.episode_id,
            decision_id=started.decision.decision_id,
            **cooperative(started.decision.action),
        )
        assert isinstance(queued, a.Queued)
        async with await staff_client(app, make_key) as staff:
            await staff.set_mission("default", care_home())
        switch.down = False
        report = await robot.flush()
        assert [p.key for p in report.interrupted] == [started.decision.decision_id]
        assert report.delivered == []
        assert report.remaining == 0
        [(entry, why)] = await robot.rejected()
        assert why.interrupted
        assert why.status_code == 409
        assert entry.episode_id == started.episode_id
        # the person's next event runs under the new mission
        fresh = await robot.start_episode(
            "lin", event_id="e2", occurred_at=EVENT_TIME, situation="visiting"
        )
        assert fresh.mission_version == 2


def test_the_sync_client(portal: PortalTransport, make_key: MakeKey) -> None:
    with fast(a.Client(BASE_URL, make_key("admin"), transport=portal)) as admin:
        changed = admin.set_mission("care", care_home())
        # Version 1 was the deployment's default, which the fleet had until now.
        assert (changed.fleet, changed.version, changed.previous_version) == ("care", 2, 1)
        assert admin.missions("care").items[0].name == "care-home"
        assert admin.mission(fleet="care").version == 2
