"""Episodes: start, outcomes, feedback, traces and lists, against the contract (docs/api.md).

Decisions are drawn from a seeded stream per user, so a test that needs a given action kind
tries a few fresh users until one's first decision is of that kind (``first``).
"""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.support import people
from tests.support.contract import assert_error
from tests.support.episodes import event, report, start

EXPECTS = {
    "initiate": ["accepted", "rejected", "terminated"],
    "pass": ["human_request", "none"],
    "query_type": ["answered", "terminated"],
    "query_detail": ["answered", "terminated"],
    "perform": ["accepted", "rejected", "terminated"],
}
TEA = {"service": "ProvideDrink", "detail": "tea"}
DECISION_KEYS = {"decision_id", "action", "expects", "probabilities", "chain"}


def check_decision(decision: dict[str, Any]) -> None:
    """Every decision: the contract's fields, expects per kind, a distribution summing to 1."""
    assert set(decision) == DECISION_KEYS
    kind = decision["action"]["kind"]
    assert decision["expects"] == EXPECTS[kind]
    assert decision["decision_id"]
    assert isinstance(decision["decision_id"], str)
    ps = [p["p"] for p in decision["probabilities"]]
    assert sum(ps) == pytest.approx(1.0)
    assert all(0.0 <= p <= 1.0 for p in ps)
    assert decision["action"] in [p["action"] for p in decision["probabilities"]]
    for step in decision["chain"]:
        assert set(step) == {"action", "p"}
        assert step["action"]["kind"] in ("respond", "infer_type", "infer_detail")


def first(
    client: TestClient,
    kind: str,
    *,
    prefix: str,
    initiator: str = "robot",
    request: dict[str, Any] | None = None,
    tries: int = 60,
) -> dict[str, Any]:
    """A new episode (of a fresh user ``{prefix}{i}``) whose first decision is ``kind``."""
    for i in range(tries):
        ep = start(client, f"{prefix}{i}", "e1", initiator=initiator, request=request)
        if ep["decision"]["action"]["kind"] == kind:
            return ep
    pytest.fail(f"no first decision of kind {kind} in {tries} users")


def positive(decision: dict[str, Any]) -> dict[str, Any]:
    """An outcome body that moves a decision on without ending the episode (if possible)."""
    return {
        "decision_id": decision["decision_id"],
        **people.answer(decision["action"], picky=False),
    }


def outcome(client: TestClient, episode_id: str, body: dict[str, Any]) -> Any:
    return client.post(f"/v1/episodes/{episode_id}/outcomes", json=body)


def snapshot(client: TestClient, ep: dict[str, Any]) -> tuple[Any, Any, Any]:
    """What a refused write must not change: the trace, the user and its model."""
    return (
        client.get(f"/v1/episodes/{ep['episode_id']}").json(),
        client.get(f"/v1/users/{ep['user_id']}").json(),
        client.get(f"/v1/users/{ep['user_id']}/model").json(),
    )


def version(client: TestClient, user_id: str) -> int:
    v: int = client.get(f"/v1/users/{user_id}/model").json()["version"]
    return v


