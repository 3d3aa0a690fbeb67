"""The service behind a reverse proxy on a path prefix, in process: the requests reach the app as
uvicorn hands them over with ``--root-path /attune`` (the path with the prefix in front, the
ASGI ``root_path`` set), from a trusted proxy (127.0.0.1, trusted by default) or from another
peer. The console's links, redirects and cookie, its same-origin check, the documentation pages,
the request id and the access line's client."""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator
from html.parser import HTMLParser
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app import logs
from app.api.middleware import TrustedProxies, route_path
from app.settings import Settings
from tests.support.fixtures import MakeKey

ROOT = "/attune"
PROXY = ("127.0.0.1", 41000)  # in ATTUNE_FORWARDED_ALLOW_IPS by default
STRANGER = ("203.0.113.7", 41000)  # not
PUBLIC = {"x-forwarded-proto": "https", "x-forwarded-host": "robots.example.org"}
FRESH = re.compile(r"^[0-9a-f]{32}$")

# Request ids, headers and pages: decided before any SQL but the key's; one engine suffices.
pytestmark = pytest.mark.one_engine


class Addresses(HTMLParser):
    """Every address a page hands the browser: href, src, action and data-*-url."""

    def __init__(self) -> None:
        super().__init__()
        self.found: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if value is not None and (
                name in ("href", "src", "action") or (name.startswith("data-") and "url" in name)
            ):
                self.found.append(value)


def addresses(page: str) -> list[str]:
    parser = Addresses()
    parser.feed(page)
    return parser.found


def assert_under_prefix(page: str) -> None:
    """Every address of the page that is a path is under the prefix (none is left at /admin)."""
    paths = [a for a in addresses(page) if a.startswith("/")]
    assert paths, "the page has no links at all"
    assert all(p.startswith(f"{ROOT}/") for p in paths), [
        p for p in paths if not p.startswith(f"{ROOT}/")
    ]


def _browser(app: FastAPI, peer: tuple[str, int] = PROXY) -> TestClient:
    return TestClient(
        app,
        base_url="http://attune-1:8000",
        root_path=ROOT,
        client=peer,
        raise_server_exceptions=False,
        follow_redirects=False,
    )


@pytest.fixture
def browser(app: FastAPI) -> Iterator[TestClient]:
    """A browser whose requests come through the trusted proxy, as https://robots.example.org."""
    with _browser(app) as c:
        c.headers.update(PUBLIC)
        yield c


@pytest.fixture
def stranger(app: FastAPI) -> Iterator[TestClient]:
    """The same requests from a peer that is not a trusted proxy."""
    with _browser(app, STRANGER) as c:
        yield c


def _sign_in(c: TestClient, key: str, **headers: str) -> Any:
    return c.post(
        f"{ROOT}/admin/login",
        data={"key": key, "next": f"{ROOT}/admin/users"},
        headers={"origin": "https://robots.example.org", **headers},
    )


