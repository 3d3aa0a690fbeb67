"""Service endpoints: liveness, readiness (and the drain), metrics (what they count, who may read
them), the mission, and the OpenAPI document."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import psycopg
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families
from pydantic import SecretStr
from sqlalchemy import event
from sqlalchemy.pool import Pool

from app.main import create_app
from app.settings import Settings
from tests.support import people
from tests.support.contract import assert_error
from tests.support.episodes import report, start

TOKEN = "metrics-token-of-the-tests-0123456789"

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
    "/livez": {"get"},
    "/healthz": {"get"},
    "/readyz": {"get"},
    "/metrics": {"get"},
}
OPEN = {"/livez", "/healthz", "/readyz", "/metrics"}
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
            assert c.get("/livez").status_code == 200
            assert c.get("/healthz").status_code == 200
            assert c.get("/readyz").status_code == 200
            assert c.get("/metrics").status_code == 200

    @pytest.mark.one_engine
    def test_livez_answers_while_the_process_runs(self, client: TestClient) -> None:
        r = client.get("/livez")
        assert r.status_code == 200
        assert r.json() == {"status": "ok"}
        assert client.head("/livez").status_code == 200


class TestDrain:
    """What a worker that was told to stop (SIGTERM, SIGINT: ``attune serve`` calls the drain)
    answers: not ready at once, still alive, and still serving the requests that reach it."""

    def test_readyz_turns_503_and_livez_stays_200(
        self, app: FastAPI, client: TestClient, robot: TestClient
    ) -> None:
        r = client.get("/readyz")
        assert r.status_code == 200
        assert "connection" not in r.headers  # keep-alive as usual
        app.state.drain.begin()
        assert_error(client.get("/readyz"), 503, "ServiceUnavailable")
        assert "shutting down" in client.get("/readyz").json()["detail"]
        assert client.get("/livez").status_code == 200
        # A request that still reaches the worker is served: the robot's write is stored; its
        # connection closes, so that the client's next request goes where the balancer sends it.
        ep = start(robot, "lin", "e1")
        r = robot.get(f"/v1/episodes/{ep['episode_id']}")
        assert r.status_code == 200
        assert r.headers["connection"] == "close"
        app.state.metrics.sample()
        assert _sample(app, "attune_draining") == 1.0

    def test_the_drain_is_where_the_server_looks_for_it(self) -> None:
        from app.api.lifecycle import STATE_KEY
        from app.commands.supervisor import DRAIN_STATE_KEY

        assert STATE_KEY == DRAIN_STATE_KEY


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


def _sample(app: FastAPI, name: str, labels: dict[str, str] | None = None) -> float | None:
    value = app.state.metrics.registry.get_sample_value(name, labels or {})
    return None if value is None else float(value)


def _play(robot: TestClient, user: str, event_id: str, need: people.Need | None) -> dict[str, Any]:
    """One episode to its end, the person answering as ``people.answer``; its last brief."""
    ep = start(robot, user, event_id)
    decision = ep["decision"]
    for _ in range(20):
        out = report(
            robot,
            ep["episode_id"],
            decision["decision_id"],
            **people.answer(decision["action"], need=need),
        )
        if out["decision"] is None:
            brief: dict[str, Any] = out["episode"]
            return brief
        decision = out["decision"]
    raise AssertionError("the episode did not end within 20 steps")


class TestOperatorMetrics:
    """What an operator watches: each family the dashboard and the alerts use, with values that
    follow what happened."""

    def test_learning_health_per_fleet(self, app: FastAPI, robot: TestClient) -> None:
        briefs = [_play(robot, f"u{i}", f"e{i}", people.TEA if i % 2 else None) for i in range(6)]
        assert _sample(app, "attune_episodes_ended_total", {"fleet": "default"}) == len(briefs)
        positive = sum(b["total_reward"] for b in briefs if b["total_reward"] > 0)
        negative = -sum(b["total_reward"] for b in briefs if b["total_reward"] < 0)
        assert positive > 0  # people with a need
        assert negative > 0  # and people without
        assert _sample(
            app, "attune_episode_reward_positive_total", {"fleet": "default"}
        ) == pytest.approx(positive)
        assert _sample(
            app, "attune_episode_reward_negative_total", {"fleet": "default"}
        ) == pytest.approx(negative)
        # No label names a person: the families carry fleets, routes, kinds and responses.
        text = robot.get("/metrics").text
        for family in text_string_to_metric_families(text):
            for sample in family.samples:
                assert not {"user", "user_id", "person"} & set(sample.labels), sample
                assert "u1" not in sample.labels.values(), sample

    def test_a_replayed_outcome_is_not_counted_again(self, app: FastAPI, robot: TestClient) -> None:
        ep = start(robot, "lin", "e1")
        url, decision = f"/v1/episodes/{ep['episode_id']}/outcomes", ep["decision"]
        for _ in range(20):
            body = {"decision_id": decision["decision_id"], **people.answer(decision["action"])}
            out = robot.post(url, json=body).json()
            if out["decision"] is None:
                break
            decision = out["decision"]
        assert out["episode"]["status"] == "closed"
        again = robot.post(url, json=body)  # the robot did not get the answer: it sends again
        assert again.status_code == 200
        assert again.headers.get("Idempotent-Replay") == "true"
        assert _sample(app, "attune_episodes_ended_total", {"fleet": "default"}) == 1.0

    def test_the_process_the_pool_and_the_cache(self, app: FastAPI, robot: TestClient) -> None:
        _play(robot, "lin", "e1", people.TEA)
        _play(robot, "lin", "e2", people.TEA)
        app.state.metrics.sample()
        assert (_sample(app, "attune_process_cpu_seconds_total") or 0) > 0
        assert (_sample(app, "attune_process_resident_memory_bytes") or 0) > 10e6
        assert _sample(app, "attune_workers") == 1.0
        db = app.state.db
        assert _sample(app, "attune_db_pool_connections_max") == db.engine.pool.capacity
        assert _sample(app, "attune_db_pool_connections_in_use") == 0.0  # between requests
        assert _sample(app, "attune_db_pool_waits_total") == 0.0
        hits = _sample(app, "attune_learner_cache_hits_total") or 0
        misses = _sample(app, "attune_learner_cache_misses_total") or 0
        assert hits + misses == app.state.ctx.cache.hits + app.state.ctx.cache.misses
        assert hits > 0  # the second episode's writes found the learner decoded
        assert _sample(app, "attune_draining") == 0.0

    def test_a_checkout_that_finds_the_pool_full_is_a_wait(self, app: FastAPI) -> None:
        app.state.metrics.sample()
        pool = app.state.db.engine.pool
        held = [pool.connect() for _ in range(pool.capacity)]
        try:
            app.state.metrics.sample()
            assert _sample(app, "attune_db_pool_connections_in_use") == pool.capacity
            got: list[Any] = []
            waiter = threading.Thread(target=lambda: got.append(pool.connect()))
            waiter.start()
            held.pop().close()  # one comes back: the waiter takes it
            waiter.join(timeout=30)
            assert got, "the waiting checkout got no connection"
            got[0].close()
        finally:
            for connection in held:
                connection.close()
        app.state.metrics.sample()
        assert _sample(app, "attune_db_pool_waits_total") == 1.0
        assert (_sample(app, "attune_db_pool_wait_seconds_total") or 0) > 0

    def test_the_event_loop_lag_is_measured(self, app: FastAPI) -> None:
        with TestClient(app) as c:
            for _ in range(200):  # until the task, which runs with the app, woke twice
                if (_sample(app, "attune_event_loop_lag_seconds_count") or 0) >= 2:
                    break
                c.get("/livez")
                time.sleep(0.1)
            assert (_sample(app, "attune_event_loop_lag_seconds_count") or 0) >= 2
        lag = _sample(app, "attune_event_loop_lag_seconds_sum")
        assert lag is not None
        assert lag >= 0


class TestRoundTrips:
    """``attune_db_round_trips_total``: on PostgreSQL, the round trips a request made, as libpq
    saw them on the wire; SQLite has none."""

    @pytest.fixture
    def wire(self, tmp_path: Path, engine_name: str) -> Iterator[Path]:
        """libpq's trace of every PostgreSQL connection checked out during the test."""
        trace = tmp_path / "wire.txt"
        out = trace.open("w")
        traced: set[int] = set()

        def on_checkout(dbapi_connection: Any, _record: Any, _proxy: Any) -> None:
            pgconn = getattr(dbapi_connection, "pgconn", None)
            if pgconn is not None and id(pgconn) not in traced:
                traced.add(id(pgconn))
                pgconn.trace(out.fileno())
                pgconn.set_trace_flags(psycopg.pq.Trace.SUPPRESS_TIMESTAMPS)

        event.listen(Pool, "checkout", on_checkout)
        try:
            yield trace
        finally:
            event.remove(Pool, "checkout", on_checkout)
            out.close()

    @staticmethod
    def _exchanges(trace: Path, since: int) -> int:
        """Round trips in the trace after byte ``since``: each run of frontend messages that
        the server then answers."""
        lines = trace.read_text()[since:].splitlines()
        runs, last = 0, ""
        for line in lines:
            side = line[:1]
            if side == "F" and last != "F":
                runs += 1
            if side in ("F", "B"):
                last = side
        return runs

    def test_robot_writes_count_what_the_wire_shows(
        self, app: FastAPI, robot: TestClient, wire: Path, engine_name: str
    ) -> None:
        start(robot, "lin", "e0")  # the user is made, the key is cached
        for route, request in (
            ("/v1/users/{user_id}/episodes", "start"),
            ("/v1/episodes/{episode_id}/outcomes", "outcome"),
        ):
            before = _sample(app, "attune_db_round_trips_total", {"route": route}) or 0.0
            mark = wire.stat().st_size
            if request == "start":
                ep = start(robot, "lin", "e1")
            else:
                report(robot, ep["episode_id"], ep["decision"]["decision_id"], "rejected")
            counted = (
                _sample(app, "attune_db_round_trips_total", {"route": route}) or 0.0
            ) - before
            if engine_name == "sqlite":
                assert counted == 0.0  # no round trips to count
                continue
            seen = self._exchanges(wire, mark)
            assert seen >= 3, seen  # BEGIN, the statements, COMMIT
            assert counted == seen, (request, counted, seen)


