"""Bad input of every kind: refused with the one error shape, never a 500, nothing stored."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.console.auth import COOKIE, csrf_token
from app.db.session import Database
from app.errors import ValidationFailed
from app.services.auth import create_key, list_keys, revoke_key
from tests.support.contract import assert_error
from tests.support.episodes import event, start

TEA = {"service": "ProvideDrink", "detail": "tea"}
LIMIT = 64 * 1024
NUL_MESSAGE = "Text must not contain the NUL character (U+0000)"
SITUATIONS = ("arriving", "working", "stretching", "busy")


def assert_nul(r: Any, *where: list[str]) -> dict[str, Any]:
    """A 422 naming each of ``where`` as a field holding the NUL character."""
    body = assert_error(r, 422, "ValidationError")
    assert body["detail"] == f"{'.'.join(where[0])}: {NUL_MESSAGE}.", body
    assert [f["loc"] for f in body["fields"]] == list(where), body
    assert {f["type"] for f in body["fields"]} == {"string_nul"}, body
    return body


def state(client: TestClient, ep: dict[str, Any]) -> tuple[Any, ...]:
    """Everything a refused write could have touched."""
    uid = ep["user_id"]
    return (
        client.get(f"/v1/episodes/{ep['episode_id']}").json(),
        client.get(f"/v1/users/{uid}").json(),
        client.get(f"/v1/users/{uid}/model").json(),
        client.get(f"/v1/users/{uid}/stats").json(),
        client.get("/v1/users").json(),
    )


@pytest.fixture
def ep(robot: TestClient) -> dict[str, Any]:
    """An open episode of user ``lin`` waiting on a perform decision."""
    return start(robot, "lin", "seed", initiator="human", request=TEA)


@pytest.mark.one_engine
class TestEpisodeBodies:
    def test_unknown_situation_lists_the_situations(
        self, robot: TestClient, ep: dict[str, Any]
    ) -> None:
        before = state(robot, ep)
        r = robot.post("/v1/users/lin/episodes", json=event("e1", situation="sleeping"))
        body = assert_error(r, 422, "ValidationError")
        for name in SITUATIONS:
            assert name in body["detail"]
        assert state(robot, ep) == before

    def test_unknown_situation_for_a_new_user_creates_nothing(self, robot: TestClient) -> None:
        r = robot.post("/v1/users/newbie/episodes", json=event("e1", situation="dancing"))
        assert_error(r, 422, "ValidationError")
        assert robot.get("/v1/users/newbie").status_code == 404

    @pytest.mark.parametrize(
        "raw",
        [
            b"{",
            b'{"event_id": "e1",}',
            b"not json",
            b"\xff\xfe\x00",
            b"",
            b'{"event_id": ' + b"[" * 5000 + b"]" * 5000 + b"}",
            b'{"event_id": ' + b"9" * 5000 + b"}",
        ],
    )
    def test_malformed_json_is_400_or_422(
        self, robot: TestClient, ep: dict[str, Any], raw: bytes
    ) -> None:
        before = state(robot, ep)
        r = robot.post(
            "/v1/users/lin/episodes", content=raw, headers={"Content-Type": "application/json"}
        )
        assert_error(r, (400, 422))
        assert state(robot, ep) == before

    @pytest.mark.parametrize(
        "change",
        [
            {"situation": 5},
            {"situation": None},
            {"situation": ["working"]},
            {"situation": ""},
            {"occurred_at": "2026-11-22T15:10:00"},  # no offset
            {"occurred_at": "yesterday"},
            {"occurred_at": "2026-13-45T99:00:00+08:00"},
            {"occurred_at": 1763795400},
            {"occurred_at": None},
            {"occurred_at": "0001-01-01T00:00:00+14:00"},
            {"occurred_at": "9999-12-31T23:59:59-12:00"},
            {"initiator": "cat"},
            {"initiator": None},
            {"event_id": ""},
            {"event_id": "has space"},
            {"event_id": "x" * 129},
            {"event_id": "ünïcode"},
            {"event_id": 7},
            {"robot_id": "r 7"},
            {"request": "tea"},
            {"request": {"service": 3}},
            {"request": {"service": "ProvideDrink", "extra": 1}},
            {"colour": "blue"},
            {"situation": "busy\u0000"},
        ],
    )
    def test_wrong_values_are_422(
        self, robot: TestClient, ep: dict[str, Any], change: dict[str, Any]
    ) -> None:
        before = state(robot, ep)
        r = robot.post("/v1/users/lin/episodes", json={**event("e-new"), **change})
        assert_error(r, 422, "ValidationError")
        assert state(robot, ep) == before
        assert robot.get("/v1/users/lin").json()["episodes"] == 1

    @pytest.mark.parametrize("missing", ["event_id", "occurred_at", "situation"])
    def test_missing_required_fields_are_422_naming_the_field(
        self, robot: TestClient, ep: dict[str, Any], missing: str
    ) -> None:
        body = event("e-new")
        del body[missing]
        r = robot.post("/v1/users/lin/episodes", json=body)
        err = assert_error(r, 422, "ValidationError")
        assert missing in err["detail"]

    @pytest.mark.parametrize("raw", ["[]", "null", "3", '"str"', "true"])
    def test_a_body_that_is_not_an_object_is_422(self, robot: TestClient, raw: str) -> None:
        r = robot.post(
            "/v1/users/lin/episodes", content=raw, headers={"Content-Type": "application/json"}
        )
        assert_error(r, 422, "ValidationError")
        assert robot.get("/v1/users/lin").status_code == 404

    def test_a_json_body_sent_as_text_plain_is_refused(self, robot: TestClient) -> None:
        r = robot.post(
            "/v1/users/lin/episodes",
            content=json.dumps(event("e1")),
            headers={"Content-Type": "text/plain"},
        )
        assert_error(r, 415, "UnsupportedMediaType")
        assert robot.get("/v1/users/lin").status_code == 404


class TestOutcomeAndFeedbackBodies:
    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "body",
        [
            {},
            {"response": "accepted"},
            {"decision_id": "dec_x"},
            {"decision_id": 5, "response": "accepted"},
            {"decision_id": "d" * 65, "response": "accepted"},
            {"decision_id": "dec_x", "response": "ACCEPTED"},
            {"decision_id": "dec_x", "response": None},
            {"decision_id": "dec_x", "response": "accepted", "feedback": "meh"},
            {"decision_id": "dec_x", "response": "accepted", "feedback": 1},
            {"decision_id": "dec_x", "response": "accepted", "mood": "happy"},
            {"decision_id": "dec_x", "response": "accepted", "service": ["ProvideDrink"]},
        ],
    )
    def test_bad_outcome_bodies_are_422(
        self, robot: TestClient, ep: dict[str, Any], body: dict[str, Any]
    ) -> None:
        before = state(robot, ep)
        r = robot.post(f"/v1/episodes/{ep['episode_id']}/outcomes", json=body)
        assert_error(r, 422, "ValidationError")
        assert state(robot, ep) == before

    @pytest.mark.one_engine
    def test_malformed_outcome_json(self, robot: TestClient, ep: dict[str, Any]) -> None:
        before = state(robot, ep)
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/outcomes",
            content=b'{"decision',
            headers={"Content-Type": "application/json"},
        )
        assert_error(r, (400, 422))
        assert state(robot, ep) == before

    def test_nul_in_a_decision_id_is_422(self, robot: TestClient, ep: dict[str, Any]) -> None:
        before = state(robot, ep)
        r = robot.post(
            f"/v1/episodes/{ep['episode_id']}/outcomes",
            json={"decision_id": "dec\u0000", "response": "accepted"},
        )
        assert_nul(r, ["body", "decision_id"])
        assert state(robot, ep) == before

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "body",
        [
            {},
            {"feedback_id": "f1"},
            {"feedback_id": "f1", "feedback": "good"},
            {"feedback_id": "f 1", "feedback": "positive"},
            {"feedback_id": None, "feedback": "positive"},
            {"feedback_id": "f1", "feedback": "positive", "score": 5},
        ],
    )
    def test_bad_feedback_bodies_are_422(
        self, robot: TestClient, ep: dict[str, Any], body: dict[str, Any]
    ) -> None:
        before = state(robot, ep)
        r = robot.post(f"/v1/episodes/{ep['episode_id']}/feedback", json=body)
        assert_error(r, 422, "ValidationError")
        assert state(robot, ep) == before


class TestUserBodies:
    @pytest.mark.parametrize(
        "body",
        [
            {"display_name": 5},
            {"display_name": "x" * 201},
            {"learner": "hri"},
            {"learner": {"algorithm": 5}},
            {"learner": {"algorithm": "hri", "params": [1]}},
            {"learner": {"algorithm": "hri", "params": {"tau": 1e999}}},
            {"learner": {"algorithm": "hri", "params": {"tau": float("nan")}}},
            {"learner": {"algorithm": "hri", "params": {"vi_max_sweeps": 10**30}}},
            {"learner": {"algorithm": "hri", "extra": 1}},
            {"nickname": "Lin"},
        ],
    )
    def test_bad_user_bodies_are_422(
        self, staff: TestClient, ep: dict[str, Any], body: dict[str, Any]
    ) -> None:
        before = state(staff, ep)
        r = staff.put(
            "/v1/users/lin", content=json.dumps(body), headers={"Content-Type": "application/json"}
        )
        assert_error(r, 422, "ValidationError")
        assert state(staff, ep) == before
        r = staff.put(
            "/v1/users/fresh",
            content=json.dumps(body),
            headers={"Content-Type": "application/json"},
        )
        assert_error(r, 422, "ValidationError")
        assert staff.get("/v1/users/fresh").status_code == 404


@pytest.mark.one_engine
class TestBodyLimit:
    def test_content_length_over_the_limit_is_413(
        self, robot: TestClient, ep: dict[str, Any]
    ) -> None:
        before = state(robot, ep)
        raw = b"{" + b" " * (LIMIT + 10) + b"}"
        r = robot.post(
            "/v1/users/lin/episodes", content=raw, headers={"Content-Type": "application/json"}
        )
        assert_error(r, 413, "PayloadTooLarge")
        assert state(robot, ep) == before

    def test_a_big_valid_json_is_413(self, robot: TestClient, ep: dict[str, Any]) -> None:
        before = state(robot, ep)
        body = {**event("e-big"), "robot_id": "r" * (LIMIT + 1)}
        r = robot.post("/v1/users/lin/episodes", json=body)
        assert_error(r, 413, "PayloadTooLarge")
        r = robot.put("/v1/users/lin", json={"display_name": "x" * (LIMIT + 1)})
        assert_error(r, 413, "PayloadTooLarge")
        assert state(robot, ep) == before

    def test_a_streamed_body_without_length_is_413(
        self, robot: TestClient, ep: dict[str, Any]
    ) -> None:
        before = state(robot, ep)

        def chunks() -> Iterator[bytes]:
            yield b'{"event_id": "e-big", "robot_id": "'
            for _ in range(20):
                yield b"r" * 8192
            yield b'"}'

        r = robot.post(
            "/v1/users/lin/episodes", content=chunks(), headers={"Content-Type": "application/json"}
        )
        assert_error(r, 413, "PayloadTooLarge")
        assert state(robot, ep) == before

    def test_just_under_the_limit_is_not_413(self, robot: TestClient) -> None:
        body = {"display_name": "x" * 100}
        raw = json.dumps(body).encode()
        raw = raw[:-1] + b" " * (LIMIT - len(raw)) + b"}"
        assert len(raw) == LIMIT
        r = robot.put("/v1/users/lin", content=raw, headers={"Content-Type": "application/json"})
        assert r.status_code == 201, r.text

    def test_413_on_an_import_too(self, admin: TestClient, ep: dict[str, Any]) -> None:
        r = admin.put("/v1/users/lin/model", json={"format": "x" * (LIMIT + 1)})
        assert_error(r, 413, "PayloadTooLarge")


BAD_USER_IDS = ["a%20b", "x" * 129, "%C3%BC", "a%2Fb", "a%00b", "%22%3B--", "a*b", "~x"]


class TestPathIds:
    @pytest.mark.one_engine
    @pytest.mark.parametrize("uid", BAD_USER_IDS)
    def test_bad_user_ids_are_422(self, admin: TestClient, uid: str) -> None:
        routes: list[tuple[str, str, dict[str, Any] | None]] = [
            ("PUT", "", {}),
            ("GET", "", None),
            ("DELETE", "", None),
            ("POST", "/episodes", event("e1")),
            ("GET", "/episodes", None),
            ("GET", "/model", None),
            ("GET", "/stats", None),
            ("DELETE", "/model", None),
            ("GET", "/model/export", None),
        ]
        for method, suffix, body in routes:
            r = admin.request(method, f"/v1/users/{uid}{suffix}", json=body)
            # a path that no longer matches a route ("a/b") is 404; anything else is 422
            assert_error(r, (404, 422) if "%2F" in uid else 422)
        assert admin.get("/v1/users").json()["items"] == []

    def test_the_longest_id_is_fine(self, robot: TestClient) -> None:
        uid = "A-z0.9_:" + "x" * 120
        assert len(uid) == 128
        assert robot.put(f"/v1/users/{uid}").status_code == 201
        assert robot.get(f"/v1/users/{uid}").json()["user_id"] == uid

    @pytest.mark.parametrize("eid", ["ep%00x", "x" * 129, "%C3%BC", "ep_nope"])
    def test_bad_episode_ids_are_404_or_422(
        self, robot: TestClient, ep: dict[str, Any], eid: str
    ) -> None:
        before = state(robot, ep)
        assert_error(robot.get(f"/v1/episodes/{eid}"), (404, 422))
        assert_error(
            robot.post(
                f"/v1/episodes/{eid}/outcomes", json={"decision_id": "d", "response": "accepted"}
            ),
            (404, 422),
        )
        assert_error(
            robot.post(
                f"/v1/episodes/{eid}/feedback", json={"feedback_id": "f", "feedback": "positive"}
            ),
            (404, 422),
        )
        assert state(robot, ep) == before

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "query",
        [
            "cursor=AA",
            "cursor=%C2%B2",
            "cursor=%00",
            "cursor=" + "x" * 300,
            "limit=1e3",
        ],
    )
    def test_bad_list_queries(self, robot: TestClient, ep: dict[str, Any], query: str) -> None:
        assert_error(robot.get(f"/v1/users?{query}"), 422, "ValidationError")
        assert_error(robot.get(f"/v1/users/lin/episodes?{query}"), 422, "ValidationError")

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "query", ["time_slot=dawn", "situation=sleeping", "time_slot=%00", "situation=" + "x" * 100]
    )
    def test_bad_model_filters(self, robot: TestClient, ep: dict[str, Any], query: str) -> None:
        assert_error(robot.get(f"/v1/users/lin/model?{query}"), 422, "ValidationError")

    @pytest.mark.one_engine
    @pytest.mark.parametrize("query", ["last=0", "last=-3", "last=many"])
    def test_bad_stats_queries(self, robot: TestClient, ep: dict[str, Any], query: str) -> None:
        assert_error(robot.get(f"/v1/users/lin/stats?{query}"), 422, "ValidationError")


class TestAuth:
    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "headers",
        [
            {},
            {"Authorization": "Bearer att_nope"},
            {"Authorization": "Basic xyz"},
            {"Authorization": "Bearer"},
            {"Authorization": "Bearer "},
            {"Authorization": "att_x"},
            {"Authorization": "Bearer " + "k" * 5000},
        ],
    )
    def test_missing_or_unknown_key_is_401(
        self, app: FastAPI, robot: TestClient, ep: dict[str, Any], headers: dict[str, str]
    ) -> None:
        before = state(robot, ep)
        routes: list[tuple[str, str, dict[str, Any] | None]] = [
            ("GET", "/v1/mission", None),
            ("GET", "/v1/users", None),
            ("PUT", "/v1/users/lin", {"display_name": "X"}),
            ("PUT", "/v1/users/newbie", {}),
            ("GET", "/v1/users/lin", None),
            ("POST", "/v1/users/lin/episodes", event("e1")),
            ("GET", "/v1/users/lin/episodes", None),
            ("GET", "/v1/users/lin/model", None),
            ("GET", "/v1/users/lin/stats", None),
            ("DELETE", "/v1/users/lin", None),
            ("DELETE", "/v1/users/lin/model", None),
        ]
        with TestClient(app, headers=headers, raise_server_exceptions=False) as anon:
            for method, path, body in routes:
                assert_error(anon.request(method, path, json=body), 401, "Unauthorized")
        assert state(robot, ep) == before

    @pytest.mark.one_engine
    def test_401_on_episode_routes(
        self, client: TestClient, robot: TestClient, ep: dict[str, Any]
    ) -> None:
        before = state(robot, ep)
        eid = ep["episode_id"]
        assert_error(client.get(f"/v1/episodes/{eid}"), 401, "Unauthorized")
        assert_error(
            client.post(
                f"/v1/episodes/{eid}/outcomes",
                json={"decision_id": ep["decision"]["decision_id"], "response": "accepted"},
            ),
            401,
            "Unauthorized",
        )
        assert_error(
            client.post(
                f"/v1/episodes/{eid}/feedback", json={"feedback_id": "f", "feedback": "positive"}
            ),
            401,
            "Unauthorized",
        )
        assert state(robot, ep) == before

    @pytest.mark.one_engine
    def test_the_scheme_is_case_insensitive(self, app: FastAPI, make_key: Any) -> None:
        key = make_key("robot")
        with TestClient(app, headers={"Authorization": f"bearer {key}"}) as c:
            assert c.get("/v1/users").status_code == 200

    def test_a_revoked_key_is_401(
        self,
        app: FastAPI,
        db: Database,
        make_key: Any,
        robot: TestClient,
        ep: dict[str, Any],
        key_clock: Any,
    ) -> None:
        secret = make_key("robot", name="to-revoke")
        with TestClient(
            app, headers={"Authorization": f"Bearer {secret}"}, raise_server_exceptions=False
        ) as c:
            assert c.get("/v1/users/lin").status_code == 200
            with db.transaction() as session:
                [key] = [k for k in list_keys(session) if k.name == "to-revoke"]
                assert secret.startswith(key.prefix)
                revoke_key(session, key.id)
            key_clock.advance(app.state.settings.key_cache_seconds)
            before = state(robot, ep)
            assert_error(c.get("/v1/users/lin"), 401, "Unauthorized")
            assert_error(
                c.post("/v1/users/lin/episodes", json=event("e-revoked")), 401, "Unauthorized"
            )
            assert_error(
                c.post(
                    f"/v1/episodes/{ep['episode_id']}/outcomes",
                    json={"decision_id": ep["decision"]["decision_id"], "response": "accepted"},
                ),
                401,
                "Unauthorized",
            )
            assert state(robot, ep) == before
        assert robot.get("/v1/users/lin").status_code == 200  # other keys still work

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        ("method", "path"),
        [
            ("DELETE", "/v1/users/lin"),
            ("DELETE", "/v1/users/lin/model"),
            ("GET", "/v1/users/lin/model/export"),
            ("PUT", "/v1/users/lin/model"),
        ],
    )
    def test_robot_is_403_on_admin_routes(
        self, robot: TestClient, ep: dict[str, Any], method: str, path: str
    ) -> None:
        before = state(robot, ep)
        r = robot.request(method, path, json={} if method == "PUT" else None)
        assert_error(r, 403, "Forbidden")
        assert state(robot, ep) == before


@pytest.mark.one_engine
class TestUnknownRoutes:
    @pytest.mark.parametrize(
        ("method", "path"),
        [
            ("GET", "/nope"),
            ("GET", "/v1/nope"),
            ("GET", "/v2/users"),
            ("POST", "/v1/things"),
            ("GET", "/v1/users/lin/nope"),
        ],
    )
    def test_unknown_route_is_404_json(self, robot: TestClient, method: str, path: str) -> None:
        assert_error(robot.request(method, path), 404, "NotFound")

    def test_unknown_route_without_key_is_404_json(self, client: TestClient) -> None:
        assert_error(client.get("/nope"), 404, "NotFound")

    def test_wrong_method_is_405_json(self, robot: TestClient) -> None:
        r = robot.patch("/v1/users/lin", json={})
        assert_error(r, 405)


# A broad sweep: every write route with many bad bodies; never a 500, always the error shape.
BAD_BODIES: list[Any] = [
    None,
    [],
    [1, 2],
    "x",
    0,
    1.5,
    True,
    {},
    {"": ""},
    {"a": {"b": {"c": []}}},
    {"event_id": None},
    {"decision_id": "x" * 10_000},
    {"feedback_id": "\u0000"},
    {"learner": {"algorithm": "hri", "params": {"tau": "0.01"}}},
    {"learner": {"algorithm": "hri", "params": {"tau": 10**400}}},
    {"learner": {"algorithm": "qlearning", "params": {"alpha": -1}}},
    {"learner": {"algorithm": "rmax", "params": {"m": 2.5}}},
    {"situation": "working", "occurred_at": "2026-11-22T15:10:00+25:00", "event_id": "e"},
    {"format": "attune.learner-state", "format_version": 1, "algorithm": "hri"},
    {"format": "attune.learner-state", "format_version": 99},
    {
        "format": "attune.learner-state",
        "format_version": 1,
        "algorithm": "hri",
        "mission": "office",
        "params": {},
        "arrays": [],
        "pending": [],
        "episodes": 0,
        "version": 0,
    },
]


@pytest.mark.parametrize("body", BAD_BODIES, ids=[f"body{i}" for i in range(len(BAD_BODIES))])
def test_no_bad_body_is_a_server_error(admin: TestClient, ep: dict[str, Any], body: Any) -> None:
    """Every write route with this body: never a 500, the error shape, nothing changed."""
    routes = [
        ("PUT", "/v1/users/lin"),
        ("POST", "/v1/users/lin/episodes"),
        ("POST", f"/v1/episodes/{ep['episode_id']}/outcomes"),
        ("POST", f"/v1/episodes/{ep['episode_id']}/feedback"),
        ("PUT", "/v1/users/lin/model"),
    ]
    before = state(admin, ep)
    for method, path in routes:
        r = admin.request(
            method, path, content=json.dumps(body), headers={"Content-Type": "application/json"}
        )
        assert r.status_code != 500, (method, path, r.text)
        if r.status_code >= 400:
            assert_error(r, r.status_code)
        else:  # only an empty PUT of a user is valid: an update that changes nothing
            assert (method, path) == ("PUT", "/v1/users/lin"), r.text
            assert body in ({}, None), r.text
    assert state(admin, ep) == before


# -- strict input, the same on both engines -----------------------------------------------------
@pytest.mark.one_engine  # refused by validation, before any SQL
class TestStrictBooleans:
    """Where the contract says boolean, only a boolean: JSON true/false in a body, the words
    true/false in a query."""

    @pytest.mark.parametrize("value", ["no", "yes", "true", 0, 1, None, "", [], {}])
    def test_the_prior_switch_takes_a_boolean_only(self, staff: TestClient, value: Any) -> None:
        before = staff.get("/v1/admin/fleets/default/prior").json()
        r = staff.put("/v1/admin/fleets/default/prior", json={"enabled": value})
        body = assert_error(r, 422, "ValidationError")
        assert body["detail"].startswith("body.enabled: "), body
        assert staff.get("/v1/admin/fleets/default/prior").json() == before

    @pytest.mark.parametrize("value", ["yes", "false", 0, 1, 0.0, "null"])
    def test_fleet_prior_takes_a_boolean_only(
        self, staff: TestClient, ep: dict[str, Any], value: Any
    ) -> None:
        before = state(staff, ep)
        for user in ("lin", "newbie"):
            r = staff.put(f"/v1/users/{user}", json={"fleet_prior": value})
            body = assert_error(r, 422, "ValidationError")
            assert body["detail"].startswith("body.fleet_prior: "), body
        assert state(staff, ep) == before
        assert staff.get("/v1/users/newbie").status_code == 404

    @pytest.mark.parametrize("value", ["yes", "no", "1", "0", "on", "off", "True", "FALSE", ""])
    def test_reset_model_is_true_or_false(
        self, staff: TestClient, ep: dict[str, Any], value: str
    ) -> None:
        before = state(staff, ep)
        r = staff.put(f"/v1/users/lin?reset_model={value}", json={"learner": {"algorithm": "rmax"}})
        body = assert_error(r, 422, "ValidationError")
        assert body["detail"] == "query.reset_model: Input should be true or false.", body
        assert state(staff, ep) == before

    def test_true_and_false_are_taken(self, staff: TestClient, ep: dict[str, Any]) -> None:
        assert staff.put("/v1/users/lin?reset_model=false", json={}).status_code == 200
        assert staff.put("/v1/users/lin?reset_model=true", json={}).status_code == 200
        r = staff.put("/v1/users/lin", json={"fleet_prior": False})
        assert (r.status_code, r.json()["fleet_prior"]) == (200, False)
        r = staff.put("/v1/admin/fleets/default/prior", json={"enabled": False})
        assert (r.status_code, r.json()["enabled"]) == (200, False)


class TestNul:
    """U+0000 in any text that comes in (body, path, query) is 422 naming the field, before any
    SQL, on SQLite as on PostgreSQL (which could not store it); nothing is stored."""

    def test_in_a_display_name(self, robot: TestClient, staff: TestClient) -> None:
        r = robot.put("/v1/users/lin", json={"display_name": "Mrs.\u0000Lin"})
        assert_nul(r, ["body", "display_name"])
        assert robot.get("/v1/users/lin").status_code == 404
        assert robot.put("/v1/users/lin", json={"display_name": "Mrs. Lin"}).status_code == 201
        assert_nul(
            staff.put("/v1/users/lin", json={"display_name": "\u0000"}), ["body", "display_name"]
        )
        assert robot.get("/v1/users/lin").json()["display_name"] == "Mrs. Lin"

    def test_in_a_note(self, staff: TestClient, ep: dict[str, Any]) -> None:
        before = state(staff, ep)
        r = staff.post(
            "/v1/users/lin/corrections",
            json={
                "correction_id": "c1",
                "time_slot": "afternoon",
                "situation": "stretching",
                "kind": "quiet",
                "note": "after\u0000lunch",
            },
        )
        assert_nul(r, ["body", "note"])
        assert staff.get("/v1/users/lin/corrections").json()["items"] == []
        assert state(staff, ep) == before

    @pytest.mark.parametrize("eid", ["%00", "ep%00x", "ep_" + "0" * 31 + "%00"])
    def test_in_an_episode_id(self, robot: TestClient, ep: dict[str, Any], eid: str) -> None:
        before = state(robot, ep)
        assert_nul(robot.get(f"/v1/episodes/{eid}"), ["path", "episode_id"])
        outcome = {"decision_id": "d", "response": "accepted"}
        r = robot.post(f"/v1/episodes/{eid}/outcomes", json=outcome)
        assert_nul(r, ["path", "episode_id"])
        feedback = {"feedback_id": "f", "feedback": "positive"}
        assert_nul(
            robot.post(f"/v1/episodes/{eid}/feedback", json=feedback), ["path", "episode_id"]
        )
        assert state(robot, ep) == before

    def test_in_an_id_with_a_pattern(self, admin: TestClient) -> None:
        """Ids have a pattern, which refuses the character first (422 naming the id too)."""
        for method in ("PUT", "GET", "DELETE"):
            err = assert_error(admin.request(method, "/v1/users/a%00b"), 422, "ValidationError")
            assert err["detail"].startswith("path.user_id: String should match pattern"), err
        err = assert_error(admin.get("/v1/users?fleet=default%00"), 422, "ValidationError")
        assert err["detail"].startswith("query.fleet: String should match pattern"), err
        assert admin.get("/v1/users").json()["items"] == []

    @pytest.mark.parametrize(
        ("query", "where"),
        [
            ("time_slot=%00", ["query", "time_slot"]),
            ("situation=busy%00", ["query", "situation"]),
            ("x%00=1", ["query", "x\u0000"]),
        ],
    )
    def test_in_a_query(
        self, robot: TestClient, ep: dict[str, Any], query: str, where: list[str]
    ) -> None:
        assert_nul(robot.get(f"/v1/users/lin/model?{query}"), where)

    @pytest.mark.parametrize(
        ("change", "where"),
        [
            ({"situation": "busy\u0000"}, ["body", "situation"]),
            (
                {"initiator": "human", "request": {"service": "Provide\u0000Drink"}},
                ["body", "request", "service"],
            ),
        ],
    )
    def test_in_an_event(
        self, robot: TestClient, ep: dict[str, Any], change: dict[str, Any], where: list[str]
    ) -> None:
        before = state(robot, ep)
        assert_nul(robot.post("/v1/users/lin/episodes", json={**event("e-nul"), **change}), where)
        assert_nul(
            robot.post("/v1/users/newbie/episodes", json={**event("e-nul"), **change}), where
        )
        assert state(robot, ep) == before
        assert robot.get("/v1/users/newbie").status_code == 404

    def test_every_field_is_named(self, staff: TestClient, ep: dict[str, Any]) -> None:
        body = {
            "correction_id": "c1",
            "time_slot": "after\u0000noon",
            "situation": "\u0000",
            "kind": "quiet",
            "note": "a\u0000",
        }
        r = staff.post("/v1/users/lin/corrections?situation=%00", json=body)
        assert_nul(
            r,
            ["query", "situation"],
            ["body", "time_slot"],
            ["body", "situation"],
            ["body", "note"],
        )

    def test_deep_in_a_document_and_in_a_key(self, admin: TestClient, ep: dict[str, Any]) -> None:
        before = state(admin, ep)
        doc = admin.get("/v1/users/lin/model/export").json()
        nested = {**doc, "mission": {**doc["mission"], "name": "office\u0000"}}
        assert_nul(admin.put("/v1/users/lin/model", json=nested), ["body", "mission", "name"])
        keyed = {**doc, "params": {**doc["params"], "tau\u0000": 1}}
        assert_nul(admin.put("/v1/users/lin/model", json=keyed), ["body", "params", "tau\u0000"])
        listed = {**doc, "pending": ["\u0000"]}
        assert_nul(admin.put("/v1/users/lin/model", json=listed), ["body", "pending", "0"])
        assert state(admin, ep) == before

    def test_in_a_mission(self, staff: TestClient, ep: dict[str, Any]) -> None:
        mission = staff.get("/v1/mission").json()
        doc = {
            k: mission[k]
            for k in ("name", "time_slots", "situations", "services", "rewards", "gamma")
            if k in mission
        }
        doc["situations"] = [*doc["situations"], "asleep\u0000"]
        r = staff.put("/v1/admin/fleets/default/mission", json={"change_id": "m1", "mission": doc})
        at = len(doc["situations"]) - 1
        assert_nul(r, ["body", "mission", "situations", str(at)])
        assert staff.get("/v1/mission").json() == mission

    def test_an_escaped_backslash_is_no_nul(self, robot: TestClient) -> None:
        """The text \\u0000 (a backslash, then u0000) is six ordinary characters."""
        r = robot.put("/v1/users/lin", json={"display_name": "\\u0000"})
        assert r.status_code == 201, r.text
        assert robot.get("/v1/users/lin").json()["display_name"] == "\\u0000"

    def test_in_the_consoles_search_and_forms(
        self, app: FastAPI, make_key: Any, robot: TestClient, ep: dict[str, Any]
    ) -> None:
        """The console's pages go through the same rule (its error page, 422)."""
        secret = make_key("staff")
        with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as console:
            console.cookies.set(COOKIE, secret, path="/admin")
            page = console.get("/admin/users?q=%00")
            assert page.status_code == 422
            assert "query.q: Text must not contain the NUL character" in page.text
            form = {
                "csrf": csrf_token(secret),
                "correction_id": "c1",
                "time_slot": "afternoon",
                "situation": "stretching",
                "kind": "quiet",
                "note": "after\u0000lunch",
            }
            r = console.post("/admin/users/lin/corrections", data=form)
            assert r.status_code == 422, r.text
            assert "form.note: Text must not contain the NUL character" in r.text
        assert robot.get("/v1/users/lin/corrections").json()["items"] == []

    @pytest.mark.one_engine
    def test_no_key_is_401_first(self, client: TestClient) -> None:
        assert_error(client.put("/v1/users/a%00b", json={"display_name": "\u0000"}), 401)