class TestStartEpisode:
    def test_201_has_exactly_the_contracts_shape(self, robot: TestClient) -> None:
        r = robot.post("/v1/users/lin/episodes", json=event("robot7-000123"))
        assert r.status_code == 201, r.text
        assert "Idempotent-Replay" not in r.headers
        body = r.json()
        assert set(body) == {
            "episode_id",
            "user_id",
            "status",
            "context",
            "state",
            "total_reward",
            "decision",
            "mission_version",
        }
        assert body["mission_version"] == 1  # the fleet's first mission: the default
        assert isinstance(body["episode_id"], str)
        assert body["episode_id"]
        assert body["user_id"] == "lin"
        assert body["status"] == "open"
        assert body["context"] == {"time_slot": "afternoon", "situation": "stretching"}
        assert body["state"] == "OBSERVE"
        assert body["total_reward"] == 0.0
        decision = body["decision"]
        check_decision(decision)
        assert decision["action"]["kind"] in ("initiate", "pass")
        assert decision["chain"] == []
        assert [p["action"] for p in decision["probabilities"]] == [
            {"kind": "initiate"},
            {"kind": "pass"},
        ]

    @pytest.mark.parametrize(
        ("occurred_at", "slot"),
        [
            ("2026-11-22T09:30:00+08:00", "morning"),
            ("2026-11-22T01:30:00Z", "evening"),  # the same instant, written in UTC
            ("2026-11-22T01:30:00+00:00", "evening"),
            ("2026-11-22T06:00:00+02:00", "morning"),
            ("2026-11-22T05:59:59+02:00", "evening"),
            ("2026-11-22T11:00:00-05:00", "noon"),
            ("2026-11-22T13:59:00+05:30", "noon"),
            ("2026-11-22T14:00:00+08:00", "afternoon"),
            ("2026-11-22T17:59:59-08:00", "afternoon"),
            ("2026-11-22T18:00:00+08:00", "evening"),
            ("2026-11-22T23:59:59+14:00", "evening"),
            ("2026-11-22T00:00:00-12:00", "evening"),
        ],
    )
    def test_time_slot_is_picked_by_the_local_time_of_the_offset(
        self, robot: TestClient, occurred_at: str, slot: str
    ) -> None:
        ep = start(robot, "lin", "e1", occurred_at=occurred_at, situation="working")
        assert ep["context"] == {"time_slot": slot, "situation": "working"}
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert trace["context"] == {"time_slot": slot, "situation": "working"}

    @pytest.mark.parametrize("situation", ["arriving", "working", "stretching", "busy"])
    def test_every_situation_is_accepted(self, robot: TestClient, situation: str) -> None:
        assert start(robot, "lin", "e1", situation=situation)["context"]["situation"] == situation

    def test_user_is_created_on_first_use(self, robot: TestClient) -> None:
        assert robot.get("/v1/users/newbie").status_code == 404
        start(robot, "newbie", "e1")
        user = robot.get("/v1/users/newbie").json()
        assert user["fleet"] == "default"
        assert user["learner"]["algorithm"] == "dts-routine"
        assert user["learner"]["params"]["forgetting"] == pytest.approx(0.95)
        assert user["episodes"] == 1

    def test_repeat_is_a_replay(self, robot: TestClient) -> None:
        first_r = robot.post("/v1/users/lin/episodes", json=event("e1"))
        assert first_r.status_code == 201
        before = (robot.get("/v1/users/lin").json(), version(robot, "lin"))
        again = robot.post("/v1/users/lin/episodes", json=event("e1"))
        assert again.status_code == 200, again.text
        assert again.headers["Idempotent-Replay"] == "true"
        assert again.json() == first_r.json()
        assert (robot.get("/v1/users/lin").json(), version(robot, "lin")) == before
        assert robot.get("/v1/users/lin").json()["episodes"] == 1
        assert len(robot.get("/v1/users/lin/episodes").json()["items"]) == 1

    def test_replay_ignores_key_order(self, robot: TestClient) -> None:
        body = event("e1")
        first_r = robot.post("/v1/users/lin/episodes", json=body)
        again = robot.post("/v1/users/lin/episodes", json=dict(reversed(list(body.items()))))
        assert again.status_code == 200
        assert again.json() == first_r.json()

    def test_replay_after_the_episode_moved_on_is_still_the_first_answer(
        self, robot: TestClient
    ) -> None:
        first_r = robot.post("/v1/users/lin/episodes", json=event("e1")).json()
        report(
            robot,
            first_r["episode_id"],
            first_r["decision"]["decision_id"],
            **{k: v for k, v in positive(first_r["decision"]).items() if k != "decision_id"},
        )
        again = robot.post("/v1/users/lin/episodes", json=event("e1"))
        assert again.status_code == 200
        assert again.json() == first_r

    @pytest.mark.parametrize(
        "change",
        [
            {"situation": "working"},
            {"occurred_at": "2026-11-22T15:11:00+08:00"},
            {"initiator": "human"},
            {"robot_id": "robot8"},
        ],
    )
    def test_same_event_id_with_another_body_is_409(
        self, robot: TestClient, change: dict[str, Any]
    ) -> None:
        ep = start(robot, "lin", "e1")
        before = snapshot(robot, ep)
        r = robot.post("/v1/users/lin/episodes", json={**event("e1"), **change})
        assert_error(r, 409, "Conflict")
        assert snapshot(robot, ep) == before

    def test_human_request_with_detail_is_performed(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        decision = ep["decision"]
        check_decision(decision)
        assert decision["action"] == {"kind": "perform", **TEA}
        assert decision["expects"] == EXPECTS["perform"]
        assert decision["chain"][0]["action"] == {"kind": "respond", "service": "ProvideDrink"}
        assert ep["total_reward"] == 1.0  # respond: r_pos
        assert ep["status"] == "open"

    def test_human_request_with_service_only(self, robot: TestClient) -> None:
        for i in range(8):
            ep = start(
                robot, f"h{i}", "e1", initiator="human", request={"service": "BriefInformation"}
            )
            decision = ep["decision"]
            check_decision(decision)
            assert decision["chain"][0]["action"] == {
                "kind": "respond",
                "service": "BriefInformation",
            }
            assert decision["action"]["kind"] in ("query_detail", "perform")
            assert decision["action"]["service"] == "BriefInformation"
            assert ep["total_reward"] == 1.0

    def test_human_without_request(self, robot: TestClient) -> None:
        for i in range(8):
            ep = start(robot, f"h{i}", "e1", initiator="human")
            check_decision(ep["decision"])
            assert ep["decision"]["action"]["kind"] in ("query_type", "query_detail", "perform")
            assert all(s["action"]["kind"] != "respond" for s in ep["decision"]["chain"])

    @pytest.mark.one_engine
    def test_request_with_robot_initiator_is_422(self, robot: TestClient) -> None:
        r = robot.post("/v1/users/lin/episodes", json=event("e1", initiator="robot", request=TEA))
        assert_error(r, 422, "ValidationError")
        assert robot.get("/v1/users/lin").status_code == 404

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "request_",
        [
            {"service": "Massage"},
            {"service": "ProvideDrink", "detail": "news"},
            {"detail": "tea"},
            {"service": "ProvideDrink", "size": "large"},
        ],
    )
    def test_bad_request_is_422(self, robot: TestClient, request_: dict[str, Any]) -> None:
        r = robot.post(
            "/v1/users/lin/episodes", json=event("e1", initiator="human", request=request_)
        )
        assert_error(r, 422, "ValidationError")
        assert robot.get("/v1/users/lin").status_code == 404

    def test_the_same_user_id_in_another_fleet_is_another_person(
        self, robot: TestClient, other_robot: TestClient
    ) -> None:
        other_robot.put("/v1/users/far")
        theirs = start(other_robot, "far", "e1")
        before = other_robot.get("/v1/users/far").json()
        ours = start(robot, "far", "e1")  # the same event id: each fleet's far has its own
        assert ours["episode_id"] != theirs["episode_id"]
        assert (
            "Idempotent-Replay"
            not in robot.post("/v1/users/far/episodes", json=event("e2")).headers
        )
        assert other_robot.get("/v1/users/far").json() == before
        assert robot.get("/v1/users/far").json()["episodes"] == 2

    def test_event_ids_are_per_user(self, robot: TestClient) -> None:
        a = start(robot, "a", "e1")
        b = start(robot, "b", "e1")
        assert a["episode_id"] != b["episode_id"]


