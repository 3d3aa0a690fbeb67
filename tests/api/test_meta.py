"""Service endpoints: health, readiness, metrics, the mission, and the OpenAPI document."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.support.contract import assert_error
from tests.support.episodes import report, start

CONTRACT = {
    "/v1/users": {"get"},
    "/v1/users/{user_id}": {"put", "get", "delete"},
    "/v1/users/{user_id}/episodes": {"post", "get"},
    "/v1/episodes/{episode_id}": {"get"},
    "/v1/episodes/{episode_id}/outcomes": {"post"},
    "/v1/episodes/{episode_id}/feedback": {"post"},
    "/v1/users/{user_id}/model": {"get", "delete", "put"},
    "/v1/users/{user_id}/model/export": {"get"},
    "/v1/users/{user_id}/stats": {"get"},
    "/v1/mission": {"get"},
    "/healthz": {"get"},
    "/readyz": {"get"},
    "/metrics": {"get"},
}
OPEN = {"/healthz", "/readyz", "/metrics"}
ADMIN = {
    ("delete", "/v1/users/{user_id}"),
    ("delete", "/v1/users/{user_id}/model"),
    ("get", "/v1/users/{user_id}/model/export"),
    ("put", "/v1/users/{user_id}/model"),
}


class TestHealth:
    @pytest.mark.one_engine
    def test_healthz_needs_no_key(self, client: TestClient) -> None:
        r = client.get("/healthz")
        assert r.status_code == 200
        assert r.json() == {"status": "ok"}

    def test_readyz_needs_no_key(self, client: TestClient) -> None:
        r = client.get("/readyz")
        assert r.status_code == 200, r.text

    def test_readyz_says_a_database_has_no_schema_yet(self, tmp_path: Any) -> None:
        from app.main import create_app
        from app.settings import Settings

        empty = create_app(
            Settings(database_url=f"sqlite:///{tmp_path / 'empty.db'}", _env_file=None)  # type: ignore[call-arg]
        )
        try:
            with TestClient(empty) as c:
                r = c.get("/readyz")
        finally:
            empty.state.db.dispose()
        assert r.status_code == 503
        assert r.json()["detail"].startswith("The database has no schema yet, not ")
        assert "attune db upgrade" in r.json()["detail"]

    @pytest.mark.one_engine
    def test_health_ignores_a_bad_key(self, app: Any) -> None:
        with TestClient(app, headers={"Authorization": "Bearer nope"}) as c:
            assert c.get("/healthz").status_code == 200
            assert c.get("/readyz").status_code == 200
            assert c.get("/metrics").status_code == 200


class TestMetrics:
    def test_prometheus_text_after_an_episode(self, client: TestClient, robot: TestClient) -> None:
        ep = start(
            robot,
            "lin",
            "e1",
            initiator="human",
            request={"service": "ProvideDrink", "detail": "tea"},
        )
        report(robot, ep["episode_id"], ep["decision"]["decision_id"], "accepted")
        robot.get("/v1/users/nobody")
        r = client.get("/metrics")
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/plain")
        text = r.text
        assert "attune_http_requests" in text
        assert "attune_decisions" in text
        assert "attune_outcomes" in text
        assert "attune_http_request_duration_seconds" in text
        assert 'route="/v1/users/{user_id}/episodes"' in text  # per route template
        assert 'kind="perform"' in text
        assert 'status="404"' in text

    def test_replays_are_not_counted_as_new_decisions(
        self, client: TestClient, robot: TestClient
    ) -> None:
        def decisions(text: str) -> float:
            return sum(
                float(line.rsplit(" ", 1)[1])
                for line in text.splitlines()
                if line.startswith("attune_decisions_total{")
            )

        start(robot, "lin", "e1")
        once = decisions(client.get("/metrics").text)
        assert once == 1.0
        robot.post(
            "/v1/users/lin/episodes",
            json={
                "event_id": "e1",
                "occurred_at": "2026-11-22T15:10:00+08:00",
                "situation": "stretching",
                "initiator": "robot",
                "request": None,
                "robot_id": "robot7",
            },
        )
        assert decisions(client.get("/metrics").text) == once


@pytest.mark.one_engine
class TestMission:
    def test_needs_a_key(self, client: TestClient) -> None:
        assert_error(client.get("/v1/mission"), 401, "Unauthorized")

    def test_is_the_office_mission(self, robot: TestClient) -> None:
        r = robot.get("/v1/mission")
        assert r.status_code == 200
        m = r.json()
        assert m["name"] == "office"
        assert m["situations"] == ["arriving", "working", "stretching", "busy"]
        assert m["time_slots"] == [
            {"name": "morning", "start": "06:00", "end": "11:00"},
            {"name": "noon", "start": "11:00", "end": "14:00"},
            {"name": "afternoon", "start": "14:00", "end": "18:00"},
            {"name": "evening", "start": "18:00", "end": "06:00"},
        ]
        assert m["services"] == [
            {"name": "ProvideDrink", "details": ["tea", "coffee", "water"]},
            {"name": "BriefInformation", "details": ["news", "weather", "stocks"]},
            {
                "name": "ArrangeSchedule",
                "details": ["today_agenda", "next_meeting", "set_reminder"],
            },
        ]
        assert m["rewards"] == {
            "positive": 1.0,
            "accepted_service": 5.0,
            "negative": -2.0,
            "query": -0.5,
        }

    def test_admin_sees_the_same(self, robot: TestClient, admin: TestClient) -> None:
        assert admin.get("/v1/mission").json() == robot.get("/v1/mission").json()


def _resolve(spec: dict[str, Any], node: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in node:
        name = node["$ref"].rsplit("/", 1)[1]
        node = spec["components"]["schemas"][name]
    return node


@pytest.mark.one_engine
class TestOpenApi:
    @pytest.fixture
    def spec(self, client: TestClient) -> dict[str, Any]:
        r = client.get("/openapi.json")
        assert r.status_code == 200
        body: dict[str, Any] = r.json()
        return body

    def test_lists_every_contract_path(self, spec: dict[str, Any]) -> None:
        for path, methods in CONTRACT.items():
            assert path in spec["paths"], path
            assert methods <= set(spec["paths"][path]), (path, set(spec["paths"][path]))

    def test_every_v1_operation_declares_its_errors(self, spec: dict[str, Any]) -> None:
        for path, methods in CONTRACT.items():
            if path in OPEN:
                continue
            for method in methods:
                op = spec["paths"][path][method]
                codes = set(op["responses"])
                assert {"401", "422"} <= codes, (method, path, codes)
                if "{" in path:
                    assert "404" in codes, (method, path, codes)
                if (method, path) in ADMIN:
                    assert "403" in codes, (method, path, codes)
                for code in ("401", "422"):
                    content = op["responses"][code]["content"]["application/json"]
                    schema = _resolve(spec, content["schema"])
                    assert {"error", "detail"} <= set(schema["properties"])

    def test_writes_declare_409(self, spec: dict[str, Any]) -> None:
        for path, method in [
            ("/v1/users/{user_id}", "put"),
            ("/v1/users/{user_id}/episodes", "post"),
            ("/v1/episodes/{episode_id}/outcomes", "post"),
            ("/v1/episodes/{episode_id}/feedback", "post"),
        ]:
            assert "409" in spec["paths"][path][method]["responses"], (method, path)

    def test_request_bodies_have_examples(self, spec: dict[str, Any]) -> None:
        seen = 0
        for path, item in spec["paths"].items():
            for method, op in item.items():
                body = op.get("requestBody")
                if body is None:
                    continue
                seen += 1
                media = body["content"]["application/json"]
                schema = _resolve(spec, media.get("schema", {}))
                has = any(k in media for k in ("example", "examples")) or any(
                    k in schema for k in ("example", "examples")
                )
                if not has and "anyOf" in schema:
                    has = any("examples" in _resolve(spec, s) for s in schema["anyOf"])
                assert has, (method, path)
        assert seen >= 5

    def test_replay_header_is_documented(self, spec: dict[str, Any]) -> None:
        for path in (
            "/v1/users/{user_id}/episodes",
            "/v1/episodes/{episode_id}/outcomes",
            "/v1/episodes/{episode_id}/feedback",
        ):
            ok = spec["paths"][path]["post"]["responses"]["200"]
            assert "Idempotent-Replay" in ok.get("headers", {}), path

    def test_created_is_documented(self, spec: dict[str, Any]) -> None:
        assert "201" in spec["paths"]["/v1/users/{user_id}/episodes"]["post"]["responses"]
        assert "201" in spec["paths"]["/v1/users/{user_id}"]["put"]["responses"]

    def test_security_scheme_or_description_mentions_the_key(self, spec: dict[str, Any]) -> None:
        text = spec["info"].get("description", "")
        schemes = spec.get("components", {}).get("securitySchemes", {})
        assert "Bearer" in text or any(s.get("scheme") == "bearer" for s in schemes.values())
