"""HTTP as clients expect it: HEAD on every GET, the Allow header of a 405, 415 for bodies that
are not JSON, bounded integer query parameters, cursors the schema describes, and the
documentation pages served without the internet."""

from __future__ import annotations

import json
import re
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from tests.support.contract import assert_error
from tests.support.episodes import event, start
from tests.support.fixtures import MakeKey

TEA = {"service": "ProvideDrink", "detail": "tea"}
# Headers that differ between two answers to the same request, whatever the method.
VOLATILE = {"date", "x-request-id"}


@pytest.fixture
def world(app: FastAPI, admin: TestClient) -> dict[str, str]:
    """User ``lin`` with one episode, and the fleet's evaluation, shadow and rollout, for the
    routes that need ids."""
    ep = start(admin, "lin", "e1", initiator="human", request=TEA)
    body = {"request_id": "world", "candidates": [{"algorithm": "dts"}]}
    evaluation = admin.post("/v1/admin/fleets/default/evaluations", json=body)
    assert evaluation.status_code == 202, evaluation.text
    candidate = {"candidate": {"algorithm": "dts"}, "share": 0.5}
    assert admin.put("/v1/admin/fleets/default/shadow", json=candidate).status_code == 201
    assert admin.put("/v1/admin/fleets/default/rollout", json=candidate).status_code == 201
    app.state.rollout_mover.join(30)  # lin moved, if the hash says so, before the tests look
    return {
        "user_id": "lin",
        "episode_id": ep["episode_id"],
        "fleet": "default",
        "correction_id": "c1",
        "evaluation_id": evaluation.json()["evaluation_id"],
    }


@pytest.fixture
def console(app: FastAPI, make_key: MakeKey) -> TestClient:
    """A browser signed in to the console with an admin key."""
    client = TestClient(app, raise_server_exceptions=False, follow_redirects=False)
    client.cookies.set("attune_console", make_key("admin"), path="/admin")
    return client


def _fill(path: str, ids: dict[str, str]) -> str:
    return re.sub(r"\{(\w+)\}", lambda m: ids[m.group(1)], path)


def _headers(r: Any) -> dict[str, str]:
    return {k: v for k, v in r.headers.items() if k not in VOLATILE}


CONSOLE_PAGES = [
    "/admin",
    "/admin/login",
    "/admin/users",
    "/admin/users/{user_id}",
    "/admin/users/{user_id}?time_slot=afternoon&situation=stretching",
    "/admin/users/{user_id}/details",
    "/admin/users/{user_id}/why",
    "/admin/users/{user_id}/episodes",
    "/admin/users/{user_id}/episodes/{episode_id}/trace",
    "/admin/users/{user_id}/export",
    "/admin/users/{user_id}/reset",
    "/admin/users/{user_id}/delete",
    "/admin/mission",
    "/admin/nowhere",
]
OTHER_PAGES = [
    "/docs",
    "/redoc",
    "/openapi.json",
    "/static/docs/redoc/LICENSE",
    "/admin/static/console.css",
]


@pytest.mark.one_engine
class TestHead:
    def test_every_get_of_the_api_answers_head_as_its_get(
        self, app: FastAPI, admin: TestClient, world: dict[str, str]
    ) -> None:
        paths = [p for p, item in app.openapi()["paths"].items() if "get" in item]
        assert len(paths) >= 12, paths
        for template in paths:
            path = _fill(template, world)
            get, head = admin.get(path), admin.head(path)
            assert head.status_code == get.status_code == 200, (path, get.text)
            assert head.content == b"", path
            if template == "/metrics":  # its counts move with every request
                assert head.headers["content-type"] == get.headers["content-type"]
                continue
            assert _headers(head) == _headers(get), path
            assert head.headers["x-request-id"]

    def test_head_keeps_the_status_of_the_get(self, client: TestClient, robot: TestClient) -> None:
        r = client.head("/v1/users/lin")
        assert r.status_code == 401
        assert r.content == b""
        assert r.headers["content-type"] == "application/json"
        assert int(r.headers["content-length"]) == len(client.get("/v1/users/lin").content)
        assert robot.head("/v1/users/nobody").status_code == 404
        assert robot.head("/v1/users/lin/stats?last=0").status_code == 422
        assert robot.head("/nope").status_code == 404

    def test_console_pages_and_documents_answer_head(
        self, console: TestClient, world: dict[str, str]
    ) -> None:
        for template in CONSOLE_PAGES + OTHER_PAGES:
            path = _fill(template, world)
            # HEAD first: a GET of a person's page records the look, which the next one shows
            head, get = console.head(path), console.get(path)
            assert get.status_code < 500, (path, get.status_code)
            assert head.status_code == get.status_code, (path, get.status_code)
            assert head.content == b"", path
            assert _headers(head) == _headers(get), path

    def test_head_is_not_an_operation_of_the_schema(self, app: FastAPI) -> None:
        for item in app.openapi()["paths"].values():
            assert "head" not in item