class TestReportOutcome:
    @pytest.mark.parametrize(
        ("kind", "prefix", "initiator", "request_", "body"),
        [
            ("initiate", "i", "robot", None, {"response": "accepted"}),
            ("initiate", "i", "robot", None, {"response": "rejected"}),
            ("initiate", "i", "robot", None, {"response": "terminated"}),
            ("pass", "p", "robot", None, {"response": "none"}),
            ("pass", "p", "robot", None, {"response": "human_request"}),
            ("pass", "p", "robot", None, {"response": "human_request", "service": "ProvideDrink"}),
            ("pass", "p", "robot", None, {"response": "human_request", **TEA}),
            (
                "query_type",
                "q",
                "human",
                None,
                {"response": "answered", "service": "ArrangeSchedule"},
            ),
            ("query_type", "q", "human", None, {"response": "terminated"}),
            (
                "query_detail",
                "d",
                "human",
                {"service": "ProvideDrink"},
                {"response": "answered", "detail": "coffee"},
            ),
            (
                "query_detail",
                "d",
                "human",
                {"service": "ProvideDrink"},
                {"response": "answered", "service": "ProvideDrink", "detail": "coffee"},
            ),
            ("query_detail", "d", "human", {"service": "ProvideDrink"}, {"response": "terminated"}),
            ("perform", "f", "human", TEA, {"response": "accepted"}),
            ("perform", "f", "human", TEA, {"response": "rejected"}),
            ("perform", "f", "human", TEA, {"response": "terminated"}),
        ],
    )
    def test_each_allowed_response(
        self,
        robot: TestClient,
        kind: str,
        prefix: str,
        initiator: str,
        request_: dict[str, Any] | None,
        body: dict[str, Any],
    ) -> None:
        ep = first(robot, kind, prefix=prefix, initiator=initiator, request=request_)
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], **body)
        assert set(out) == {"reward", "episode", "decision"}
        assert set(out["episode"]) == {"episode_id", "status", "state", "total_reward"}
        assert out["episode"]["episode_id"] == ep["episode_id"]
        if out["decision"] is None:
            assert out["episode"]["status"] == "closed"
            assert out["episode"]["state"] == "END"
        else:
            assert out["episode"]["status"] == "open"
            check_decision(out["decision"])
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        answered = [
            d for d in trace["decisions"] if d["decision_id"] == ep["decision"]["decision_id"]
        ][0]
        assert answered["response"] == body["response"]
        if "detail" in body:
            assert answered["detail"] == body["detail"]

    @pytest.mark.parametrize(
        ("kind", "prefix", "initiator", "request_", "response"),
        [
            ("initiate", "i", "robot", None, "answered"),
            ("initiate", "i", "robot", None, "none"),
            ("initiate", "i", "robot", None, "human_request"),
            ("pass", "p", "robot", None, "accepted"),
            ("pass", "p", "robot", None, "terminated"),
            ("query_type", "q", "human", None, "accepted"),
            ("query_type", "q", "human", None, "none"),
            ("query_detail", "d", "human", {"service": "ProvideDrink"}, "rejected"),
            ("perform", "f", "human", TEA, "answered"),
            ("perform", "f", "human", TEA, "none"),
        ],
    )
    def test_a_response_not_allowed_is_422_naming_the_allowed_ones(
        self,
        robot: TestClient,
        kind: str,
        prefix: str,
        initiator: str,
        request_: dict[str, Any] | None,
        response: str,
    ) -> None:
        ep = first(robot, kind, prefix=prefix, initiator=initiator, request=request_)
        before = snapshot(robot, ep)
        r = outcome(
            robot,
            ep["episode_id"],
            {
                "decision_id": ep["decision"]["decision_id"],
                "response": response,
                "service": "ProvideDrink",
                "detail": "tea",
            }
            if response in ("answered", "human_request")
            else {"decision_id": ep["decision"]["decision_id"], "response": response},
        )
        body = assert_error(r, 422, "ValidationError")
        if response not in ("answered", "human_request"):
            for allowed in EXPECTS[kind]:
                assert allowed in body["detail"]
        assert snapshot(robot, ep) == before

    def test_not_allowed_names_the_allowed_ones(self, robot: TestClient) -> None:
        ep = first(robot, "initiate", prefix="i")
        r = outcome(
            robot,
            ep["episode_id"],
            {"decision_id": ep["decision"]["decision_id"], "response": "answered"},
        )
        body = assert_error(r, 422, "ValidationError")
        for allowed in EXPECTS["initiate"]:
            assert allowed in body["detail"]

    @pytest.mark.one_engine
    def test_unknown_response_word_is_422(self, robot: TestClient) -> None:
        ep = first(robot, "initiate", prefix="i")
        before = snapshot(robot, ep)
        r = outcome(
            robot,
            ep["episode_id"],
            {"decision_id": ep["decision"]["decision_id"], "response": "maybe"},
        )
        assert_error(r, 422, "ValidationError")
        assert snapshot(robot, ep) == before

    @pytest.mark.parametrize(
        "extra",
        [
            {},  # no service
            {"service": "Massage"},
            {"service": "ProvideDrink", "detail": "tea"},  # the detail is asked next
            {"detail": "tea"},
        ],
    )
    def test_query_type_answer_needs_a_known_service(
        self, robot: TestClient, extra: dict[str, Any]
    ) -> None:
        ep = first(robot, "query_type", prefix="q", initiator="human")
        before = snapshot(robot, ep)
        r = outcome(
            robot,
            ep["episode_id"],
            {"decision_id": ep["decision"]["decision_id"], "response": "answered", **extra},
        )
        body = assert_error(r, 422, "ValidationError")
        if extra.get("service") == "Massage":
            assert "ProvideDrink" in body["detail"]
        assert snapshot(robot, ep) == before

    @pytest.mark.parametrize(
        "extra",
        [
            {},
            {"detail": "news"},
            {"detail": "nope"},
            {"service": "BriefInformation", "detail": "news"},
        ],
    )
    def test_query_detail_answer_needs_a_detail_of_its_service(
        self, robot: TestClient, extra: dict[str, Any]
    ) -> None:
        ep = first(
            robot,
            "query_detail",
            prefix="d",
            initiator="human",
            request={"service": "ProvideDrink"},
        )
        before = snapshot(robot, ep)
        r = outcome(
            robot,
            ep["episode_id"],
            {"decision_id": ep["decision"]["decision_id"], "response": "answered", **extra},
        )
        assert_error(r, 422, "ValidationError")
        assert snapshot(robot, ep) == before

    def test_human_request_with_unknown_service_is_422(self, robot: TestClient) -> None:
        ep = first(robot, "pass", prefix="p")
        before = snapshot(robot, ep)
        r = outcome(
            robot,
            ep["episode_id"],
            {
                "decision_id": ep["decision"]["decision_id"],
                "response": "human_request",
                "service": "Massage",
            },
        )
        assert_error(r, 422, "ValidationError")
        assert snapshot(robot, ep) == before

    def test_replay_is_200_with_the_header_and_the_same_body(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        body = {"decision_id": ep["decision"]["decision_id"], "response": "accepted"}
        first_r = outcome(robot, ep["episode_id"], body)
        assert first_r.status_code == 200
        assert "Idempotent-Replay" not in first_r.headers
        before = snapshot(robot, ep)
        again = outcome(robot, ep["episode_id"], body)
        assert again.status_code == 200
        assert again.headers["Idempotent-Replay"] == "true"
        assert again.json() == first_r.json()
        assert snapshot(robot, ep) == before

    def test_replay_of_an_earlier_decision_in_an_open_episode(self, robot: TestClient) -> None:
        ep = first(robot, "initiate", prefix="i")
        body = {"decision_id": ep["decision"]["decision_id"], "response": "accepted"}
        first_r = outcome(robot, ep["episode_id"], body).json()
        assert first_r["decision"] is not None
        before = snapshot(robot, ep)
        again = outcome(robot, ep["episode_id"], body)
        assert again.status_code == 200
        assert again.headers["Idempotent-Replay"] == "true"
        assert again.json() == first_r
        assert snapshot(robot, ep) == before

    @pytest.mark.parametrize("change", [{"response": "rejected"}, {"feedback": "positive"}])
    def test_another_body_for_an_answered_decision_is_409(
        self, robot: TestClient, change: dict[str, Any]
    ) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        body = {"decision_id": ep["decision"]["decision_id"], "response": "accepted"}
        outcome(robot, ep["episode_id"], body)
        before = snapshot(robot, ep)
        assert_error(outcome(robot, ep["episode_id"], {**body, **change}), 409, "Conflict")
        assert snapshot(robot, ep) == before

    def test_a_decision_that_is_not_current_is_409(self, robot: TestClient) -> None:
        ep = first(robot, "initiate", prefix="i")
        other = start(robot, ep["user_id"], "e2")
        before = snapshot(robot, ep)
        r = outcome(
            robot,
            ep["episode_id"],
            {"decision_id": other["decision"]["decision_id"], "response": "accepted"},
        )
        assert_error(r, 409, "Conflict")
        r = outcome(robot, ep["episode_id"], {"decision_id": "dec_nope", "response": "accepted"})
        assert_error(r, 409, "Conflict")
        assert snapshot(robot, ep) == before

    def test_a_closed_episode_is_409(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], "rejected")
        assert out["decision"] is None
        before = snapshot(robot, ep)
        r = outcome(robot, ep["episode_id"], {"decision_id": "dec_later", "response": "accepted"})
        assert_error(r, 409, "Conflict")
        assert snapshot(robot, ep) == before

    def test_unknown_episode_is_404(self, robot: TestClient) -> None:
        r = outcome(robot, "ep_nope", {"decision_id": "dec_x", "response": "accepted"})
        assert_error(r, 404, "NotFound")

    def test_another_fleets_episode_is_404(
        self, robot: TestClient, other_robot: TestClient
    ) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        before = snapshot(robot, ep)
        r = outcome(
            other_robot,
            ep["episode_id"],
            {"decision_id": ep["decision"]["decision_id"], "response": "accepted"},
        )
        assert_error(r, 404, "NotFound")
        assert snapshot(robot, ep) == before

    def test_admin_may_answer_any_fleet(self, other_robot: TestClient, admin: TestClient) -> None:
        ep = start(other_robot, "far", "e1", initiator="human", request=TEA)
        out = report(admin, ep["episode_id"], ep["decision"]["decision_id"], "accepted")
        assert out["reward"] == 6.0


