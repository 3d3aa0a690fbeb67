"""The client's profile and correction calls against the real application, in-process, on
SQLite and PostgreSQL: reading a person's profile, making a correction (idempotent on its id),
listing and lifting corrections, a reset that keeps or drops them, and the errors the client
raises for what the service refuses. Async and sync clients."""

from __future__ import annotations

from typing import Any

import attune_client as a
import httpx
import pytest
from fastapi import FastAPI

from tests.support.fixtures import MakeKey

from .conftest import BASE_URL, PortalTransport, fast
from .helpers import EVENT_TIME, occurred

pytestmark = pytest.mark.anyio

SLOT, SITUATION = "afternoon", "stretching"  # EVENT_TIME is 15:10 local time
TEA = {"service": "ProvideDrink", "detail": "tea"}


async def staff_client(app: FastAPI, make_key: MakeKey, fleet: str = "default") -> a.AsyncClient:
    client = a.AsyncClient(
        BASE_URL, make_key("staff", fleet=fleet), transport=httpx.ASGITransport(app=app)
    )
    fast(client)
    return client


async def test_profile_of_a_person(robot: a.AsyncClient) -> None:
    await robot.put_user("chen", display_name="Mrs. Chen")
    started = await robot.start_episode(
        "chen",
        event_id="asks-for-tea",
        occurred_at=EVENT_TIME,
        situation=SITUATION,
        initiator="human",
        request=TEA,
    )
    assert started.decision is not None  # left open
    profile = await robot.get_profile("chen")
    assert isinstance(profile, a.Profile)
    assert (profile.user_id, profile.display_name) == ("chen", "Mrs. Chen")
    assert (profile.episodes, profile.open_episodes) == (1, 1)
    assert profile.utc_offset == 8 * 60
    assert profile.corrections == []
    cell = profile.context(SLOT, SITUATION)
    assert isinstance(cell, a.ProfileContext)
    assert cell.wants == a.Wanted(service="ProvideDrink", detail="tea")
    assert cell.certainty == "tentative"
    assert cell.source == "person"
    assert isinstance(cell.evidence, a.ProfileEvidence)
    assert cell.evidence.asked_for == 1
    assert cell.evidence.last_seen is not None
    assert cell.evidence.last_seen.utcoffset() is not None
    assert cell.evidence.last_seen.utcoffset().total_seconds() == 8 * 3600  # type: ignore[union-attr]
    assert isinstance(cell.robot_will, a.RobotWill)
    assert 0.0 <= cell.robot_will.probability <= 1.0
    assert "tea" in cell.summary
    assert cell.changed is None
    elsewhere = profile.context("morning", "arriving")
    assert (elsewhere.certainty, elsewhere.wants, elsewhere.episodes) == ("unknown", None, 0)
    with pytest.raises(KeyError):
        profile.context("midnight", SITUATION)
    with pytest.raises(a.NotFoundError):
        await robot.get_profile("nobody")


async def test_made_replayed_listed_and_lifted(
    app: FastAPI, make_key: MakeKey, robot: a.AsyncClient
) -> None:
    await robot.put_user("chen")
    async with await staff_client(app, make_key) as staff:
        made = await staff.add_correction(
            "chen",
            correction_id="tea-afternoons",
            time_slot=SLOT,
            situation=SITUATION,
            kind="prefers",
            service="ProvideDrink",
            detail="tea",
            note="Her daughter says so.",
        )
        assert isinstance(made, a.Correction)
        assert not made.replayed
        assert (made.kind, made.status, made.service, made.detail) == (
            "prefers",
            "in_force",
            "ProvideDrink",
            "tea",
        )
        assert made.note == "Her daughter says so."
        assert made.author
        assert made.lifted_at is None
        again = await staff.add_correction(
            "chen",
            correction_id="tea-afternoons",
            time_slot=SLOT,
            situation=SITUATION,
            kind="prefers",
            service="ProvideDrink",
            detail="tea",
            note="Her daughter says so.",
        )
        assert again.replayed
        assert again.model_dump(exclude={"replayed"}) == made.model_dump(exclude={"replayed"})
        hush = await staff.add_correction(
            "chen", correction_id="hush", time_slot="morning", situation="working", kind="quiet"
        )
        assert (hush.service, hush.detail, hush.note) == (None, None, None)
        assert hush.model_version == made.model_version + 1

        listed = await robot.list_corrections("chen")  # robot keys may read them
        assert isinstance(listed, a.CorrectionList)
        assert [c.correction_id for c in listed.items] == ["tea-afternoons", "hush"]
        profile = await robot.get_profile("chen")
        assert [c.correction_id for c in profile.corrections] == ["tea-afternoons", "hush"]
        cell = profile.context(SLOT, SITUATION)
        assert cell.source == "staff"
        assert cell.wants == a.Wanted(**TEA)
        assert cell.corrections == ["tea-afternoons"]
        assert cell.robot_will.action == "offer"
        assert profile.context("morning", "working").robot_will.action == "stay_away"

        await staff.lift_correction("chen", "hush")
        await staff.lift_correction("chen", "hush")  # lifting again changes nothing
        statuses = {
            c.correction_id: (c.status, c.lifted_by)
            for c in (await staff.list_corrections("chen")).items
        }
        assert statuses["tea-afternoons"] == ("in_force", None)
        assert statuses["hush"][0] == "lifted"
        assert statuses["hush"][1]
        assert [c.correction_id for c in (await robot.get_profile("chen")).corrections] == [
            "tea-afternoons"
        ]


