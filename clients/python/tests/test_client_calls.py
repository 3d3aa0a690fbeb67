"""Each method sends the request of the contract and reads the answer into its model."""

from __future__ import annotations

import datetime as dt
import json
import re
from typing import Any

import attune_client as a
import httpx
import pydantic
import pytest
from attune_client_fakes import KEY, MakeAsyncClient, MakeClient, decision

USER = {
    "user_id": "lin",
    "fleet": "default",
    "display_name": "Mrs. Lin",
    "learner": {"algorithm": "hri", "params": {"tau": 0.01}},
    "created_at": "2026-11-22T03:50:31.603058Z",
    "episodes": 2,
}
STARTED = {
    "episode_id": "ep_1",
    "user_id": "lin",
    "status": "open",
    "context": {"time_slot": "afternoon", "situation": "stretching"},
    "state": "OBSERVE",
    "total_reward": 0.0,
    "decision": decision("dec_1"),
}
SUMMARY = {
    "episode_id": "ep_1",
    "user_id": "lin",
    "event_id": "e1",
    "robot_id": None,
    "status": "closed",
    "context": {"time_slot": "afternoon", "situation": "stretching"},
    "initiator": "robot",
    "interaction_class": "I2",
    "total_reward": 6.0,
    "state": "END",
    "occurred_at": "2026-11-22T07:10:00Z",
    "index": 1,
}
TRACE = {
    **SUMMARY,
    "decisions": [
        {
            "decision_id": "dec_1",
            "state": "OBSERVE",
            "action": {"kind": "initiate"},
            "probabilities": [
                {"action": {"kind": "initiate"}, "p": 0.5},
                {"action": {"kind": "pass"}, "p": 0.5},
            ],
            "chain": [],
            "response": "accepted",
            "service": None,
            "detail": None,
            "feedback": None,
            "reward": 1.0,
            "decided_at": "2026-11-22T03:50:31.634953Z",
            "answered_at": "2026-11-22T03:50:32.1Z",
        }
    ],
    "feedback": [
        {
            "feedback_id": "fb1",
            "feedback": "positive",
            "reward": 1.0,
            "received_at": "2026-11-22T03:50:33Z",
        }
    ],
}
MODEL = {
    "user_id": "lin",
    "algorithm": "qlearning",
    "params": {"alpha": 0.1},
    "version": 3,
    "episodes": 1,
    "contexts": [
        {
            "time_slot": "afternoon",
            "situation": "stretching",
            "states": [
                {
                    "state": "OBSERVE",
                    "service": None,
                    "detail": None,
                    "actions": [
                        {
                            "action": {"kind": "initiate"},
                            "q": 3.1,
                            "visits": 12,
                            "kept_visits": None,
                            "since_last": 2,
                            "measure": None,
                            "p": 0.83,
                        }
                    ],
                }
            ],
        }
    ],
}
STATS = {
    "episodes": 0,
    "missions": 0,
    "interaction_rate": None,
    "success_rate": None,
    "queries_per_mission": None,
    "total_reward": 0.0,
    "cumulative_reward": [0.0],
}
MISSION = {
    "name": "office",
    "situations": ["arriving", "working", "stretching", "busy"],
    "time_slots": [{"name": "morning", "start": "06:00", "end": "11:00"}],
    "services": [{"name": "ProvideDrink", "details": ["tea", "coffee", "water"]}],
    "rewards": {"positive": 1.0, "accepted_service": 5.0, "negative": -2.0, "query": -0.5},
    "unavailable_situations": ["busy"],
    "gamma": 0.9,
}
FLEET_MISSION = {
    **MISSION,
    "fleet": "care",
    "version": 3,
    "fingerprint": "sha256:0123456789abcdef0123456789abcdef",
}
CHANGED = {
    "fleet": "care",
    "version": 3,
    "previous_version": 2,
    "fingerprint": "sha256:0123456789abcdef0123456789abcdef",
    "changed": True,
    "users_moved": 4,
    "episodes_interrupted": 1,
    "diff": {"kept": {"situations": ["arriving"]}, "added": {}, "removed": {}, "renamed": {}},
}

