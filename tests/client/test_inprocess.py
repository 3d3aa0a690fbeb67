"""The client against the real application, in-process (``ASGITransport``), on SQLite and
PostgreSQL: every endpoint, the models reading real answers, and the errors the service
really produces."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import attune_client as a
import httpx
import pytest
from fastapi import FastAPI

from tests.support.fixtures import MakeKey
from tests.support.people import cooperative

from .conftest import BASE_URL, PortalTransport, SwitchTransport, fast
from .helpers import EVENT_TIME, occurred

pytestmark = pytest.mark.anyio


async def play(
    client: a.AsyncClient,
    user_id: str,
    event_id: str,
    n: int = 0,
) -> tuple[a.EpisodeStarted, list[a.OutcomeResult]]:
    """One episode to its end; the outcome answers in order."""
    started = await client.start_episode(
        user_id,
        event_id=event_id,
        occurred_at=occurred(n),
        situation="stretching",
        robot_id="robot7",
    )
    results: list[a.OutcomeResult] = []
    decision = started.decision
    while decision is not None:
        result = await client.report_outcome(
            started.episode_id, decision_id=decision.decision_id, **cooperative(decision.action, n)
        )
        assert isinstance(result, a.OutcomeResult)
        results.append(result)
        decision = result.decision
    return started, results


class TestContract:
    async def test_users(self, robot: a.AsyncClient, admin: a.AsyncClient) -> None:
        created = await robot.put_user(
            "lin", display_name="Mrs. Lin", learner={"algorithm": "hri", "params": {"tau": 0.02}}
        )
        assert created.user_id == "lin"
        assert created.fleet == "default"
        assert created.learner.algorithm == "hri"
        assert created.learner.params["tau"] == 0.02
        assert created.episodes == 0
        assert created.created_at.tzinfo is not None
        updated = await admin.put_user("lin", display_name="Lin")
        assert updated.display_name == "Lin"
        assert (await robot.get_user("lin")).display_name == "Lin"
        for name in ("mo", "ana", "zed"):
            await robot.put_user(name)
        page = await robot.list_users(limit=2)
        assert [u.user_id for u in page.items] == ["ana", "lin"]
        assert page.next_cursor is not None
        assert [u.user_id async for u in robot.iter_users(page_size=3)] == [
            "ana",
            "lin",
            "mo",
            "zed",
        ]
        await admin.delete_user("zed")
        with pytest.raises(a.NotFoundError):
            await robot.get_user("zed")

    async def test_a_whole_episode_and_its_trace(self, robot: a.AsyncClient) -> None:
        started, results = await play(robot, "lin", "robot7-000001")
        assert started.status == "open"
        assert started.context == a.Context(time_slot="afternoon", situation="stretching")
        assert started.state == "OBSERVE"
        assert not started.replayed
        assert started.decision is not None
        assert sum(p.p for p in started.decision.probabilities) == pytest.approx(1.0)
        assert results[-1].episode.status == "closed"
        assert results[-1].decision is None
        trace = await robot.get_episode(started.episode_id)
        assert trace.status == "closed"
        assert trace.event_id == "robot7-000001"
        assert trace.robot_id == "robot7"
        assert trace.initiator == "robot"
        assert len(trace.decisions) == len(results)
        assert all(d.answered_at is not None for d in trace.decisions)
        assert trace.total_reward == pytest.approx(results[-1].episode.total_reward)
        fb = await robot.send_feedback(started.episode_id, feedback_id="fb-1", feedback="positive")
        assert isinstance(fb, a.FeedbackResult)
        assert fb.reward == 1.0
        assert not fb.replayed
        trace = await robot.get_episode(started.episode_id)
        assert [f.feedback_id for f in trace.feedback] == ["fb-1"]

    async def test_a_person_who_asks_first(self, robot: a.AsyncClient) -> None:
        started = await robot.start_episode(
            "lin",
            event_id="h1",
            occurred_at=dt.datetime.fromisoformat(EVENT_TIME),
            situation="working",
            initiator="human",
            request=a.ServiceRequest(service="ProvideDrink", detail="tea"),
        )
        assert started.decision is not None
        assert started.decision.chain  # respond and infer, taken silently
        trace = await robot.get_episode(started.episode_id)
        assert trace.initiator == "human"
        assert trace.interaction_class == "I1"

    async def test_writes_replay(self, robot: a.AsyncClient) -> None:
        kwargs = {"event_id": "e1", "occurred_at": EVENT_TIME, "situation": "arriving"}
        first = await robot.start_episode("lin", **kwargs)  # type: ignore[arg-type]
        again = await robot.start_episode("lin", **kwargs)  # type: ignore[arg-type]
        assert again.replayed
        assert again.model_dump(exclude={"replayed"}) == first.model_dump(exclude={"replayed"})
        assert first.decision is not None
        outcome = cooperative(first.decision.action)
        one = await robot.report_outcome(
            first.episode_id, decision_id=first.decision.decision_id, **outcome
        )
        two = await robot.report_outcome(
            first.episode_id, decision_id=first.decision.decision_id, **outcome
        )
        assert isinstance(one, a.OutcomeResult)
        assert isinstance(two, a.OutcomeResult)
        assert (one.replayed, two.replayed) == (False, True)
        assert two.model_dump(exclude={"replayed"}) == one.model_dump(exclude={"replayed"})

    async def test_episodes_model_and_stats(self, robot: a.AsyncClient) -> None:
        for n in range(3):
            await play(robot, "lin", f"e{n}", n)
        page = await robot.list_episodes("lin", limit=2)
        assert [e.event_id for e in page.items] == ["e2", "e1"]
        assert page.next_cursor is not None
        listed = [e async for e in robot.iter_episodes("lin", page_size=2)]
        assert [e.event_id for e in listed] == ["e2", "e1", "e0"]
        assert all(e.status == "closed" for e in listed)
        model = await robot.get_model("lin")
        assert model.algorithm == "dts-routine"
        assert model.episodes == 3
        assert model.version > 0
        only = await robot.get_model("lin", time_slot="afternoon", situation="stretching")
        assert [(c.time_slot, c.situation) for c in only.contexts] == [("afternoon", "stretching")]
        beliefs = only.contexts[0].states[0].actions
        assert {b.action.kind for b in beliefs} == {"initiate", "pass"}
        stats = await robot.get_stats("lin")
        assert stats.episodes == 3
        assert len(stats.cumulative_reward) >= 3
        assert (await robot.get_stats("lin", last=1)).episodes == 1
        empty = await robot.get_stats((await robot.put_user("new")).user_id)
        assert empty.interaction_rate is None

    async def test_mission_and_probes(self, robot: a.AsyncClient) -> None:
        mission = await robot.mission()
        assert mission.name == "office"
        assert "stretching" in mission.situations
        assert {s.name for s in mission.services} >= {"ProvideDrink"}
        assert mission.rewards["accepted_service"] == 5.0
        assert await robot.health()
        assert await robot.ready()

    async def test_admin_model_actions(self, robot: a.AsyncClient, admin: a.AsyncClient) -> None:
        await play(robot, "lin", "e1")
        before = await robot.get_model("lin")
        document = await admin.export_model("lin")
        assert document["algorithm"] == "dts-routine"
        await admin.reset_model("lin")
        reset = await robot.get_model("lin")
        assert reset.version > before.version
        imported = await admin.import_model("lin", document)
        assert isinstance(imported, a.ModelView)
        assert imported.user_id == "lin"
        assert imported.algorithm == "dts-routine"
        await play(robot, "mo", "e2")
        moved = await admin.import_model("mo", document)
        assert moved.user_id == "mo"


class TestErrors:
    async def test_401_a_bad_key(self, switch: SwitchTransport) -> None:
        async with a.AsyncClient(BASE_URL, "att_not-a-key", transport=switch) as client:
            with pytest.raises(a.AuthenticationError) as caught:
                await client.get_user("lin")
        assert caught.value.status_code == 401
        assert caught.value.detail

    async def test_403_admin_only(self, robot: a.AsyncClient) -> None:
        await robot.put_user("lin")
        for call in (robot.delete_user("lin"), robot.reset_model("lin"), robot.export_model("lin")):
            with pytest.raises(a.PermissionDeniedError) as caught:
                await call
            assert caught.value.error == "Forbidden"

    async def test_404_absent_or_of_another_fleet(
        self, robot: a.AsyncClient, app: FastAPI, make_key: MakeKey
    ) -> None:
        with pytest.raises(a.NotFoundError):
            await robot.get_user("nobody")
        with pytest.raises(a.NotFoundError):
            await robot.get_episode("ep_nothing")
        with pytest.raises(a.NotFoundError):
            await robot.report_outcome("ep_nothing", decision_id="dec_x", response="accepted")
        await robot.put_user("lin")
        other = a.AsyncClient(
            BASE_URL, make_key("robot", "other"), transport=httpx.ASGITransport(app=app)
        )
        async with other:
            with pytest.raises(a.NotFoundError) as caught:
                await other.get_user("lin")
        assert caught.value.error == "NotFound"

    async def test_409_conflicts(self, robot: a.AsyncClient) -> None:
        started = await robot.start_episode(
            "lin", event_id="e1", occurred_at=EVENT_TIME, situation="arriving"
        )
        with pytest.raises(a.ConflictError) as caught:
            await robot.start_episode(
                "lin", event_id="e1", occurred_at=EVENT_TIME, situation="working"
            )
        assert caught.value.error == "Conflict"
        with pytest.raises(a.ConflictError):
            await robot.report_outcome(
                started.episode_id, decision_id="dec_not_current", response="accepted"
            )
        with pytest.raises(a.ConflictError):  # nothing answered yet
            await robot.send_feedback(started.episode_id, feedback_id="f", feedback="positive")

    async def test_413_too_big(self, robot: a.AsyncClient) -> None:
        with pytest.raises(a.PayloadTooLargeError) as caught:
            await robot.put_user("lin", display_name="x" * 70_000)
        assert caught.value.status_code == 413

    async def test_422_invalid(self, robot: a.AsyncClient, admin: a.AsyncClient) -> None:
        await robot.put_user("lin")
        with pytest.raises(a.UnprocessableEntityError) as caught:
            await robot.start_episode(
                "lin", event_id="e1", occurred_at=EVENT_TIME, situation="dancing"
            )
        assert "stretching" in caught.value.detail
        with pytest.raises(a.UnprocessableEntityError) as bad_id:
            await robot.start_episode(
                "lin", event_id="bad id!", occurred_at=EVENT_TIME, situation="busy"
            )
        assert bad_id.value.fields
        with pytest.raises(a.UnprocessableEntityError):
            await admin.put_user("lin", learner={"algorithm": "no-such-learner"})
        with pytest.raises(a.UnprocessableEntityError):
            await admin.import_model("lin", {"format": "something else"})
        started = await robot.start_episode(
            "lin", event_id="e2", occurred_at=EVENT_TIME, situation="stretching"
        )
        assert started.decision is not None
        wrong: a.OutcomeResponse = (
            "answered" if started.decision.action.kind in ("initiate", "pass") else "none"
        )
        with pytest.raises(a.UnprocessableEntityError) as caught:
            await robot.report_outcome(
                started.episode_id, decision_id=started.decision.decision_id, response=wrong
            )
        assert "must be one of" in caught.value.detail


class TestOutbox:
    async def test_reports_made_offline_arrive_in_order(
        self, switch: SwitchTransport, make_key: MakeKey, tmp_path: Path
    ) -> None:
        client = fast(
            a.AsyncClient(
                BASE_URL,
                make_key("robot"),
                transport=switch,
                max_retries=1,
                outbox=tmp_path / "outbox.db",
            )
        )
        async with client:
            first = await client.start_episode(
                "ana", event_id="e1", occurred_at=EVENT_TIME, situation="stretching"
            )
            second = await client.start_episode(
                "ben", event_id="e2", occurred_at=EVENT_TIME, situation="stretching"
            )
            closed, _ = await play(client, "cy", "e3")
            assert first.decision is not None
            assert second.decision is not None
            switch.down = True
            made = [
                await client.report_outcome(
                    second.episode_id,
                    decision_id=second.decision.decision_id,
                    **cooperative(second.decision.action),
                ),
                await client.send_feedback(
                    closed.episode_id, feedback_id="fb-3", feedback="negative"
                ),
                await client.report_outcome(
                    first.episode_id,
                    decision_id=first.decision.decision_id,
                    response="bogus-for-this-decision",
                ),
                await client.report_outcome(
                    first.episode_id,
                    decision_id=first.decision.decision_id,
                    **cooperative(first.decision.action),
                ),
            ]
            assert [m.position for m in made if isinstance(m, a.Queued)] == [1, 2, 3, 4]
            with pytest.raises(a.APIConnectionError):  # no new decisions while offline
                await client.start_episode(
                    "ana", event_id="e4", occurred_at=EVENT_TIME, situation="busy"
                )
            switch.down = False
            report = await client.flush()
            assert report.remaining == 0
            assert [p.key for p, _ in report.delivered] == [
                second.decision.decision_id,
                "fb-3",
                first.decision.decision_id,
            ]
            [(refused, why)] = report.rejected
            assert refused.body["response"] == "bogus-for-this-decision"
            assert why.status_code == 422
            after_second = report.delivered[0][1]
            assert isinstance(after_second, a.OutcomeResult)
            assert after_second.episode.episode_id == second.episode_id
            # the history has them in the order the robot made them
            times = []
            for episode_id, key in (
                (second.episode_id, second.decision.decision_id),
                (closed.episode_id, "fb-3"),
                (first.episode_id, first.decision.decision_id),
            ):
                trace = await client.get_episode(episode_id)
                times += [d.answered_at for d in trace.decisions if d.decision_id == key]
                times += [f.received_at for f in trace.feedback if f.feedback_id == key]
            assert len(times) == 3
            assert times == sorted(times)
            assert await client.pending() == []


class TestSyncClient:
    def test_an_episode_and_errors(self, sync_robot: a.Client) -> None:
        started = sync_robot.start_episode(
            "lin", event_id="s1", occurred_at=EVENT_TIME, situation="stretching"
        )
        decision = started.decision
        n = 0
        while decision is not None:
            result = sync_robot.report_outcome(
                started.episode_id,
                decision_id=decision.decision_id,
                **cooperative(decision.action, n),
            )
            assert isinstance(result, a.OutcomeResult)
            decision = result.decision
        trace = sync_robot.get_episode(started.episode_id)
        assert trace.status == "closed"
        assert [e.episode_id for e in sync_robot.iter_episodes("lin")] == [started.episode_id]
        assert [u.user_id for u in sync_robot.iter_users()] == ["lin"]
        assert sync_robot.get_stats("lin").episodes == 1
        assert sync_robot.mission().name == "office"
        with pytest.raises(a.NotFoundError):
            sync_robot.get_user("nobody")
        with pytest.raises(a.PermissionDeniedError):
            sync_robot.delete_user("lin")

    def test_the_outbox(self, portal: PortalTransport, make_key: MakeKey, tmp_path: Path) -> None:
        path = tmp_path / "outbox.db"
        key = make_key("robot")
        with fast(a.Client(BASE_URL, key, transport=portal, max_retries=1, outbox=path)) as robot:
            started = robot.start_episode(
                "lin", event_id="s1", occurred_at=EVENT_TIME, situation="stretching"
            )
            assert started.decision is not None
            portal.down = True
            queued = robot.report_outcome(
                started.episode_id,
                decision_id=started.decision.decision_id,
                **cooperative(started.decision.action),
            )
            assert isinstance(queued, a.Queued)
        portal.down = False
        with a.Client(BASE_URL, key, transport=portal, outbox=path) as again:  # restarted
            assert [p.key for p in again.pending()] == [started.decision.decision_id]
            trace = again.get_episode(started.episode_id)  # delivers first
            assert trace.decisions[0].answered_at is not None
            [(entry, result)] = again.flush().delivered
            assert entry.key == started.decision.decision_id
            assert isinstance(result, a.OutcomeResult)