async def test_a_reset_keeps_corrections_unless_dropped(
    app: FastAPI, make_key: MakeKey, robot: a.AsyncClient, admin: a.AsyncClient
) -> None:
    await robot.put_user("chen")
    await admin.add_correction(
        "chen", correction_id="tea", time_slot=SLOT, situation=SITUATION, kind="prefers", **TEA
    )
    await admin.reset_model("chen")
    assert [c.status for c in (await admin.list_corrections("chen")).items] == ["in_force"]
    await admin.reset_model("chen", drop_corrections=True)
    assert [c.status for c in (await admin.list_corrections("chen")).items] == ["lifted"]
    assert (await robot.get_profile("chen")).context(SLOT, SITUATION).source is None


async def test_the_person_overrides_a_preference(
    app: FastAPI, make_key: MakeKey, robot: a.AsyncClient
) -> None:
    await robot.put_user("chen")
    async with await staff_client(app, make_key) as staff:
        await staff.add_correction(
            "chen", correction_id="tea", time_slot=SLOT, situation=SITUATION, kind="prefers", **TEA
        )
    n = 0
    while (await robot.list_corrections("chen")).items[0].status == "in_force":
        assert n < 12, "the person's refusals never overrode the correction"
        started = await robot.start_episode(
            "chen", event_id=f"e{n}", occurred_at=occurred(n), situation=SITUATION
        )
        decision = started.decision
        while decision is not None:
            kind = decision.action.kind
            said: dict[str, Any] = {"response": "rejected"}
            if kind == "pass":
                said = {"response": "none"}
            elif kind == "query_type":
                said = {"response": "answered", "service": "ProvideDrink"}
            elif kind == "query_detail":
                said = {"response": "answered", "detail": "coffee"}
            elif kind == "perform" and decision.action.detail != "tea":
                said = {"response": "accepted"}
            result = await robot.report_outcome(
                started.episode_id, decision_id=decision.decision_id, **said
            )
            assert isinstance(result, a.OutcomeResult)
            decision = result.decision
        n += 1
    [item] = (await robot.list_corrections("chen")).items
    assert item.status == "overridden"
    assert item.overridden_at is not None
    cell = (await robot.get_profile("chen")).context(SLOT, SITUATION)
    assert cell.source != "staff"
    assert cell.changed is not None
    assert isinstance(cell.changed, a.ProfileChange)
    assert cell.changed.overrides == "tea"
    assert cell.changed.before == a.Wanted(**TEA)


async def test_errors_are_the_clients_usual_ones(
    app: FastAPI, make_key: MakeKey, robot: a.AsyncClient
) -> None:
    await robot.put_user("chen")
    with pytest.raises(a.PermissionDeniedError):
        await robot.add_correction(
            "chen", correction_id="r", time_slot=SLOT, situation=SITUATION, kind="quiet"
        )
    async with await staff_client(app, make_key) as staff:
        with pytest.raises(a.UnprocessableEntityError) as bad:
            await staff.add_correction(
                "chen", correction_id="x", time_slot="midnight", situation=SITUATION, kind="quiet"
            )
        assert "time slot" in bad.value.detail
        with pytest.raises(a.UnprocessableEntityError) as lacking:
            await staff.add_correction(
                "chen",
                correction_id="x",
                time_slot=SLOT,
                situation=SITUATION,
                kind="prefers",
                service="ProvideDrink",
            )
        assert "needs a detail" in lacking.value.detail
        await staff.add_correction(
            "chen", correction_id="c1", time_slot=SLOT, situation=SITUATION, kind="quiet"
        )
        with pytest.raises(a.ConflictError):
            await staff.add_correction(
                "chen",
                correction_id="c1",
                time_slot=SLOT,
                situation=SITUATION,
                kind="avoid",
                service="ProvideDrink",
            )
        with pytest.raises(a.NotFoundError):
            await staff.lift_correction("chen", "nope")
        with pytest.raises(a.NotFoundError):
            await staff.list_corrections("nobody")
    with pytest.raises(a.PermissionDeniedError):
        await robot.lift_correction("chen", "c1")
    async with await staff_client(app, make_key, fleet="other") as elsewhere:
        with pytest.raises(a.NotFoundError):
            await elsewhere.get_profile("chen")


def test_the_sync_client(portal: PortalTransport, make_key: MakeKey) -> None:
    with fast(a.Client(BASE_URL, make_key("admin"), transport=portal)) as admin:
        admin.put_user("lin")
        made = admin.add_correction(
            "lin",
            correction_id="no-news",
            time_slot="morning",
            situation="arriving",
            kind="avoid",
            service="BriefInformation",
            detail="news",
        )
        assert (made.kind, made.status) == ("avoid", "in_force")
        assert admin.add_correction(
            "lin",
            correction_id="no-news",
            time_slot="morning",
            situation="arriving",
            kind="avoid",
            service="BriefInformation",
            detail="news",
        ).replayed
        assert [c.correction_id for c in admin.list_corrections("lin").items] == ["no-news"]
        profile = admin.get_profile("lin")
        assert profile.context("morning", "arriving").corrections == ["no-news"]
        assert profile.episodes == 0
        assert profile.utc_offset is None
        admin.reset_model("lin")
        assert admin.list_corrections("lin").items[0].status == "in_force"
        admin.lift_correction("lin", "no-news")
        assert admin.list_corrections("lin").items[0].status == "lifted"
        admin.add_correction(
            "lin", correction_id="hush", time_slot="noon", situation="working", kind="quiet"
        )
        admin.reset_model("lin", drop_corrections=True)
        assert {c.status for c in admin.list_corrections("lin").items} == {"lifted"}