@pytest.mark.one_engine
class TestAllow:
    def test_options_on_a_user_lists_every_method(self, robot: TestClient) -> None:
        r = robot.options("/v1/users/lin")
        body = assert_error(r, 405, "MethodNotAllowed")
        assert r.headers["allow"] == "GET, HEAD, PUT, DELETE"
        assert "GET, HEAD, PUT, DELETE" in body["detail"]

    def test_every_405_of_the_api_lists_the_methods_of_its_path(
        self, app: FastAPI, robot: TestClient
    ) -> None:
        ids = {
            "user_id": "lin",
            "episode_id": "ep_x",
            "key_id": "key_x",
            "fleet": "default",
            "correction_id": "c1",
            "evaluation_id": "ev_" + "0" * 32,
        }
        for template, item in app.openapi()["paths"].items():
            methods = {m.upper() for m in item}
            if "GET" in methods:
                methods.add("HEAD")
            for wrong in {"GET", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"} - methods:
                r = robot.request(wrong, _fill(template, ids))
                assert_error(r, 405, "MethodNotAllowed")
                assert set(r.headers["allow"].split(", ")) == methods, (wrong, template)

    @pytest.mark.parametrize(
        ("method", "path", "allow"),
        [
            ("POST", "/healthz", "GET, HEAD"),
            ("DELETE", "/v1/users/lin/episodes", "GET, HEAD, POST"),
            ("PATCH", "/v1/users/lin/model", "GET, HEAD, PUT, DELETE"),
            ("POST", "/admin/users/lin", "GET, HEAD"),
            ("PUT", "/admin/users/lin/reset", "GET, HEAD, POST"),
            ("POST", "/static/docs/redoc/LICENSE", "GET, HEAD"),
            ("POST", "/docs", "GET, HEAD"),
        ],
    )
    def test_allow(self, robot: TestClient, method: str, path: str, allow: str) -> None:
        r = robot.request(method, path)
        assert_error(r, 405, "MethodNotAllowed")
        assert r.headers["allow"] == allow


def _routes_with_bodies(episode_id: str) -> list[tuple[str, str, dict[str, Any]]]:
    return [
        ("PUT", "/v1/users/lin", {"display_name": "Lin"}),
        ("POST", "/v1/users/lin/episodes", event("e-new")),
        (
            "POST",
            f"/v1/episodes/{episode_id}/outcomes",
            {"decision_id": "d", "response": "accepted"},
        ),
        (
            "POST",
            f"/v1/episodes/{episode_id}/feedback",
            {"feedback_id": "f", "feedback": "positive"},
        ),
        ("PUT", "/v1/users/lin/model", {"format": "attune.learner-state"}),
        ("POST", "/v1/admin/keys", {"role": "robot", "fleet": "default", "name": "r"}),
        (
            "POST",
            "/v1/admin/fleets/default/evaluations",
            {"request_id": "r", "candidates": [{"algorithm": "hri"}]},
        ),
        ("PUT", "/v1/admin/fleets/default/shadow", {"candidate": {"algorithm": "hri"}}),
        (
            "PUT",
            "/v1/admin/fleets/default/rollout",
            {"candidate": {"algorithm": "dts"}, "share": 1.0},
        ),
        ("POST", "/v1/admin/fleets/default/rollout/rollback", {"reason": "r"}),
    ]


@pytest.mark.one_engine
class TestContentType:
    @pytest.mark.parametrize("how", ["text/plain", "form", "multipart", "none", "xml"])
    def test_a_body_that_is_not_json_is_415_and_changes_nothing(
        self, admin: TestClient, world: dict[str, str], how: str
    ) -> None:
        before = admin.get("/v1/users/lin").json(), admin.get("/v1/users/lin/episodes").json()
        for method, path, body in _routes_with_bodies(world["episode_id"]):
            raw = json.dumps(body)
            if how == "form":
                r = admin.request(method, path, data={"body": raw})
            elif how == "multipart":
                r = admin.request(method, path, files={"body": ("body.json", raw.encode())})
            elif how == "none":
                r = admin.request(method, path, content=raw.encode())
                assert "content-type" not in r.request.headers
            else:
                kind = {"text/plain": "text/plain", "xml": "application/xml"}[how]
                r = admin.request(
                    method, path, content=raw.encode(), headers={"Content-Type": kind}
                )
            err = assert_error(r, 415, "UnsupportedMediaType")
            assert "application/json" in err["detail"], err
        after = admin.get("/v1/users/lin").json(), admin.get("/v1/users/lin/episodes").json()
        assert after == before

    def test_415_comes_before_the_key_is_checked(self, client: TestClient) -> None:
        r = client.post(
            "/v1/users/lin/episodes", content=b"{}", headers={"Content-Type": "text/plain"}
        )
        assert_error(r, 415, "UnsupportedMediaType")

    @pytest.mark.parametrize(
        "kind",
        [
            "application/json",
            "application/json; charset=utf-8",
            "Application/JSON",
            "application/merge-patch+json",
        ],
    )
    def test_json_types_are_accepted(self, robot: TestClient, kind: str) -> None:
        r = robot.put(
            "/v1/users/lin", content=b'{"display_name": "Lin"}', headers={"Content-Type": kind}
        )
        assert r.status_code in (200, 201), r.text
        assert r.json()["display_name"] == "Lin"

    def test_no_body_where_the_body_is_optional(self, robot: TestClient) -> None:
        r = robot.put("/v1/users/lin")
        assert r.status_code == 201, r.text
        r = robot.put("/v1/users/lin", content=b"", headers={"Content-Type": "text/plain"})
        assert r.status_code == 200, r.text

    def test_no_body_where_the_body_is_required_is_422(self, robot: TestClient) -> None:
        err = assert_error(robot.post("/v1/users/lin/episodes"), 422, "ValidationError")
        assert "body" in err["detail"]

    def test_malformed_json_is_still_400(self, robot: TestClient) -> None:
        r = robot.post(
            "/v1/users/lin/episodes",
            content=b'{"event_id": ',
            headers={"Content-Type": "application/json"},
        )
        assert_error(r, 400, "BadRequest")

    def test_the_schema_declares_415_on_every_route_with_a_body(self, app: FastAPI) -> None:
        seen = 0
        for path, item in app.openapi()["paths"].items():
            for method, op in item.items():
                if "requestBody" in op:
                    seen += 1
                    assert "415" in op["responses"], (method, path)
                else:
                    assert "415" not in op["responses"], (method, path)
        # users, episodes, outcomes, feedback, model, corrections, keys, mission, fleet prior,
        # fleet history, evaluations, shadow, rollout, rollback
        assert seen == 14


# (path, parameter, lowest, highest): every integer query parameter of the API.
BOUNDED = [
    ("/v1/users", "limit", 1, 500),
    ("/v1/users/lin/episodes", "limit", 1, 500),
    ("/v1/admin/audit", "limit", 1, 500),
    ("/v1/users/lin/views", "limit", 1, 500),
    ("/v1/admin/views", "limit", 1, 500),
    ("/v1/users/lin/changes", "limit", 1, 500),
    ("/v1/admin/fleets/default/changes", "limit", 1, 500),
    ("/v1/admin/fleets/default/evaluations", "limit", 1, 500),
    ("/v1/users/lin/stats", "last", 1, 1_000_000),
]
OUT_OF_RANGE = [
    "{low_1}",
    "{high1}",
    "9223372036854775807",
    "9223372036854775808",
    "18446744073709551616",
    "-9223372036854775809",
    "1" + "0" * 40,
    "abc",
    "1.5",
    "1e3",
    "",
    "%00",
]


class TestIntegerQueries:
    @pytest.mark.one_engine
    def test_every_integer_query_parameter_is_bounded_in_the_schema(self, app: FastAPI) -> None:
        found = []
        for path, item in app.openapi()["paths"].items():
            for op in item.values():
                for param in op.get("parameters", []):
                    schema = param["schema"]
                    options = schema.get("anyOf", [schema])
                    ints = [s for s in options if s.get("type") == "integer"]
                    if param["in"] == "query" and ints:
                        found.append((path, param["name"], ints[0]["minimum"], ints[0]["maximum"]))
                        assert (
                            f"{ints[0]['minimum']} to {ints[0]['maximum']}" in param["description"]
                        ), param
        expected = {
            (p.replace("lin", "{user_id}").replace("fleets/default", "fleets/{fleet}"), n, lo, hi)
            for p, n, lo, hi in BOUNDED
        }
        assert set(found) == expected

    @pytest.mark.one_engine
    @pytest.mark.parametrize(("path", "name", "low", "high"), BOUNDED)
    def test_out_of_range_is_422_naming_the_parameter_and_its_range(
        self,
        admin: TestClient,
        world: dict[str, str],
        engine_name: str,
        path: str,
        name: str,
        low: int,
        high: int,
    ) -> None:
        for raw in OUT_OF_RANGE:
            value = raw.format(low_1=low - 1, high1=high + 1)
            if value == "9223372036854775807" and high >= 2**63 - 1:
                continue
            r = admin.get(f"{path}?{name}={value}")
            err = assert_error(r, 422, "ValidationError")
            assert err["detail"] == f"{name} must be an integer from {low} to {high}.", (
                engine_name,
                value,
                err,
            )
            assert err["fields"][0]["loc"] == ["query", name]

    @pytest.mark.parametrize(("path", "name", "low", "high"), BOUNDED)
    def test_the_bounds_themselves_are_accepted(
        self, admin: TestClient, world: dict[str, str], path: str, name: str, low: int, high: int
    ) -> None:
        for value in (low, high):
            r = admin.get(f"{path}?{name}={value}")
            assert r.status_code == 200, (value, r.text)

    def test_the_reported_overflow(self, robot: TestClient, world: dict[str, str]) -> None:
        """Once a 500 on SQLite (OverflowError) and another 422 on PostgreSQL."""
        r = robot.get("/v1/users/lin/stats?last=9223372036854775808")
        err = assert_error(r, 422, "ValidationError")
        assert err["detail"] == "last must be an integer from 1 to 1000000."

    @pytest.mark.parametrize(
        ("page", "name", "low", "high"),
        [
            ("/admin/users", "page", 1, 1_000_000),
            ("/admin/users", "per_page", 5, 200),
            ("/admin/users/lin/details", "last", 1, 1_000_000),
            ("/admin/users/lin/episodes", "before", 1, 2**31 - 1),
            ("/admin/users/lin/episodes", "at", 1, 2**31 - 2),
            ("/admin/users/lin/episodes", "per_page", 5, 200),
            ("/admin/changes", "days", 1, 366),
        ],
    )
    def test_console_pages_name_the_parameter_and_its_range(
        self, console: TestClient, world: dict[str, str], page: str, name: str, low: int, high: int
    ) -> None:
        for value in (low - 1, high + 1, 2**63, 2**64, "x"):
            r = console.get(f"{page}?{name}={value}")
            assert r.status_code == 422, (name, value, r.status_code)
            assert f"{name} must be an integer from {low} to {high}." in r.text
        assert console.get(f"{page}?{name}={high}").status_code == 200


class TestCursors:
    @pytest.mark.one_engine
    def test_the_schema_says_a_cursor_is_opaque(self, app: FastAPI) -> None:
        seen = 0
        for path, item in app.openapi()["paths"].items():
            for op in item.values():
                for param in op.get("parameters", []):
                    if param["name"] != "cursor":
                        continue
                    seen += 1
                    schema = next(s for s in param["schema"]["anyOf"] if s["type"] == "string")
                    assert schema["pattern"], path
                    assert "422" in param["description"], path
                    assert "next_cursor" in param["description"], path
                    assert "422" in op["responses"], path
        assert seen == 8

    @pytest.mark.one_engine
    @pytest.mark.parametrize(
        ("path", "cursor"),
        [
            ("/v1/users", "AA"),
            ("/v1/users", "not*base64"),
            ("/v1/users/lin/episodes", "abc"),
            ("/v1/users/lin/episodes", "1" * 19),
            ("/v1/users/lin/episodes", "2147483648"),
            ("/v1/admin/audit", "x1"),
            ("/v1/admin/audit", "9999999999"),
            ("/v1/users/lin/changes", "x1"),
            ("/v1/admin/fleets/default/changes", "-1"),
        ],
    )
    def test_a_cursor_never_issued_is_422(
        self, admin: TestClient, world: dict[str, str], path: str, cursor: str
    ) -> None:
        err = assert_error(admin.get(f"{path}?cursor={cursor}"), 422, "ValidationError")
        assert err["detail"] == "cursor is not one this API returned."

    def test_the_largest_position_is_a_cursor_on_both_engines(
        self, admin: TestClient, world: dict[str, str]
    ) -> None:
        for path in ("/v1/users/lin/episodes", "/v1/admin/audit"):
            r = admin.get(f"{path}?cursor=2147483647")
            assert r.status_code == 200, r.text

    def test_issued_cursors_are_accepted(self, admin: TestClient) -> None:
        for uid in ("a", "b", "c"):
            assert admin.put(f"/v1/users/{uid}", json={}).status_code == 201
        page = admin.get("/v1/users?limit=1").json()
        r = admin.get(f"/v1/users?limit=1&cursor={page['next_cursor']}")
        assert r.status_code == 200
        assert r.json()["items"][0]["user_id"] == "b"


@pytest.mark.one_engine
class TestDocs:
    @pytest.mark.parametrize("page", ["/docs", "/redoc"])
    def test_pages_load_nothing_from_elsewhere(self, client: TestClient, page: str) -> None:
        r = client.get(page)
        assert r.status_code == 200
        urls = re.findall(r"""(?:src|href|url)\s*[=:]\s*['"]([^'"]+)['"]""", r.text)
        assert urls, r.text
        for url in urls:
            assert url.startswith("/"), (page, url)
            assert client.get(url).status_code == 200, url
        assert "http://" not in r.text, r.text
        assert "https://" not in r.text, r.text

    @pytest.mark.parametrize(
        "bundle",
        ["/static/docs/redoc/redoc.standalone.js", "/static/docs/swagger-ui/swagger-ui-bundle.js"],
    )
    def test_the_scripts_load_no_image_from_elsewhere(
        self, client: TestClient, bundle: str
    ) -> None:
        """Redoc's bundle, as published, shows its maker's logo from a CDN in the sidebar; the
        vendored one renders the sidebar's credit without it (static/docs/redoc/README.md), so
        the browser never asks another host (its page's policy would refuse it anyway)."""
        script = client.get(bundle).text
        assert "cdn.redoc.ly" not in script
        assert re.findall(r"""src:\s*['"]https?://""", script) == []
        if "redoc" in bundle:
            assert "API docs by Redocly" in script  # the credit itself stays

    def test_the_schemas_version_is_the_packages(self, client: TestClient) -> None:
        from importlib.metadata import version

        from typer.testing import CliRunner

        from app import cli

        printed = CliRunner().invoke(cli.app, ["--version"]).stdout.split()
        assert client.get("/openapi.json").json()["info"]["version"] == version("attune")
        assert printed == ["attune", version("attune")]

    def test_the_assets_and_their_licences_are_served(self, client: TestClient) -> None:
        for path in (
            "/static/docs/swagger-ui/swagger-ui-bundle.js",
            "/static/docs/swagger-ui/swagger-ui.css",
            "/static/docs/swagger-ui/LICENSE",
            "/static/docs/swagger-ui/NOTICE",
            "/static/docs/redoc/redoc.standalone.js",
            "/static/docs/redoc/LICENSE",
        ):
            r = client.get(path)
            assert r.status_code == 200, path
            assert len(r.content) > 50, path

    def test_every_response_declares_x_request_id(self, app: FastAPI) -> None:
        for path, item in app.openapi()["paths"].items():
            for method, op in item.items():
                for code, response in op["responses"].items():
                    header = response["headers"]["X-Request-ID"]
                    assert header["schema"]["pattern"], (method, path, code)