class TestConsole:
    def test_a_page_without_a_session_goes_to_the_login_under_the_prefix(
        self, browser: TestClient
    ) -> None:
        r = browser.get(f"{ROOT}/admin/users?q=lin")
        assert r.status_code == 303
        assert r.headers["location"] == f"{ROOT}/admin/login?next={ROOT}/admin/users%3Fq%3Dlin"
        login = browser.get(r.headers["location"])
        assert login.status_code == 200
        assert_under_prefix(login.text)
        assert f'value="{ROOT}/admin/users?q=lin"' in login.text  # where it goes back to
        assert browser.get(f"{ROOT}/admin").headers["location"] == f"{ROOT}/admin/users"

    def test_its_static_files_are_served_under_the_prefix(self, browser: TestClient) -> None:
        page = browser.get(f"{ROOT}/admin/login").text
        static = [a for a in addresses(page) if "/static/" in a]
        assert static
        for path in static:
            assert browser.get(path).status_code == 200, path

    def test_signing_in_sets_a_secure_cookie_of_the_prefixed_console(
        self, browser: TestClient, make_key: MakeKey
    ) -> None:
        r = _sign_in(browser, make_key("staff"))
        assert r.status_code == 303, r.text
        assert r.headers["location"] == f"{ROOT}/admin/users"
        cookie = r.headers["set-cookie"]
        assert f"Path={ROOT}/admin" in cookie
        assert "Secure" in cookie
        assert "HttpOnly" in cookie

    def test_pages_links_and_redirects_stay_under_the_prefix(
        self, browser: TestClient, app: FastAPI, make_key: MakeKey
    ) -> None:
        staff = make_key("staff")
        with TestClient(app, headers={"Authorization": f"Bearer {make_key()}"}) as robot:
            assert robot.put("/v1/users/lin", json={}).status_code == 201
        browser.cookies.set("attune_console", staff)
        users = browser.get(f"{ROOT}/admin/users")
        assert users.status_code == 200, users.text
        assert_under_prefix(users.text)
        assert f"{ROOT}/admin/users/lin?fleet=default" in addresses(users.text)
        for path in (
            "/admin/users/lin",
            "/admin/users/lin/episodes",
            "/admin/users/lin/details",
            "/admin/users/lin/reset",
            "/admin/mission",
        ):
            page = browser.get(f"{ROOT}{path}?fleet=default")
            assert page.status_code == 200, (path, page.text)
            assert_under_prefix(page.text)
        # A form's POST: from the public origin, back to the user's page under the prefix.
        reset = browser.get(f"{ROOT}/admin/users/lin/reset?fleet=default").text
        csrf = re.search(r'name="csrf" value="([^"]+)"', reset)
        assert csrf is not None
        done = browser.post(
            f"{ROOT}/admin/users/lin/reset?fleet=default",
            data={"csrf": csrf.group(1)},
            headers={"origin": "https://robots.example.org"},
        )
        assert done.status_code == 303, done.text
        assert done.headers["location"].startswith(f"{ROOT}/admin/users/lin/details?")
        # Signing out forgets the cookie of the prefixed path and goes to the prefixed login.
        out = browser.post(
            f"{ROOT}/admin/logout",
            data={"csrf": csrf.group(1)},
            headers={"origin": "https://robots.example.org"},
        )
        assert out.status_code == 303
        assert out.headers["location"] == f"{ROOT}/admin/login?signed_out=true"
        assert f"Path={ROOT}/admin" in out.headers["set-cookie"]
        assert "Max-Age=0" in out.headers["set-cookie"]

    def test_a_404_page_links_under_the_prefix(self, browser: TestClient) -> None:
        r = browser.get(f"{ROOT}/admin/nowhere")
        assert r.status_code == 404
        assert_under_prefix(r.text)

    @pytest.mark.parametrize(
        ("headers", "signed_in"),
        [
            ({"origin": "https://robots.example.org"}, True),
            ({"origin": "https://robots.example.org:443"}, True),
            ({"origin": "http://robots.example.org"}, False),  # not the scheme the browser used
            ({"origin": "http://attune-1:8000"}, False),  # the instance's own host
            ({"origin": "https://evil.example"}, False),
            ({"origin": "http://[x"}, False),  # not a URL at all: refused, not a 500
            ({"origin": "", "referer": "https://[robots.example.org/"}, False),
            ({"origin": "null"}, False),
            ({"origin": "", "referer": "https://robots.example.org/attune/admin/login"}, True),
            ({"origin": "", "referer": "https://evil.example/attune/admin/login"}, False),
        ],
    )
    def test_the_origin_is_compared_with_the_host_the_browser_used(
        self, browser: TestClient, make_key: MakeKey, headers: dict[str, str], signed_in: bool
    ) -> None:
        headers = {k: v for k, v in headers.items() if v}
        r = browser.post(
            f"{ROOT}/admin/login",
            data={"key": make_key("staff"), "next": f"{ROOT}/admin/users"},
            headers=headers,
        )
        assert (r.status_code == 303) is signed_in, r.text
        if not signed_in:
            assert r.status_code == 403

    def test_a_stranger_cannot_claim_the_public_host_or_https(
        self, stranger: TestClient, make_key: MakeKey
    ) -> None:
        key = make_key("staff")
        # Its X-Forwarded-Host is dropped: the site it asked is its own Host.
        refused = _sign_in(stranger, key, **PUBLIC)
        assert refused.status_code == 403
        r = _sign_in(stranger, key, **{**PUBLIC, "origin": "http://attune-1:8000"})
        assert r.status_code == 303, r.text
        assert "Secure" not in r.headers["set-cookie"]  # its X-Forwarded-Proto is dropped too
        assert f"Path={ROOT}/admin" in r.headers["set-cookie"]

    def test_without_a_proxy_the_console_is_at_admin(self, app: FastAPI, make_key: MakeKey) -> None:
        with TestClient(app, follow_redirects=False) as c:
            r = c.post(
                "/admin/login",
                data={"key": make_key("staff"), "next": "/admin/users"},
                headers={"origin": "http://testserver"},
            )
            assert r.status_code == 303, r.text
            assert r.headers["location"] == "/admin/users"
            assert "Path=/admin;" in r.headers["set-cookie"] + ";"
            assert "Secure" not in r.headers["set-cookie"]
            assert all(a.startswith("/admin/") for a in addresses(c.get("/admin/users").text))


class TestDocs:
    def test_the_schema_names_the_prefix_as_its_server(self, browser: TestClient) -> None:
        schema = browser.get(f"{ROOT}/openapi.json").json()
        assert schema["servers"][0] == {"url": ROOT}

    @pytest.mark.parametrize("page", ["/docs", "/redoc"])
    def test_the_pages_load_the_schema_and_their_files_under_the_prefix(
        self, browser: TestClient, page: str
    ) -> None:
        r = browser.get(f"{ROOT}{page}")
        assert r.status_code == 200
        assert f"'{ROOT}/openapi.json'" in r.text or f'"{ROOT}/openapi.json"' in r.text
        files = [a for a in addresses(r.text) if "/static/" in a]
        assert files
        for path in files:
            assert path.startswith(f"{ROOT}/static/docs/")
            assert browser.get(path).status_code == 200, path