class TestRewards:
    @pytest.mark.parametrize(
        ("response", "reward"),
        [
            ("accepted", 1.0),
            ("rejected", -2.0),
            ("terminated", -2.0),
        ],
    )
    def test_initiate(self, robot: TestClient, response: str, reward: float) -> None:
        ep = first(robot, "initiate", prefix="i")
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], response)
        assert out["reward"] == reward
        assert out["episode"]["total_reward"] == reward
        if response == "accepted":
            assert out["episode"]["status"] == "open"
        else:
            assert out["decision"] is None
            assert out["episode"]["state"] == "END"

    def test_pass_none_is_0_and_closes(self, robot: TestClient) -> None:
        ep = first(robot, "pass", prefix="p")
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], "none")
        assert out["reward"] == 0.0
        assert out["decision"] is None
        assert out["episode"] == {
            "episode_id": ep["episode_id"],
            "status": "closed",
            "state": "END",
            "total_reward": 0.0,
        }

    def test_pass_then_request_responds_first(self, robot: TestClient) -> None:
        ep = first(robot, "pass", prefix="p")
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], "human_request", **TEA)
        assert out["reward"] == 0.0
        assert out["decision"]["action"] == {"kind": "perform", **TEA}
        assert out["decision"]["chain"][0]["action"] == {
            "kind": "respond",
            "service": "ProvideDrink",
        }
        assert out["episode"]["total_reward"] == 1.0  # the silent respond step
        done = report(robot, ep["episode_id"], out["decision"]["decision_id"], "accepted")
        assert done["episode"]["total_reward"] == 7.0
        assert robot.get(f"/v1/episodes/{ep['episode_id']}").json()["interaction_class"] == "I1"

    def test_query_answered_is_minus_half(self, robot: TestClient) -> None:
        ep = first(robot, "query_type", prefix="q", initiator="human")
        out = report(
            robot,
            ep["episode_id"],
            ep["decision"]["decision_id"],
            "answered",
            service="ProvideDrink",
        )
        assert out["reward"] == -0.5
        assert out["episode"]["state"] == "TYPE_KNOWN" or out["decision"]["chain"]
        assert out["episode"]["total_reward"] == ep["total_reward"] - 0.5

    def test_query_terminated_is_minus_two_and_a_half(self, robot: TestClient) -> None:
        ep = first(robot, "query_type", prefix="q", initiator="human")
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], "terminated")
        assert out["reward"] == -2.5
        assert out["decision"] is None
        assert out["episode"]["status"] == "closed"

    def test_query_detail_answered_is_minus_half(self, robot: TestClient) -> None:
        ep = first(
            robot,
            "query_detail",
            prefix="d",
            initiator="human",
            request={"service": "ProvideDrink"},
        )
        out = report(
            robot, ep["episode_id"], ep["decision"]["decision_id"], "answered", detail="water"
        )
        assert out["reward"] == -0.5
        assert out["decision"]["action"] == {
            "kind": "perform",
            "service": "ProvideDrink",
            "detail": "water",
        }
        assert out["episode"]["state"] == "DETAIL_KNOWN"
        assert out["episode"]["total_reward"] == 0.5  # respond +1, query -0.5

    @pytest.mark.parametrize(
        ("response", "reward"),
        [
            ("accepted", 6.0),
            ("rejected", -2.0),
            ("terminated", -2.0),
        ],
    )
    def test_perform(self, robot: TestClient, response: str, reward: float) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], response)
        assert out["reward"] == reward
        assert out["episode"] == {
            "episode_id": ep["episode_id"],
            "status": "closed",
            "state": "END",
            "total_reward": 1.0 + reward,
        }
        assert out["decision"] is None

    @pytest.mark.parametrize(("feedback", "reward"), [("positive", 7.0), ("negative", 4.0)])
    def test_feedback_in_the_outcome_adds_to_the_reward(
        self, robot: TestClient, feedback: str, reward: float
    ) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        out = report(
            robot, ep["episode_id"], ep["decision"]["decision_id"], "accepted", feedback=feedback
        )
        assert out["reward"] == reward
        assert out["episode"]["total_reward"] == 1.0 + reward
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert trace["decisions"][-1]["feedback"] == feedback
        assert trace["decisions"][-1]["reward"] == reward

    def test_a_whole_robot_initiated_episode(self, robot: TestClient) -> None:
        ep = first(robot, "initiate", prefix="i")
        decision = ep["decision"]
        out = report(robot, ep["episode_id"], decision["decision_id"], "accepted")
        expected = 1.0
        steps = 1
        while out["decision"] is not None:
            decision = out["decision"]
            check_decision(decision)
            body = positive(decision)
            out = report(
                robot,
                ep["episode_id"],
                decision["decision_id"],
                **{k: v for k, v in body.items() if k != "decision_id"},
            )
            expected += out["reward"]
            steps += 1
            assert steps <= 4
        assert out["episode"]["status"] == "closed"
        assert out["episode"]["total_reward"] == pytest.approx(expected)
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert trace["total_reward"] == pytest.approx(expected)
        assert trace["interaction_class"] == "I2"
        assert trace["decisions"][-1]["action"]["kind"] == "perform"