CORRECTION = {
    "correction_id": "c-1",
    "kind": "prefers",
    "time_slot": "morning",
    "situation": "arriving",
    "service": "ProvideDrink",
    "detail": "coffee",
    "note": "Her daughter says so.",
    "author": "key_5aed0c02dbc8f75a",
    "created_at": "2026-11-30T09:12:03Z",
    "status": "in_force",
    "overridden_at": None,
    "lifted_at": None,
    "lifted_by": None,
    "model_version": 42,
}
PROFILE = {
    "user_id": "chen",
    "display_name": "Mrs. Chen",
    "episodes": 16,
    "open_episodes": 1,
    "utc_offset": 480,
    "contexts": [
        {
            "time_slot": "afternoon",
            "situation": "stretching",
            "episodes": 9,
            "open_episodes": 1,
            "wants": {"service": "ProvideDrink", "detail": "tea"},
            "certainty": "confident",
            "source": "person",
            "evidence": {
                "accepted": 7,
                "refused": 1,
                "asked_for": 1,
                "answered": 0,
                "last_seen": "2026-11-22T15:10:00+08:00",
                "support": 7,
                "recent": 8,
            },
            "robot_will": {
                "action": "offer",
                "service": "ProvideDrink",
                "detail": "tea",
                "asks_first": False,
                "probability": 0.97,
            },
            "summary": "In the afternoon, while stretching, Mrs. Chen usually wants tea.",
            "changed": {
                "at": "2026-11-21T15:10:00+08:00",
                "episode": 7,
                "before": {"service": "ProvideDrink", "detail": "coffee"},
                "now": {"service": "ProvideDrink", "detail": "tea"},
                "by": "person",
                "overrides": None,
            },
            "corrections": [],
        }
    ],
    "corrections": [CORRECTION],
}


CHANGE = {
    "change_id": "7",
    "user_id": "lin",
    "fleet": "default",
    "source": "routine",
    "time_slot": "afternoon",
    "situation": "stretching",
    "since": {"episode": 41, "at": "2026-12-03T15:10:00+08:00"},
    "decided": {"episode": 42, "at": "2026-12-04T07:12:09Z"},
    "before": {"service": "ProvideDrink", "detail": "tea"},
    "now": {"service": "ProvideDrink", "detail": "coffee"},
    "evidence": [
        {
            "episode": 41,
            "chose": None,
            "turned_down": [{"service": "ProvideDrink", "detail": "tea"}],
            "turned_down_offer": False,
        },
        {
            "episode": 42,
            "chose": {"service": "ProvideDrink", "detail": "coffee"},
            "turned_down": [],
            "turned_down_offer": False,
        },
    ],
    "summary": "Since 3 December, Mrs. Lin wants coffee instead of tea in the afternoon, "
    "while stretching.",
}


class Recorder:
    """Answers ``(status, body, headers)`` for every request and keeps the requests."""

    def __init__(
        self, status: int = 200, body: Any = None, headers: dict[str, str] | None = None
    ) -> None:
        self.status, self.body, self.headers = status, body, headers or {}
        self.requests: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        if self.body is None:
            return httpx.Response(self.status, headers=self.headers)
        return httpx.Response(self.status, json=self.body, headers=self.headers)

    @property
    def last(self) -> httpx.Request:
        return self.requests[-1]

    def sent(self) -> Any:
        return json.loads(self.last.content)


