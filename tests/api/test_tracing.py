"""Requests can be traced: the X-Request-ID of every response, the id in the request's log lines
and error body, one access line per request, and an unhandled error logged once."""

from __future__ import annotations

import io
import json
import logging
import re
import sys
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app import logs
from app.api.middleware import InFlightLimitMiddleware
from app.db.session import Database
from app.main import create_app
from app.services.auth import create_key
from app.settings import Settings
from tests.support.contract import assert_error
from tests.support.episodes import event
from tests.support.live import serving

# Request ids and log lines: the same on both engines.
pytestmark = pytest.mark.one_engine

FRESH = re.compile(r"^[0-9a-f]{32}$")
LOCAL = ("127.0.0.1", 50000)  # a trusted peer by default: its X-Request-ID is kept


class Lines:
    """The JSON log lines of the ``attune`` loggers, as the service writes them."""

    def __init__(self) -> None:
        self.stream = io.StringIO()

    def all(self) -> list[dict[str, Any]]:
        return [json.loads(line) for line in self.stream.getvalue().splitlines()]

    def text(self) -> str:
        return self.stream.getvalue()

    def access(self) -> list[dict[str, Any]]:
        return [line for line in self.all() if line["logger"] == "attune.access"]

    def of(self, request_id: str) -> list[dict[str, Any]]:
        return [line for line in self.all() if line.get("request_id") == request_id]


@pytest.fixture
def lines() -> Iterator[Lines]:
    """Capture what ``attune serve`` would write with ATTUNE_LOG_FORMAT=json."""
    captured = Lines()
    handler = logging.StreamHandler(captured.stream)
    handler.addFilter(logs.RequestIdFilter())
    handler.setFormatter(logs.JsonFormatter())
    root = logging.getLogger("attune")
    level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    try:
        yield captured
    finally:
        root.removeHandler(handler)
        root.setLevel(level)


def _key(db: Database, role: str = "robot") -> tuple[str, str]:
    """(key id, secret) of a new key."""
    with db.transaction() as session:
        key, secret = create_key(session, role=role)
    return key.id, secret


def _in_flight(app: FastAPI) -> InFlightLimitMiddleware:
    layer: Any = app.middleware_stack
    while not isinstance(layer, InFlightLimitMiddleware):
        layer = layer.app
    return layer


class TestRequestId:
    @pytest.mark.parametrize(
        "given", ["abc", "A.b_c:d-1", "x" * 128, "0" * 32, "7b1e4c1f-2e0a-4a51-9f0b-4d9a2f7d0e11"]
    )
    def test_a_valid_id_is_kept(self, robot: TestClient, given: str) -> None:
        r = robot.get("/v1/users/nobody", headers={"X-Request-ID": given})
        assert r.headers["x-request-id"] == given
        assert assert_error(r, 404, "NotFound")["request_id"] == given

    @pytest.mark.parametrize("given", ["", "a b", "x" * 129, "a/b", "a;b", "<script>", "é"])
    def test_an_invalid_id_is_replaced_by_a_fresh_one(self, robot: TestClient, given: str) -> None:
        r = robot.get("/v1/users/nobody", headers={"X-Request-ID": given.encode("utf-8")})
        assert FRESH.match(r.headers["x-request-id"]), r.headers["x-request-id"]
        assert assert_error(r, 404, "NotFound")["request_id"] == r.headers["x-request-id"]

    def test_ids_are_fresh_for_each_request(self, robot: TestClient) -> None:
        ids = {robot.get("/healthz").headers["x-request-id"] for _ in range(5)}
        assert len(ids) == 5
        assert all(FRESH.match(i) for i in ids)

    def test_every_kind_of_response_carries_it(
        self, app: FastAPI, robot: TestClient, admin: TestClient, client: TestClient
    ) -> None:
        assert robot.put("/v1/users/lin", json={}).status_code == 201
        answers = {
            "200": robot.get("/v1/users/lin"),
            "204": admin.delete("/v1/users/lin/model"),
            "HEAD": robot.head("/v1/users/lin"),
            "healthz": client.get("/healthz"),
            "readyz": client.get("/readyz"),
            "metrics": client.get("/metrics"),
            "docs": client.get("/docs"),
            "static": client.get("/static/docs/redoc/LICENSE"),
            "console": client.get("/admin/login"),
            "400": robot.post(
                "/v1/users/lin/episodes", content=b"{", headers={"Content-Type": "application/json"}
            ),
            "401": client.get("/v1/users"),
            "403": robot.delete("/v1/users/lin"),
            "404": robot.get("/v1/nothing"),
            "405": robot.patch("/v1/users/lin"),
            "413": robot.post(
                "/v1/users/lin/episodes",
                content=b"x" * 70_000,
                headers={"Content-Type": "application/json"},
            ),
            "415": robot.post(
                "/v1/users/lin/episodes", content=b"{}", headers={"Content-Type": "text/plain"}
            ),
            "422": robot.get("/v1/users?limit=0"),
        }
        limiter = _in_flight(app)
        limiter.in_flight = limiter.limit  # as if every slot were taken
        try:
            answers["503"] = robot.get("/v1/users")
        finally:
            limiter.in_flight = 0
        for name, r in answers.items():
            rid = r.headers.get("x-request-id")
            assert rid, name
            if r.status_code >= 400:
                assert str(r.status_code) == name or name == "HEAD", (name, r.status_code)
                if name != "HEAD":
                    assert r.json()["request_id"] == rid, name

    def test_429_carries_it(self, settings: Settings, db: Database) -> None:
        app = create_app(
            settings.model_copy(update={"rate_limit_per_s": 0.001, "rate_limit_burst": 1})
        )
        try:
            _, secret = _key(db)
            with TestClient(
                app,
                headers={"Authorization": f"Bearer {secret}"},
                raise_server_exceptions=False,
                client=LOCAL,
            ) as c:
                c.get("/v1/users")
                r = c.get("/v1/users", headers={"X-Request-ID": "slow-down"})
                assert assert_error(r, 429, "TooManyRequests")["request_id"] == "slow-down"
                assert r.headers["x-request-id"] == "slow-down"
        finally:
            app.state.db.dispose()

    def test_a_response_never_carries_two(self, robot: TestClient) -> None:
        r = robot.get("/healthz", headers={"X-Request-ID": "one"})
        assert r.headers.get_list("x-request-id") == ["one"]