DOT_IDS = ["%2E", "%2E%2E", "%2e%2e"]


class TestDotIds:
    """``.`` and ``..`` match the ids' pattern but mean this path and its parent in a URL: no
    client-chosen id may be one (422 saying why), so nothing is made that no URL could open."""

    @pytest.mark.one_engine
    @pytest.mark.parametrize("uid", DOT_IDS)
    def test_user_ids(self, admin: TestClient, uid: str) -> None:
        for method, suffix, body in [
            ("PUT", "", {}),
            ("GET", "", None),
            ("DELETE", "", None),
            ("POST", "/episodes", event("e1")),
            ("GET", "/model", None),
            ("GET", "/profile", None),
            ("POST", "/corrections", None),
        ]:
            r = admin.request(method, f"/v1/users/{uid}{suffix}", json=body)
            err = assert_error(r, 422, "ValidationError")
            assert err["detail"].startswith("path.user_id: '."), err
            assert "URL path" in err["detail"], err
        assert admin.get("/v1/users").json()["items"] == []

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        ("method", "path", "where"),
        [
            ("GET", "/v1/users?fleet=.", "query.fleet"),
            ("GET", "/v1/users/lin?fleet=..", "query.fleet"),
            ("GET", "/v1/mission?fleet=..", "query.fleet"),
            ("GET", "/v1/admin/fleets/%2E%2E/prior", "path.fleet"),
            ("PUT", "/v1/admin/fleets/%2E/prior", "path.fleet"),
            ("DELETE", "/v1/users/lin/corrections/%2E%2E", "path.correction_id"),
        ],
    )
    def test_fleets_and_corrections_in_paths_and_queries(
        self, admin: TestClient, method: str, path: str, where: str
    ) -> None:
        body = {"enabled": False} if method == "PUT" else None
        err = assert_error(admin.request(method, path, json=body), 422, "ValidationError")
        assert err["detail"].startswith(f"{where}: '."), err

    @pytest.mark.parametrize(
        ("path", "body", "where"),
        [
            ("/v1/users/lin/episodes", event("."), "body.event_id"),
            ("/v1/users/lin/episodes", {**event("e2"), "robot_id": ".."}, "body.robot_id"),
            ("/v1/admin/keys", {"role": "robot", "fleet": ".."}, "body.fleet"),
            (
                "/v1/users/lin/corrections",
                {
                    "correction_id": "..",
                    "time_slot": "afternoon",
                    "situation": "busy",
                    "kind": "quiet",
                },
                "body.correction_id",
            ),
        ],
    )
    def test_ids_in_bodies(
        self, admin: TestClient, ep: dict[str, Any], path: str, body: dict[str, Any], where: str
    ) -> None:
        before = state(admin, ep)
        keys = admin.get("/v1/admin/keys").json()
        err = assert_error(admin.post(path, json=body), 422, "ValidationError")
        assert err["detail"].startswith(f"{where}: '."), err
        assert state(admin, ep) == before
        assert admin.get("/v1/admin/keys").json() == keys

    def test_the_command_line_cannot_make_a_key_of_fleet_dot(self, db: Database) -> None:
        for fleet in (".", ".."):
            with pytest.raises(ValidationFailed, match="neither"), db.transaction() as session:
                create_key(session, role="robot", fleet=fleet)
        with db.transaction() as session:
            assert list_keys(session) == []

    def test_dots_among_other_characters_are_ids(self, robot: TestClient) -> None:
        for uid in ("...", ".a", "a..b", "..." + "x"):
            r = robot.put(f"/v1/users/{uid}")
            assert r.status_code == 201, (uid, r.text)
            assert robot.get(f"/v1/users/{uid}").json()["user_id"] == uid