class TestRequests:
    def test_every_call_sends_the_key(self, make_client: MakeClient) -> None:
        rec = Recorder(body=USER)
        make_client(rec).get_user("lin")
        assert rec.last.headers["Authorization"] == f"Bearer {KEY}"
        assert rec.last.headers["User-Agent"].startswith("attune-client/")

    def test_no_key_no_authorization_header(self) -> None:
        rec = Recorder(body={"status": "ok"})
        with a.Client("http://attune.test", "", transport=httpx.MockTransport(rec)) as client:
            assert client.health()
        assert "Authorization" not in rec.last.headers

    def test_probes_never_send_the_key(self, make_client: MakeClient) -> None:
        rec = Recorder(body={"status": "ok"})
        make_client(rec).health()
        assert "Authorization" not in rec.last.headers

    def test_extra_headers(self, make_client: MakeClient) -> None:
        rec = Recorder(body=USER)
        make_client(rec, headers={"X-Robot": "robot7"}).get_user("lin")
        assert rec.last.headers["X-Robot"] == "robot7"

    def test_put_user(self, make_client: MakeClient) -> None:
        rec = Recorder(201, USER)
        user = make_client(rec).put_user(
            "lin",
            display_name="Mrs. Lin",
            learner={"algorithm": "hri", "params": {"tau": 0.01}},
            reset_model=True,
        )
        assert rec.last.method == "PUT"
        assert rec.last.url.path == "/v1/users/lin"
        assert rec.last.url.params["reset_model"] == "true"
        assert rec.sent() == {
            "display_name": "Mrs. Lin",
            "learner": {"algorithm": "hri", "params": {"tau": 0.01}},
        }
        assert user.learner == a.LearnerSpec(algorithm="hri", params={"tau": 0.01})
        assert user.created_at == dt.datetime(2026, 11, 22, 3, 50, 31, 603058, tzinfo=dt.UTC)

    def test_put_user_with_nothing_to_change(self, make_client: MakeClient) -> None:
        rec = Recorder(200, USER)
        make_client(rec).put_user("lin", learner=a.LearnerSpec(algorithm="rmax"))
        assert "reset_model" not in rec.last.url.params
        assert rec.sent() == {"learner": {"algorithm": "rmax", "params": {}}}

    def test_ids_are_escaped_in_paths(self, make_client: MakeClient) -> None:
        rec = Recorder(200, USER)
        client = make_client(rec)
        client.get_user("a/b c")
        assert rec.last.url.raw_path == b"/v1/users/a%2Fb%20c"
        client.get_user("..")
        assert rec.last.url.raw_path == b"/v1/users/%2E%2E"

    def test_list_and_iterate_users(self, make_client: MakeClient) -> None:
        pages = {
            None: {"items": [USER], "next_cursor": "lin"},
            "lin": {"items": [{**USER, "user_id": "mo"}], "next_cursor": None},
        }
        seen: list[httpx.Request] = []

        def handler(request: httpx.Request) -> httpx.Response:
            seen.append(request)
            return httpx.Response(200, json=pages[request.url.params.get("cursor")])

        client = make_client(handler)
        page = client.list_users(limit=1)
        assert page.next_cursor == "lin"
        assert seen[0].url.params["limit"] == "1"
        assert [u.user_id for u in client.iter_users(page_size=1)] == ["lin", "mo"]
        assert seen[-1].url.params["cursor"] == "lin"

    def test_start_episode(self, make_client: MakeClient) -> None:
        rec = Recorder(201, STARTED)
        when = dt.datetime(2026, 11, 22, 15, 10, tzinfo=dt.timezone(dt.timedelta(hours=8)))
        started = make_client(rec).start_episode(
            "lin",
            event_id="robot7-000123",
            occurred_at=when,
            situation="stretching",
            initiator="human",
            request=a.ServiceRequest(service="ProvideDrink", detail="tea"),
            robot_id="robot7",
        )
        assert rec.last.method == "POST"
        assert rec.last.url.path == "/v1/users/lin/episodes"
        assert rec.last.headers["Content-Type"] == "application/json"
        assert rec.sent() == {
            "event_id": "robot7-000123",
            "occurred_at": "2026-11-22T15:10:00+08:00",
            "situation": "stretching",
            "initiator": "human",
            "request": {"service": "ProvideDrink", "detail": "tea"},
            "robot_id": "robot7",
        }
        assert not started.replayed
        assert started.decision is not None
        assert started.decision.action.kind == "initiate"
        assert started.context.time_slot == "afternoon"

    def test_start_episode_takes_text_times_and_mapping_requests(
        self, make_client: MakeClient
    ) -> None:
        rec = Recorder(201, STARTED)
        make_client(rec).start_episode(
            "lin",
            event_id="e",
            situation="busy",
            occurred_at="2026-11-22T15:10:00+08:00",
            request={"service": "ProvideDrink"},
        )
        sent = rec.sent()
        assert sent["occurred_at"] == "2026-11-22T15:10:00+08:00"
        assert sent["request"] == {"service": "ProvideDrink", "detail": None}
        assert sent["initiator"] == "robot"
        assert sent["robot_id"] is None

    def test_a_naive_time_is_refused_before_sending(self, make_client: MakeClient) -> None:
        rec = Recorder(201, STARTED)
        with pytest.raises(ValueError, match="time zone"):
            make_client(rec).start_episode(
                "lin", event_id="e", situation="busy", occurred_at=dt.datetime(2026, 11, 22, 15, 10)
            )
        assert rec.requests == []

    def test_a_replay_says_so(self, make_client: MakeClient) -> None:
        rec = Recorder(200, STARTED, {"Idempotent-Replay": "true"})
        started = make_client(rec).start_episode(
            "lin", event_id="e", situation="busy", occurred_at="2026-11-22T15:10:00+08:00"
        )
        assert started.replayed

    def test_report_outcome(self, make_client: MakeClient) -> None:
        answer = {
            "reward": -0.5,
            "episode": {
                "episode_id": "ep_1",
                "status": "closed",
                "state": "END",
                "total_reward": 0.5,
            },
            "decision": None,
        }
        rec = Recorder(200, answer)
        result = make_client(rec).report_outcome(
            "ep_1", decision_id="dec_1", response="answered", service="ProvideDrink"
        )
        assert rec.last.url.path == "/v1/episodes/ep_1/outcomes"
        assert rec.sent() == {
            "decision_id": "dec_1",
            "response": "answered",
            "service": "ProvideDrink",
        }
        assert isinstance(result, a.OutcomeResult)
        assert result.decision is None
        assert result.episode.status == "closed"
        assert not result.replayed

    def test_send_feedback(self, make_client: MakeClient) -> None:
        answer = {
            "reward": 1.0,
            "episode": {
                "episode_id": "ep_1",
                "status": "closed",
                "state": "END",
                "total_reward": 7.0,
            },
        }
        rec = Recorder(200, answer, {"Idempotent-Replay": "true"})
        result = make_client(rec).send_feedback("ep_1", feedback_id="fb1", feedback="positive")
        assert rec.last.url.path == "/v1/episodes/ep_1/feedback"
        assert rec.sent() == {"feedback_id": "fb1", "feedback": "positive"}
        assert isinstance(result, a.FeedbackResult)
        assert result.replayed

    def test_get_episode(self, make_client: MakeClient) -> None:
        rec = Recorder(200, TRACE)
        trace = make_client(rec).get_episode("ep_1")
        assert rec.last.url.path == "/v1/episodes/ep_1"
        assert trace.decisions[0].answered_at is not None
        assert trace.feedback[0].feedback_id == "fb1"
        assert trace.interaction_class == "I2"

    def test_list_and_iterate_episodes(self, make_client: MakeClient) -> None:
        rec = Recorder(200, {"items": [SUMMARY], "next_cursor": None})
        client = make_client(rec)
        page = client.list_episodes("lin", limit=5, cursor="9")
        assert rec.last.url.path == "/v1/users/lin/episodes"
        assert dict(rec.last.url.params) == {"limit": "5", "cursor": "9"}
        assert page.items[0].index == 1
        assert [e.episode_id for e in client.iter_episodes("lin")] == ["ep_1"]

    def test_get_model(self, make_client: MakeClient) -> None:
        rec = Recorder(200, MODEL)
        model = make_client(rec).get_model("lin", situation="stretching")
        assert rec.last.url.path == "/v1/users/lin/model"
        assert dict(rec.last.url.params) == {"situation": "stretching"}
        belief = model.contexts[0].states[0].actions[0]
        assert belief.measure is None
        assert belief.kept_visits is None
        assert belief.q == 3.1

    def test_get_stats(self, make_client: MakeClient) -> None:
        rec = Recorder(200, STATS)
        stats = make_client(rec).get_stats("lin", last=100)
        assert dict(rec.last.url.params) == {"last": "100"}
        assert stats.success_rate is None

    def test_admin_calls(self, make_client: MakeClient) -> None:
        rec = Recorder(204)
        client = make_client(rec)
        client.reset_model("lin")
        assert (rec.last.method, rec.last.url.path) == ("DELETE", "/v1/users/lin/model")
        client.delete_user("lin")
        assert (rec.last.method, rec.last.url.path) == ("DELETE", "/v1/users/lin")
        rec.status, rec.body = 200, {"format": "attune.learner-state", "arrays": {}}
        document = client.export_model("lin")
        assert rec.last.url.path == "/v1/users/lin/model/export"
        rec.body = MODEL
        model = client.import_model("lin", document)
        assert (rec.last.method, rec.last.url.path) == ("PUT", "/v1/users/lin/model")
        assert rec.sent() == document
        assert model.version == 3

    def test_reset_model_keeps_or_drops_corrections(self, make_client: MakeClient) -> None:
        rec = Recorder(204)
        client = make_client(rec)
        client.reset_model("lin")
        assert "corrections" not in rec.last.url.params
        client.reset_model("lin", drop_corrections=True)
        assert (rec.last.method, rec.last.url.path) == ("DELETE", "/v1/users/lin/model")
        assert dict(rec.last.url.params) == {"corrections": "drop"}

    def test_mission(self, make_client: MakeClient) -> None:
        mission = make_client(Recorder(200, MISSION)).mission()
        assert mission.services[0].details == ["tea", "coffee", "water"]
        assert mission.unavailable_situations == ["busy"]
        assert mission.version is None  # a service older than versioned missions