class TestAccessLine:
    def test_one_line_per_request_with_its_fields(
        self, app: FastAPI, db: Database, lines: Lines
    ) -> None:
        key_id, secret = _key(db)
        with TestClient(
            app,
            headers={"Authorization": f"Bearer {secret}"},
            raise_server_exceptions=False,
            client=LOCAL,
        ) as c:
            c.put("/v1/users/lin", json={}, headers={"X-Request-ID": "put-lin"})
            c.post("/v1/users/lin/episodes", json=event("e1"), headers={"X-Request-ID": "ev-1"})
            c.get("/v1/users/nobody", headers={"X-Request-ID": "get-nobody"})
        access = lines.access()
        assert [a["request_id"] for a in access] == ["put-lin", "ev-1", "get-nobody"]
        put, post, get = access
        assert put["method"] == "PUT"
        assert put["route"] == "/v1/users/{user_id}"
        assert put["status"] == 201
        assert post["route"] == "/v1/users/{user_id}/episodes"
        assert post["status"] == 201
        assert get["status"] == 404
        for line in access:
            assert line["key_id"] == key_id
            assert isinstance(line["latency_ms"], float | int)
            assert line["latency_ms"] >= 0
            assert line["level"] == "INFO"
            assert re.match(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$", line["time"])
            assert f"key_id={key_id}" in line["message"]
        assert secret not in lines.text()
        assert secret[:12] not in lines.text()  # not even the key's public prefix

    def test_early_answers_and_unmatched_paths(
        self, app: FastAPI, client: TestClient, lines: Lines
    ) -> None:
        client.get("/nowhere", headers={"X-Request-ID": "r404"})
        client.post(
            "/v1/users/lin/episodes",
            content=b"x" * 70_000,
            headers={"Content-Type": "application/json", "X-Request-ID": "r413"},
        )
        client.options("/v1/users/lin", headers={"X-Request-ID": "r405"})
        client.head("/v1/users/lin", headers={"X-Request-ID": "rhead"})
        limiter = _in_flight(app)
        limiter.in_flight = limiter.limit
        try:
            client.get("/v1/users", headers={"X-Request-ID": "r503"})
        finally:
            limiter.in_flight = 0
        got = {a["request_id"]: a for a in lines.access()}
        assert set(got) == {"r404", "r413", "r405", "rhead", "r503"}
        assert (got["r404"]["route"], got["r404"]["status"]) == ("unmatched", 404)
        assert (got["r413"]["route"], got["r413"]["status"]) == ("unmatched", 413)
        assert (got["r405"]["route"], got["r405"]["status"]) == ("/v1/users/{user_id}", 405)
        assert (got["rhead"]["method"], got["rhead"]["route"], got["rhead"]["status"]) == (
            "HEAD",
            "/v1/users/{user_id}",
            401,
        )
        assert got["r503"]["status"] == 503
        assert all(a["key_id"] is None for a in got.values())

    def test_console_pages_have_the_admins_key_id(
        self, app: FastAPI, db: Database, lines: Lines
    ) -> None:
        key_id, secret = _key(db, "admin")
        with TestClient(app, raise_server_exceptions=False, client=LOCAL) as c:
            c.cookies.set("attune_console", secret, path="/admin")
            assert c.get("/admin/users", headers={"X-Request-ID": "page"}).status_code == 200
        [line] = lines.access()
        assert (line["route"], line["key_id"], line["status"]) == ("/admin/users", key_id, 200)
        assert secret not in lines.text()


def _failing_app(app: FastAPI) -> FastAPI:
    """The app with two routes that log a line and then fail (one sync, one async)."""
    log = logging.getLogger("attune.test")

    def boom() -> None:
        log.info("about to fail")
        raise RuntimeError("boom")

    async def aboom() -> None:
        log.info("about to fail")
        raise RuntimeError("async boom")

    app.add_api_route("/test/boom", boom)
    app.add_api_route("/test/aboom", aboom)
    return app


class TestUnhandledError:
    @pytest.mark.parametrize("path", ["/test/boom", "/test/aboom"])
    def test_is_a_500_with_the_contract_body_and_logged_once(
        self, app: FastAPI, lines: Lines, path: str
    ) -> None:
        with TestClient(_failing_app(app), raise_server_exceptions=False, client=LOCAL) as c:
            r = c.get(path, headers={"X-Request-ID": "it-failed"})
        body = assert_error(r, 500, "InternalError")
        assert body == {
            "error": "InternalError",
            "request_id": "it-failed",
            "detail": "The server failed; the error was logged.",
        }
        assert "boom" not in r.text
        mine = lines.of("it-failed")
        assert [m["message"] for m in mine][0] == "about to fail"
        errors = [m for m in mine if "exception" in m]
        assert len(errors) == 1, mine
        assert errors[0]["level"] == "ERROR"
        assert errors[0]["logger"] == "attune.api"
        assert "RuntimeError: " in errors[0]["exception"]
        assert errors[0]["message"] == f"unhandled error on GET {path}"
        [access] = [m for m in mine if m["logger"] == "attune.access"]
        assert (access["status"], access["route"]) == (500, path)
        assert all(m.get("request_id") == "it-failed" for m in mine)

    def test_is_logged_once_under_uvicorn(self, app: FastAPI, lines: Lines) -> None:
        """The server does not log it a second time ("Exception in ASGI application")."""
        server_lines = io.StringIO()
        handler = logging.StreamHandler(server_lines)
        with serving(_failing_app(app)) as url:
            uvicorn_log = logging.getLogger("uvicorn.error")
            uvicorn_log.addHandler(handler)
            try:
                r = httpx.get(f"{url}/test/boom", headers={"X-Request-ID": "served"}, timeout=10)
            finally:
                uvicorn_log.removeHandler(handler)
        assert r.status_code == 500
        assert r.headers["x-request-id"] == "served"
        assert r.json()["request_id"] == "served"
        assert "Traceback" not in server_lines.getvalue()
        assert "Exception in ASGI application" not in server_lines.getvalue()
        assert len([m for m in lines.of("served") if "exception" in m]) == 1


class TestFormats:
    def _record(self, exc_info: Any = None) -> logging.LogRecord:
        return logging.LogRecord(
            "attune.x", logging.WARNING, __file__, 1, "hello %s", ("world",), exc_info
        )

    def test_text_lines_end_with_the_request_id(self) -> None:
        fmt = logs.TextFormatter()
        assert fmt.format(self._record()).endswith("WARNING attune.x: hello world")
        token = logs.bind(logs.RequestContext("rid-1"))
        try:
            assert fmt.format(self._record()).endswith(
                "WARNING attune.x: hello world request_id=rid-1"
            )
        finally:
            logs.unbind(token)

    def test_json_lines(self) -> None:
        fmt = logs.JsonFormatter()
        line = fmt.format(self._record())
        assert "\n" not in line
        out = json.loads(line)
        assert set(out) == {"time", "level", "logger", "message"}
        assert (out["level"], out["logger"], out["message"]) == (
            "WARNING",
            "attune.x",
            "hello world",
        )
        token = logs.bind(logs.RequestContext("rid-2", key_id="key_1"))
        try:
            record = self._record()
            record.attune_fields = {"status": 200}
            out = json.loads(fmt.format(record))
        finally:
            logs.unbind(token)
        assert (out["request_id"], out["status"]) == ("rid-2", 200)
        try:
            raise ValueError("bad\nthing")
        except ValueError:
            record = self._record(sys.exc_info())
        line = fmt.format(record)
        assert "\n" not in line
        assert "ValueError: bad" in json.loads(line)["exception"]

    def test_the_serve_configuration(self) -> None:
        config = logs.logging_config("warning", "json")
        assert config["formatters"]["attune"]["()"] is logs.JsonFormatter
        assert config["loggers"]["attune"]["level"] == "WARNING"
        assert config["loggers"]["uvicorn.access"]["handlers"] == []
        assert (
            logs.logging_config("info", "text")["formatters"]["attune"]["()"] is logs.TextFormatter
        )
        with pytest.raises(ValueError, match="log format"):
            logs.logging_config("info", "xml")

    def test_the_setting(self) -> None:
        assert Settings(_env_file=None).log_format == "text"  # type: ignore[call-arg]
        assert Settings(log_format="JSON", _env_file=None).log_format == "json"  # type: ignore[call-arg]
        with pytest.raises(ValueError, match="log_format"):
            Settings(log_format="xml", _env_file=None)  # type: ignore[call-arg]