class TestTrustedProxies:
    def test_a_trusted_proxy_s_request_id_is_kept_a_stranger_s_replaced(
        self, browser: TestClient, stranger: TestClient
    ) -> None:
        kept = browser.get(f"{ROOT}/readyz", headers={"x-request-id": "nginx-42"})
        assert kept.headers["x-request-id"] == "nginx-42"
        replaced = stranger.get(f"{ROOT}/readyz", headers={"x-request-id": "nginx-42"})
        assert FRESH.match(replaced.headers["x-request-id"])

    def test_the_access_line_names_the_caller_the_proxy_forwarded(
        self, browser: TestClient, stranger: TestClient, caplog: pytest.LogCaptureFixture
    ) -> None:
        with caplog.at_level(logging.INFO, logger="attune.access"):
            browser.get(f"{ROOT}/livez", headers={"x-forwarded-for": "198.51.100.4"})
            # A chain: the last address that is not a trusted proxy is the caller.
            browser.get(
                f"{ROOT}/livez", headers={"x-forwarded-for": "10.1.1.1, 198.51.100.5, 127.0.0.1"}
            )
            stranger.get(f"{ROOT}/livez", headers={"x-forwarded-for": "198.51.100.6"})
        got = [
            getattr(r, logs.FIELDS)["client"] for r in caplog.records if r.name == "attune.access"
        ]
        assert got == ["198.51.100.4", "198.51.100.5", STRANGER[0]]
        assert f"client={STRANGER[0]}" in caplog.records[-1].getMessage()

    def test_probes_under_the_prefix_are_the_probes(self, browser: TestClient) -> None:
        assert browser.get(f"{ROOT}/readyz").json()["status"] == "ready"
        assert browser.get(f"{ROOT}/v1/users").status_code == 401

    def test_membership_of_addresses_and_networks(self) -> None:
        trusted = TrustedProxies(["10.0.0.0/8", "::1", "192.0.2.1"])
        assert "10.4.5.6" in trusted
        assert "::ffff:10.4.5.6" in trusted
        assert "::1" in trusted
        assert "192.0.2.1" in trusted
        assert "192.0.2.2" not in trusted
        assert "testclient" not in trusted
        assert "" not in trusted
        assert "203.0.113.9" in TrustedProxies(["*"])
        assert trusted.client("203.0.113.9, 10.0.0.1") == "203.0.113.9"
        assert trusted.client("10.0.0.2, 10.0.0.1") == "10.0.0.2"  # all trusted: the first
        # What is left of a hop that is no address was written by the caller: not taken.
        assert trusted.client("203.0.113.9 status=200, 10.0.0.1") == "10.0.0.1"
        assert trusted.client("1.2.3.4, key_id=x, 203.0.113.9") == "203.0.113.9"
        assert trusted.client("evil") is None

    def test_the_route_path_leaves_the_root_path_out(self) -> None:
        assert route_path({"path": "/attune/readyz", "root_path": "/attune"}) == "/readyz"
        assert route_path({"path": "/attune", "root_path": "/attune"}) == "/"
        assert route_path({"path": "/attuned", "root_path": "/attune"}) == "/attuned"
        assert route_path({"path": "/readyz", "root_path": ""}) == "/readyz"


class TestSettings:
    @pytest.mark.parametrize(
        ("given", "kept"),
        [("", ""), ("/attune", "/attune"), ("/attune/", "/attune"), ("/a/b-1", "/a/b-1")],
    )
    def test_a_root_path(self, given: str, kept: str) -> None:
        assert Settings(_env_file=None, root_path=given).root_path == kept  # type: ignore[call-arg]

    @pytest.mark.parametrize(
        "given", ["attune", "/at tune", "/a//b", "/a?b", "http://x/a", "/..", "/a/./b", "/ätt"]
    )
    def test_a_bad_root_path(self, given: str) -> None:
        with pytest.raises(ValueError, match="root_path"):
            Settings(_env_file=None, root_path=given)  # type: ignore[call-arg]

    def test_proxies_are_addresses_and_networks(self) -> None:
        listed: Any = "10.0.0.0/8, 127.0.0.1,::1"  # as in ATTUNE_FORWARDED_ALLOW_IPS
        s = Settings(_env_file=None, forwarded_allow_ips=listed)  # type: ignore[call-arg]
        assert s.forwarded_allow_ips == ["10.0.0.0/8", "127.0.0.1", "::1"]
        bad: Any = "10.0.0.0/8,nginx"
        with pytest.raises(ValueError, match="forwarded_allow_ips"):
            Settings(_env_file=None, forwarded_allow_ips=bad)  # type: ignore[call-arg]