class TestMissions:
    def test_the_fleets_mission_with_its_version(self, make_client: MakeClient) -> None:
        rec = Recorder(200, FLEET_MISSION)
        client = make_client(rec)
        mission = client.mission()
        assert (rec.last.method, rec.last.url.path) == ("GET", "/v1/mission")
        assert "fleet" not in rec.last.url.params
        assert isinstance(mission, a.FleetMission)
        assert isinstance(mission, a.Mission)  # what mission() returned before
        assert (mission.fleet, mission.version, mission.fingerprint) == (
            "care",
            3,
            "sha256:0123456789abcdef0123456789abcdef",
        )
        assert mission.document() == MISSION  # the mission alone, as set_mission takes it
        client.mission(fleet="care")
        assert rec.last.url.params["fleet"] == "care"

    def test_missions_lists_the_versions(self, make_client: MakeClient) -> None:
        rec = Recorder(
            200,
            {
                "fleet": "care",
                "current_version": 2,
                "items": [
                    {
                        "version": 2,
                        "name": "office",
                        "fingerprint": "sha256:b",
                        "created_at": "2026-12-01T08:00:00Z",
                        "change_id": "menu-2",
                        "renames": {"details": {"cha": "tea"}},
                        "set_by": "key_1",
                        "stored": True,
                        "mission": MISSION,
                    },
                    {
                        "version": 1,
                        "name": "office",
                        "fingerprint": "sha256:a",
                        "created_at": None,
                        "change_id": None,
                        "renames": None,
                        "set_by": None,
                        "stored": False,
                        "mission": MISSION,
                    },
                ],
            },
        )
        versions = make_client(rec).missions("care")
        assert rec.last.url.path == "/v1/admin/fleets/care/missions"
        assert versions.current_version == 2
        newest, first = versions.items
        assert newest.created_at == dt.datetime(2026, 12, 1, 8, tzinfo=dt.UTC)
        assert newest.renames == {"details": {"cha": "tea"}}
        assert newest.mission.services[0].details == ["tea", "coffee", "water"]
        assert not first.stored
        assert first.created_at is None

    def test_set_mission(self, make_client: MakeClient) -> None:
        rec = Recorder(200, CHANGED)
        client = make_client(rec)
        changed = client.set_mission(
            "care", MISSION, change_id="menu-3", renames={"details": {"cha": "tea"}}
        )
        assert (rec.last.method, rec.last.url.path) == ("PUT", "/v1/admin/fleets/care/mission")
        assert rec.sent() == {
            "change_id": "menu-3",
            "mission": MISSION,
            "renames": {"details": {"cha": "tea"}},
        }
        assert changed.changed
        assert (changed.version, changed.previous_version) == (3, 2)
        assert changed.users_moved == 4
        assert changed.episodes_interrupted == 1
        assert not changed.replayed
        rec.headers = {"Idempotent-Replay": "true"}
        assert client.set_mission("care", MISSION, change_id="menu-3").replayed

    def test_the_change_id_is_derived_from_the_content(self, make_client: MakeClient) -> None:
        rec = Recorder(200, CHANGED)
        client = make_client(rec)
        client.set_mission("care", MISSION)
        first = rec.sent()
        assert "renames" not in first
        assert first["change_id"].startswith("mission-")
        assert re.fullmatch(r"[A-Za-z0-9._:-]{1,128}", first["change_id"])
        # the same mission, however it is given, is the same change: retries are one change
        fleet_mission = a.FleetMission.model_validate(FLEET_MISSION)
        client.set_mission("care", fleet_mission)
        assert rec.sent() == first  # fleet, version and fingerprint are left out
        client.set_mission("care", FLEET_MISSION)
        assert rec.sent() == first
        assert a.mission_change_id(MISSION) == first["change_id"]
        # another mission, or other renames, is another change
        other = {**MISSION, "situations": ["arriving", "working"]}
        assert a.mission_change_id(other) != first["change_id"]
        renamed = a.mission_change_id(MISSION, a.MissionRenames(details={"cha": "tea"}))
        assert renamed != first["change_id"]
        assert renamed == a.mission_change_id(MISSION, {"details": {"cha": "tea"}})
        assert a.mission_change_id(MISSION, {}) == first["change_id"]  # no renames at all

    @pytest.mark.parametrize(
        ("status", "cls"),
        [(403, a.PermissionDeniedError), (409, a.ConflictError), (422, a.UnprocessableEntityError)],
    )
    def test_errors(
        self, make_client: MakeClient, status: int, cls: type[a.APIStatusError], sleeps: list[float]
    ) -> None:
        rec = Recorder(status, {"error": "Nope", "detail": "mission: situations: bad."})
        with pytest.raises(cls) as caught:
            make_client(rec).set_mission("care", MISSION)
        assert caught.value.detail == "mission: situations: bad."
        assert len(rec.requests) == 1
        assert sleeps == []

    def test_a_change_is_retried_as_the_same_change(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        rec = Recorder(503, {"error": "ServiceUnavailable", "detail": "busy"})
        answers = iter([503, 200])

        def handler(request: httpx.Request) -> httpx.Response:
            rec.status = next(answers)
            rec.body = CHANGED if rec.status == 200 else rec.body
            return rec(request)

        changed = make_client(handler).set_mission("care", MISSION)
        assert changed.version == 3
        assert len(sleeps) == 1
        bodies = [json.loads(r.content) for r in rec.requests]
        assert bodies[0] == bodies[1]

    def test_a_mission_is_a_mission_or_a_mapping(self, make_client: MakeClient) -> None:
        with pytest.raises(TypeError, match="mission"):
            make_client(Recorder(200, CHANGED)).set_mission("care", ["not", "a", "mission"])  # type: ignore[arg-type]

    @pytest.mark.anyio
    async def test_the_async_client(self, make_async_client: MakeAsyncClient) -> None:
        rec = Recorder(200, FLEET_MISSION)
        client = make_async_client(rec)
        mission = await client.mission(fleet="care")
        assert mission.version == 3
        rec.body = {"fleet": "care", "current_version": 1, "items": []}
        assert (await client.missions("care")).current_version == 1
        rec.body = CHANGED
        changed = await client.set_mission("care", mission)
        assert changed.users_moved == 4
        assert rec.sent()["change_id"] == a.mission_change_id(MISSION)

    def test_health_and_ready(self, make_client: MakeClient) -> None:
        rec = Recorder(200, {"status": "ok"})
        client = make_client(rec)
        assert client.health()
        assert rec.last.url.path == "/healthz"
        assert client.ready()
        rec.status = 503
        assert not client.ready()
        assert len(rec.requests) == 3  # no retries for probes

    def test_health_is_false_when_nothing_answers(
        self, make_client: MakeClient, sleeps: list[float]
    ) -> None:
        def handler(request: httpx.Request) -> httpx.Response:
            raise httpx.ConnectError("refused", request=request)

        client = make_client(handler)
        assert not client.health()
        assert not client.ready()
        assert sleeps == []


class TestCorrections:
    def test_get_profile(self, make_client: MakeClient) -> None:
        rec = Recorder(200, PROFILE)
        profile = make_client(rec).get_profile("chen")
        assert (rec.last.method, rec.last.url.path) == ("GET", "/v1/users/chen/profile")
        assert isinstance(profile, a.Profile)
        assert profile.utc_offset == 480
        cell = profile.context("afternoon", "stretching")
        assert cell.wants == a.Wanted(service="ProvideDrink", detail="tea")
        assert cell.certainty == "confident"
        assert cell.evidence.last_seen == dt.datetime(
            2026, 11, 22, 15, 10, tzinfo=dt.timezone(dt.timedelta(hours=8))
        )
        assert cell.robot_will.probability == 0.97
        assert cell.changed is not None
        assert cell.changed.before == a.Wanted(service="ProvideDrink", detail="coffee")
        assert cell.changed.overrides is None
        assert [c.correction_id for c in profile.corrections] == ["c-1"]
        with pytest.raises(KeyError):
            profile.context("morning", "stretching")

    def test_add_correction(self, make_client: MakeClient) -> None:
        rec = Recorder(201, CORRECTION)
        client = make_client(rec)
        made = client.add_correction(
            "chen",
            correction_id="c-1",
            time_slot="morning",
            situation="arriving",
            kind="prefers",
            service="ProvideDrink",
            detail="coffee",
            note="Her daughter says so.",
        )
        assert (rec.last.method, rec.last.url.path) == ("POST", "/v1/users/chen/corrections")
        assert rec.sent() == {
            "correction_id": "c-1",
            "time_slot": "morning",
            "situation": "arriving",
            "kind": "prefers",
            "service": "ProvideDrink",
            "detail": "coffee",
            "note": "Her daughter says so.",
        }
        assert isinstance(made, a.Correction)
        assert (made.status, made.model_version, made.replayed) == ("in_force", 42, False)
        rec.status, rec.headers = 200, {"Idempotent-Replay": "true"}
        again = client.add_correction(
            "chen",
            correction_id="c-1",
            time_slot="morning",
            situation="arriving",
            kind="prefers",
            service="ProvideDrink",
            detail="coffee",
            note="Her daughter says so.",
        )
        assert again.replayed
        assert again.model_dump(exclude={"replayed"}) == made.model_dump(exclude={"replayed"})

    def test_a_quiet_correction_sends_no_service(self, make_client: MakeClient) -> None:
        rec = Recorder(
            201, {**CORRECTION, "kind": "quiet", "service": None, "detail": None, "note": None}
        )
        make_client(rec).add_correction(
            "chen", correction_id="hush", time_slot="morning", situation="arriving", kind="quiet"
        )
        assert rec.sent() == {
            "correction_id": "hush",
            "time_slot": "morning",
            "situation": "arriving",
            "kind": "quiet",
        }

    def test_list_and_lift(self, make_client: MakeClient) -> None:
        rec = Recorder(
            200,
            {
                "items": [
                    CORRECTION,
                    {
                        **CORRECTION,
                        "correction_id": "c/2",
                        "status": "lifted",
                        "lifted_at": "2026-11-30T10:00:00Z",
                        "lifted_by": "key_1",
                    },
                ]
            },
        )
        client = make_client(rec)
        listed = client.list_corrections("chen")
        assert (rec.last.method, rec.last.url.path) == ("GET", "/v1/users/chen/corrections")
        assert [c.status for c in listed.items] == ["in_force", "lifted"]
        rec.status, rec.body = 204, None
        client.lift_correction("chen", "c/2")
        assert rec.last.method == "DELETE"
        assert rec.last.url.raw_path == b"/v1/users/chen/corrections/c%2F2"

    @pytest.mark.anyio
    async def test_the_async_client(self, make_async_client: MakeAsyncClient) -> None:
        rec = Recorder(200, PROFILE)
        client = make_async_client(rec)
        assert (await client.get_profile("chen")).episodes == 16
        rec.status, rec.body = 201, CORRECTION
        made = await client.add_correction(
            "chen",
            correction_id="c-1",
            time_slot="morning",
            situation="arriving",
            kind="prefers",
            service="ProvideDrink",
            detail="coffee",
        )
        assert made.correction_id == "c-1"
        assert "note" not in rec.sent()
        rec.status, rec.body = 200, {"items": [CORRECTION]}
        assert len((await client.list_corrections("chen")).items) == 1
        rec.status, rec.body = 204, None
        await client.lift_correction("chen", "c-1")
        assert rec.last.url.path == "/v1/users/chen/corrections/c-1"
        await client.reset_model("chen", drop_corrections=True)
        assert rec.last.url.params["corrections"] == "drop"


class TestChanges:
    def test_list_changes(self, make_client: MakeClient) -> None:
        rec = Recorder(200, {"items": [CHANGE], "next_cursor": "7"})
        page = make_client(rec).list_changes("lin", limit=1, cursor="9")
        assert (rec.last.method, rec.last.url.path) == ("GET", "/v1/users/lin/changes")
        assert dict(rec.last.url.params) == {"limit": "1", "cursor": "9"}
        assert isinstance(page, a.ChangeList)
        assert page.next_cursor == "7"
        (change,) = page.items
        assert isinstance(change, a.ChangeEvent)
        assert change.source == "routine"
        assert (change.time_slot, change.situation) == ("afternoon", "stretching")
        assert change.since == a.ChangeMoment(
            episode=41,
            at=dt.datetime(2026, 12, 3, 15, 10, tzinfo=dt.timezone(dt.timedelta(hours=8))),
        )
        assert change.decided.episode == 42
        assert change.decided.at == dt.datetime(2026, 12, 4, 7, 12, 9, tzinfo=dt.UTC)
        assert change.before == a.Wanted(service="ProvideDrink", detail="tea")
        assert change.now == a.Wanted(service="ProvideDrink", detail="coffee")
        first, second = change.evidence
        assert isinstance(first, a.ChangeEvidence)
        assert first.chose is None
        assert first.turned_down == [a.Wanted(service="ProvideDrink", detail="tea")]
        assert second.chose == change.now
        assert not second.turned_down_offer
        assert change.summary.startswith("Since 3 December")
        assert change.model_dump(mode="json") == CHANGE

    def test_a_change_given_up_has_nothing_now(self) -> None:
        change = a.ChangeEvent.model_validate(
            {**CHANGE, "source": "profile", "now": None, "evidence": []}
        )
        assert change.now is None
        assert change.source == "profile"
        newer = a.ChangeEvent.model_validate({**CHANGE, "source": "staff_note", "mood": "calm"})
        source: str = newer.source  # a source a newer service adds still parses
        assert source == "staff_note"
        assert newer.model_extra == {"mood": "calm"}

    def test_iterate_changes_page_after_page(self, make_client: MakeClient) -> None:
        pages = {
            None: {"items": [CHANGE], "next_cursor": "7"},
            "7": {"items": [{**CHANGE, "change_id": "3"}], "next_cursor": None},
        }
        seen: list[httpx.Request] = []

        def handler(request: httpx.Request) -> httpx.Response:
            seen.append(request)
            return httpx.Response(200, json=pages[request.url.params.get("cursor")])

        client = make_client(handler)
        assert [c.change_id for c in client.iter_changes("a/b", page_size=1)] == ["7", "3"]
        assert [r.url.raw_path.split(b"?")[0] for r in seen] == [b"/v1/users/a%2Fb/changes"] * 2
        assert [dict(r.url.params) for r in seen] == [
            {"limit": "1"},
            {"limit": "1", "cursor": "7"},
        ]

    def test_list_fleet_changes(self, make_client: MakeClient) -> None:
        rec = Recorder(200, {"items": [CHANGE], "next_cursor": None})
        client = make_client(rec)
        page = client.list_fleet_changes("care-north")
        assert (rec.last.method, rec.last.url.path) == (
            "GET",
            "/v1/admin/fleets/care-north/changes",
        )
        assert dict(rec.last.url.params) == {"limit": "50"}
        assert page.items[0].user_id == "lin"
        week_ago = dt.datetime(2026, 11, 27, 8, 0, tzinfo=dt.timezone(dt.timedelta(hours=8)))
        client.list_fleet_changes("care-north", since=week_ago, limit=10, cursor="12")
        assert dict(rec.last.url.params) == {
            "since": "2026-11-27T08:00:00+08:00",
            "limit": "10",
            "cursor": "12",
        }
        assert b"since=2026-11-27T08%3A00%3A00%2B08%3A00" in rec.last.url.query
        client.list_fleet_changes("care-north", since="2026-11-27T00:00:00Z")
        assert rec.last.url.params["since"] == "2026-11-27T00:00:00Z"
        assert [c.change_id for c in client.iter_fleet_changes("care-north", since=week_ago)] == [
            "7"
        ]
        assert dict(rec.last.url.params) == {"since": "2026-11-27T08:00:00+08:00", "limit": "100"}

    def test_a_naive_since_is_refused_before_sending(self, make_client: MakeClient) -> None:
        rec = Recorder(200, {"items": [], "next_cursor": None})
        with pytest.raises(ValueError, match="since needs a time zone"):
            make_client(rec).list_fleet_changes("care", since=dt.datetime(2026, 11, 27))
        assert rec.requests == []

    def test_a_robot_key_is_refused(self, make_client: MakeClient) -> None:
        rec = Recorder(403, {"error": "Forbidden", "detail": "Staff and admin keys only."})
        client = make_client(rec)
        with pytest.raises(a.PermissionDeniedError, match="Staff and admin keys only"):
            client.list_changes("lin")
        with pytest.raises(a.PermissionDeniedError):
            list(client.iter_fleet_changes("default"))
        assert len(rec.requests) == 2  # a 403 is not retried

    @pytest.mark.anyio
    async def test_the_async_client(self, make_async_client: MakeAsyncClient) -> None:
        pages = {
            None: {"items": [CHANGE], "next_cursor": "7"},
            "7": {"items": [{**CHANGE, "change_id": "3"}], "next_cursor": None},
        }
        seen: list[httpx.Request] = []

        def handler(request: httpx.Request) -> httpx.Response:
            seen.append(request)
            return httpx.Response(200, json=pages[request.url.params.get("cursor")])

        client = make_async_client(handler)
        page = await client.list_changes("lin", limit=1)
        assert page.items[0].before == a.Wanted(service="ProvideDrink", detail="tea")
        assert seen[-1].url.path == "/v1/users/lin/changes"
        assert [c.change_id async for c in client.iter_changes("lin", page_size=1)] == ["7", "3"]
        fleet_page = await client.list_fleet_changes("care", since="2026-11-27T00:00:00Z")
        assert fleet_page.next_cursor == "7"
        assert seen[-1].url.path == "/v1/admin/fleets/care/changes"
        assert seen[-1].url.params["since"] == "2026-11-27T00:00:00Z"
        got = [c.change_id async for c in client.iter_fleet_changes("care", page_size=1)]
        assert got == ["7", "3"]
        assert seen[-1].url.params["cursor"] == "7"
        with pytest.raises(ValueError, match="since"):
            await client.list_fleet_changes("care", since=dt.datetime(2026, 11, 27))


class TestModels:
    def test_unknown_fields_are_kept(self) -> None:
        started = a.EpisodeStarted.model_validate({**STARTED, "mood": "sunny"})
        assert started.model_extra == {"mood": "sunny"}
        assert started.mood == "sunny"  # type: ignore[attr-defined]

    def test_unknown_action_kinds_and_states_are_fine(self) -> None:
        odd = decision("dec_9", kind="dance")
        got = a.Decision.model_validate({**odd, "expects": ["applause"]})
        assert got.action.kind == "dance"

    def test_an_interrupted_episode_and_its_mission_version(self) -> None:
        summary = a.EpisodeSummary.model_validate(
            {**SUMMARY, "status": "interrupted", "mission_version": 2}
        )
        assert summary.status == "interrupted"
        assert summary.mission_version == 2
        started = a.EpisodeStarted.model_validate({**STARTED, "mission_version": 1})
        assert started.mission_version == 1
        assert a.EpisodeStarted.model_validate(STARTED).mission_version is None

    def test_models_are_values(self) -> None:
        first = a.Action(kind="perform", service="ProvideDrink", detail="tea")
        assert first == a.Action.model_validate(first.model_dump())
        with pytest.raises(pydantic.ValidationError, match="frozen"):
            first.kind = "pass"


class TestAsyncCalls:
    @pytest.mark.anyio
    async def test_the_same_requests(self, make_async_client: MakeAsyncClient) -> None:
        rec = Recorder(201, STARTED)
        client = make_async_client(rec)
        started = await client.start_episode(
            "lin", event_id="e1", situation="stretching", occurred_at="2026-11-22T15:10:00+08:00"
        )
        assert started.episode_id == "ep_1"
        assert rec.last.url.path == "/v1/users/lin/episodes"
        rec.body = {"items": [SUMMARY], "next_cursor": None}
        assert [e.episode_id async for e in client.iter_episodes("lin")] == ["ep_1"]
        rec.body = {"items": [USER], "next_cursor": None}
        assert [u.user_id async for u in client.iter_users()] == ["lin"]
        rec.body = STATS
        assert (await client.get_stats("lin")).episodes == 0
        rec.status, rec.body = 200, {"status": "ok"}
        assert await client.health()
        assert await client.ready()