class TestFeedback:
    def _closed(self, robot: TestClient) -> dict[str, Any]:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        report(robot, ep["episode_id"], ep["decision"]["decision_id"], "accepted")
        return ep

    @pytest.mark.parametrize(("word", "reward"), [("positive", 1.0), ("negative", -2.0)])
    def test_200_with_reward_and_episode(self, robot: TestClient, word: str, reward: float) -> None:
        ep = self._closed(robot)
        v = version(robot, "lin")
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/feedback",
            json={"feedback_id": "fb-1", "feedback": word},
        )
        assert r.status_code == 200, r.text
        assert "Idempotent-Replay" not in r.headers
        body = r.json()
        assert body == {
            "reward": reward,
            "episode": {
                "episode_id": ep["episode_id"],
                "status": "closed",
                "state": "END",
                "total_reward": 7.0 + reward,
            },
        }
        assert version(robot, "lin") == v + 1
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert trace["total_reward"] == 7.0 + reward
        assert len(trace["feedback"]) == 1
        fb = trace["feedback"][0]
        assert set(fb) == {"feedback_id", "feedback", "reward", "received_at"}
        assert (fb["feedback_id"], fb["feedback"], fb["reward"]) == ("fb-1", word, reward)
        stats = robot.get("/v1/users/lin/stats").json()
        assert stats["total_reward"] == 7.0 + reward

    def test_replay_changes_nothing(self, robot: TestClient) -> None:
        ep = self._closed(robot)
        url = f"/v1/episodes/{ep['episode_id']}/feedback"
        first_r = robot.post(url, json={"feedback_id": "fb-1", "feedback": "positive"})
        before = snapshot(robot, ep)
        again = robot.post(url, json={"feedback_id": "fb-1", "feedback": "positive"})
        assert again.status_code == 200
        assert again.headers["Idempotent-Replay"] == "true"
        assert again.json() == first_r.json()
        assert snapshot(robot, ep) == before

    def test_same_id_another_body_is_409(self, robot: TestClient) -> None:
        ep = self._closed(robot)
        url = f"/v1/episodes/{ep['episode_id']}/feedback"
        robot.post(url, json={"feedback_id": "fb-1", "feedback": "positive"})
        before = snapshot(robot, ep)
        r = robot.post(url, json={"feedback_id": "fb-1", "feedback": "negative"})
        assert_error(r, 409, "Conflict")
        assert snapshot(robot, ep) == before

    def test_two_ids_both_count(self, robot: TestClient) -> None:
        ep = self._closed(robot)
        url = f"/v1/episodes/{ep['episode_id']}/feedback"
        robot.post(url, json={"feedback_id": "fb-1", "feedback": "positive"})
        out = robot.post(url, json={"feedback_id": "fb-2", "feedback": "positive"}).json()
        assert out["episode"]["total_reward"] == 9.0
        assert len(robot.get(f"/v1/episodes/{ep['episode_id']}").json()["feedback"]) == 2

    def test_during_an_open_episode(self, robot: TestClient) -> None:
        ep = first(robot, "initiate", prefix="i")
        report(robot, ep["episode_id"], ep["decision"]["decision_id"], "accepted")
        v = version(robot, ep["user_id"])
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/feedback",
            json={"feedback_id": "fb-1", "feedback": "positive"},
        )
        assert r.status_code == 200, r.text
        assert r.json()["episode"]["status"] == "open"
        assert r.json()["episode"]["total_reward"] == 2.0
        assert version(robot, ep["user_id"]) == v + 1

    def test_no_answered_step_yet_is_409(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1")
        before = snapshot(robot, ep)
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/feedback",
            json={"feedback_id": "fb-1", "feedback": "positive"},
        )
        assert_error(r, 409, "Conflict")
        assert snapshot(robot, ep) == before

    def test_unknown_and_foreign_episodes_are_404(
        self, robot: TestClient, other_robot: TestClient
    ) -> None:
        ep = self._closed(robot)
        body = {"feedback_id": "fb-1", "feedback": "positive"}
        assert_error(robot.post("/v1/episodes/ep_nope/feedback", json=body), 404, "NotFound")
        before = snapshot(robot, ep)
        assert_error(
            other_robot.post(f"/v1/episodes/{ep['episode_id']}/feedback", json=body),
            404,
            "NotFound",
        )
        assert snapshot(robot, ep) == before

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "body",
        [
            {"feedback_id": "fb-1", "feedback": "great"},
            {"feedback_id": "fb 1", "feedback": "positive"},
            {"feedback_id": "", "feedback": "positive"},
            {"feedback": "positive"},
            {"feedback_id": "fb-1"},
            {"feedback_id": "fb-1", "feedback": "positive", "extra": 1},
        ],
    )
    def test_bad_bodies_are_422(self, robot: TestClient, body: dict[str, Any]) -> None:
        ep = self._closed(robot)
        before = snapshot(robot, ep)
        r = robot.post(f"/v1/episodes/{ep['episode_id']}/feedback", json=body)
        assert_error(r, 422, "ValidationError")
        assert snapshot(robot, ep) == before