class TestMetricsAccess:
    """``/metrics`` names fleets: ATTUNE_METRICS_TOKEN puts it behind a token of its own, and
    ATTUNE_METRICS_PORT moves it off the service's port."""

    @pytest.fixture
    def guarded(self, database_url: str) -> Iterator[TestClient]:
        app = create_app(
            Settings(database_url=database_url, metrics_token=SecretStr(TOKEN), _env_file=None)  # type: ignore[call-arg]
        )
        try:
            with TestClient(app, raise_server_exceptions=False) as c:
                yield c
        finally:
            app.state.db.dispose()

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        "authorization",
        [None, "Bearer wrong-token-wrong-token", f"Basic {TOKEN}", f"Bearer {TOKEN}x", "Bearer"],
    )
    def test_without_the_token_401(self, guarded: TestClient, authorization: str | None) -> None:
        headers = {"Authorization": authorization} if authorization else {}
        r = guarded.get("/metrics", headers=headers)
        assert_error(r, 401, "Unauthorized")
        assert r.headers["www-authenticate"].startswith("Bearer")
        assert "ATTUNE_METRICS_TOKEN" in r.json()["detail"]
        assert TOKEN not in r.text

    @pytest.mark.one_engine
    def test_with_the_token_the_metrics(self, guarded: TestClient) -> None:
        r = guarded.get("/metrics", headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 200
        assert "attune_http_requests_total" in r.text
        # The probes stay open: an orchestrator has no token.
        assert guarded.get("/livez").status_code == 200
        assert guarded.get("/readyz").status_code == 200

    @pytest.mark.one_engine
    def test_a_metrics_port_moves_them_off_this_one(self, database_url: str) -> None:
        app = create_app(
            Settings(database_url=database_url, metrics_port=9100, _env_file=None)  # type: ignore[call-arg]
        )
        try:
            with TestClient(app, raise_server_exceptions=False) as c:
                r = c.get("/metrics")
        finally:
            app.state.db.dispose()
        assert_error(r, 404, "NotFound")
        assert "ATTUNE_METRICS_PORT" in r.json()["detail"]


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