@pytest.mark.one_engine
class TestOccurredAt:
    @pytest.mark.parametrize("value", ["1700000000", "1700000000.5", "-1", "1e9", 1700000000, True])
    def test_a_number_is_not_a_time(
        self, robot: TestClient, ep: dict[str, Any], value: Any
    ) -> None:
        before = state(robot, ep)
        r = robot.post("/v1/users/lin/episodes", json={**event("e-num"), "occurred_at": value})
        err = assert_error(r, 422, "ValidationError")
        assert err["detail"] == (
            "body.occurred_at: occurred_at must be an RFC 3339 date-time with an offset, as "
            "text (2026-11-22T15:10:00+08:00), not a number of seconds."
        ), err
        assert state(robot, ep) == before

    @pytest.mark.parametrize("value", ["2026-11-22", "yesterday", "15:10:00+08:00", ""])
    def test_a_date_time_it_must_be(
        self, robot: TestClient, ep: dict[str, Any], value: str
    ) -> None:
        r = robot.post("/v1/users/lin/episodes", json={**event("e-bad"), "occurred_at": value})
        err = assert_error(r, 422, "ValidationError")
        assert err["detail"].startswith("body.occurred_at: occurred_at must be an RFC 3339"), err

    @pytest.mark.parametrize(
        "value",
        ["2026-11-22T15:10:00+08:00", "2026-11-22 15:10:00Z", "2026-11-22t15:10:00.5-03:30"],
    )
    def test_rfc_3339_is_taken(self, robot: TestClient, value: str) -> None:
        r = robot.post("/v1/users/lin/episodes", json={**event("e-ok"), "occurred_at": value})
        assert r.status_code == 201, r.text