class TestGetEpisode:
    def test_trace_of_an_open_episode(self, robot: TestClient) -> None:
        r = robot.post("/v1/users/lin/episodes", json=event("ev-9", robot_id="r2"))
        ep = r.json()
        r = robot.get(f"/v1/episodes/{ep['episode_id']}")
        assert r.status_code == 200
        trace = r.json()
        assert set(trace) >= {
            "episode_id",
            "user_id",
            "event_id",
            "robot_id",
            "status",
            "context",
            "initiator",
            "interaction_class",
            "total_reward",
            "decisions",
            "feedback",
        }
        assert (trace["episode_id"], trace["user_id"], trace["event_id"], trace["robot_id"]) == (
            ep["episode_id"],
            "lin",
            "ev-9",
            "r2",
        )
        assert trace["status"] == "open"
        assert trace["initiator"] == "robot"
        assert trace["context"] == ep["context"]
        assert trace["feedback"] == []
        [d] = trace["decisions"]
        assert set(d) >= {
            "decision_id",
            "state",
            "action",
            "probabilities",
            "chain",
            "response",
            "service",
            "detail",
            "feedback",
            "reward",
            "decided_at",
            "answered_at",
        }
        assert d["decision_id"] == ep["decision"]["decision_id"]
        assert d["state"] == "OBSERVE"
        assert d["action"] == ep["decision"]["action"]
        assert d["probabilities"] == ep["decision"]["probabilities"]
        assert d["chain"] == []
        assert d["response"] is None
        assert d["reward"] is None
        assert d["answered_at"] is None
        assert d["decided_at"]

    def test_answered_decisions_carry_response_reward_and_time(self, robot: TestClient) -> None:
        ep = first(robot, "initiate", prefix="i")
        out = report(robot, ep["episode_id"], ep["decision"]["decision_id"], "accepted")
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert len(trace["decisions"]) == 2
        d0, d1 = trace["decisions"]
        assert (d0["response"], d0["reward"]) == ("accepted", 1.0)
        assert d0["answered_at"] is not None
        assert d1["decision_id"] == out["decision"]["decision_id"]
        assert d1["state"] == "ENGAGED" if not d1["chain"] else d1["state"] != "OBSERVE"
        assert (d1["response"], d1["reward"], d1["answered_at"]) == (None, None, None)
        assert trace["interaction_class"] == "I2"
        assert trace["total_reward"] == out["episode"]["total_reward"]

    @pytest.mark.parametrize(
        ("kind", "response", "cls"),
        [
            ("initiate", "accepted", "I2"),
            ("initiate", "rejected", "I3"),
            ("initiate", "terminated", "I3"),
            ("pass", "none", "none"),
            ("pass", "human_request", "I1"),
        ],
    )
    def test_interaction_class(self, robot: TestClient, kind: str, response: str, cls: str) -> None:
        ep = first(robot, kind, prefix=kind[0])
        report(robot, ep["episode_id"], ep["decision"]["decision_id"], response)
        assert robot.get(f"/v1/episodes/{ep['episode_id']}").json()["interaction_class"] == cls

    def test_human_initiated_is_i1_and_lists_the_request(self, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1", initiator="human", request=TEA)
        report(robot, ep["episode_id"], ep["decision"]["decision_id"], "accepted")
        trace = robot.get(f"/v1/episodes/{ep['episode_id']}").json()
        assert trace["initiator"] == "human"
        assert trace["interaction_class"] == "I1"
        assert trace["status"] == "closed"
        assert trace["total_reward"] == 7.0
        last = trace["decisions"][-1]
        assert last["action"] == {"kind": "perform", **TEA}
        assert (last["response"], last["reward"]) == ("accepted", 6.0)
        assert last["chain"][0]["action"]["kind"] == "respond"
        assert all(d["answered_at"] is not None for d in trace["decisions"])

    def test_unknown_and_foreign_are_404(self, robot: TestClient, other_robot: TestClient) -> None:
        ep = start(robot, "lin", "e1")
        assert_error(robot.get("/v1/episodes/ep_nope"), 404, "NotFound")
        assert_error(other_robot.get(f"/v1/episodes/{ep['episode_id']}"), 404, "NotFound")


class TestListEpisodes:
    def test_newest_first_in_pages(self, robot: TestClient) -> None:
        ids = [start(robot, "lin", f"e{i}")["episode_id"] for i in range(5)]
        seen: list[str] = []
        cursor: str | None = None
        for _ in range(5):
            params: dict[str, Any] = {"limit": 2}
            if cursor:
                params["cursor"] = cursor
            page = robot.get("/v1/users/lin/episodes", params=params).json()
            seen += [e["episode_id"] for e in page["items"]]
            assert all("decisions" not in e for e in page["items"])
            cursor = page["next_cursor"]
            if cursor is None:
                break
        assert seen == list(reversed(ids))

    def test_unknown_user_is_404(self, robot: TestClient) -> None:
        assert_error(robot.get("/v1/users/nobody/episodes"), 404, "NotFound")

    def test_bad_cursor_is_422(self, robot: TestClient) -> None:
        start(robot, "lin", "e1")
        assert_error(robot.get("/v1/users/lin/episodes?cursor=abc"), 422, "ValidationError")
