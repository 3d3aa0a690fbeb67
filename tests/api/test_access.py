"""Every access rule of the contract, and the abuse limits.

No key or an unknown/revoked key: 401. A robot key on admin routes: 403. Another fleet's users
and episodes: 404, never a hint that they exist. Admins read every fleet. Per-key rate limits
(429 with Retry-After), overload shedding (503 with Retry-After), the body size limit (413), the
key check itself, and the audit log of admin actions (who, what, when).
"""

from __future__ import annotations

import asyncio
import dataclasses
import datetime as dt
import gc
import hmac
import warnings
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.api.middleware import InFlightLimitMiddleware, KeyRateLimiter
from app.db.repositories import keys as keys_repo
from app.db.session import Database
from app.errors import Unauthorized
from app.main import create_app
from app.services import auth
from app.services.auth import list_keys, revoke_key
from app.settings import Settings
from tests.support.contract import assert_error
from tests.support.episodes import event, start
from tests.support.fixtures import MakeKey, ManualClock

# Every route that needs a key: (method, path, body).
USER_ROUTES = [
    ("GET", "/v1/users/{user}", None),
    ("PUT", "/v1/users/{user}", {}),
    ("GET", "/v1/users/{user}/episodes", None),
    ("POST", "/v1/users/{user}/episodes", event("access-1")),
    ("GET", "/v1/users/{user}/model", None),
    ("GET", "/v1/users/{user}/stats", None),
    ("GET", "/v1/users/{user}/profile", None),
    ("GET", "/v1/users/{user}/corrections", None),
]
EPISODE_ROUTES = [
    ("GET", "/v1/episodes/{episode}", None),
    (
        "POST",
        "/v1/episodes/{episode}/outcomes",
        {"decision_id": "{decision}", "response": "accepted"},
    ),
    ("POST", "/v1/episodes/{episode}/feedback", {"feedback_id": "f1", "feedback": "positive"}),
]
ADMIN_ROUTES = [
    ("DELETE", "/v1/users/{user}", None),
    ("DELETE", "/v1/users/{user}/model", None),
    ("GET", "/v1/users/{user}/model/export", None),
    ("PUT", "/v1/users/{user}/model", {"format": "attune.learner-state"}),
    ("GET", "/v1/admin/audit", None),
    (
        "POST",
        "/v1/users/{user}/corrections",
        {
            "correction_id": "c1",
            "time_slot": "afternoon",
            "situation": "stretching",
            "kind": "quiet",
        },
    ),
    ("DELETE", "/v1/users/{user}/corrections/c1", None),
]
OPEN_ROUTES = [("GET", "/v1/users", None), ("GET", "/v1/mission", None)]


def _fill(value: Any, ids: dict[str, str]) -> Any:
    if isinstance(value, str):
        return value.format(**ids)
    if isinstance(value, dict):
        return {k: _fill(v, ids) for k, v in value.items()}
    return value


def _call(client: TestClient, method: str, path: str, body: Any, ids: dict[str, str]) -> Any:
    kwargs = {"json": _fill(body, ids)} if body is not None else {}
    return client.request(method, _fill(path, ids), **kwargs)


@pytest.fixture
def lin(robot: TestClient) -> dict[str, str]:
    """User lin of fleet default with one open episode: the ids the routes need."""
    ep = start(robot, "lin", "lin-1")
    return {"user": "lin", "episode": ep["episode_id"], "decision": ep["decision"]["decision_id"]}


ALL_ROUTES = USER_ROUTES + EPISODE_ROUTES + ADMIN_ROUTES + OPEN_ROUTES


@pytest.mark.one_engine
class TestNoKey:
    @pytest.mark.parametrize(("method", "path", "body"), ALL_ROUTES)
    def test_every_route_needs_a_key(
        self, client: TestClient, lin: dict[str, str], method: str, path: str, body: Any
    ) -> None:
        r = _call(client, method, path, body, lin)
        assert_error(r, 401, "Unauthorized")
        assert r.headers["WWW-Authenticate"] == "Bearer"  # how to send one (RFC 6750)

    @pytest.mark.parametrize(
        "header",
        [
            "",
            "Bearer",
            "Bearer ",
            "Basic abc",
            "att_x",
            "Bearer att_unknown",
            "Bearer " + "a" * 5000,
        ],
    )
    def test_malformed_or_unknown_keys(
        self, app: FastAPI, lin: dict[str, str], header: str
    ) -> None:
        with TestClient(app, headers={"Authorization": header}, raise_server_exceptions=False) as c:
            r = c.get("/v1/users/lin")
            assert_error(r, 401, "Unauthorized")
            assert r.headers["WWW-Authenticate"] == "Bearer"

    def test_the_schema_declares_the_challenge(self, app: FastAPI) -> None:
        for path, item in app.openapi()["paths"].items():
            for method, op in item.items():
                if "401" in op["responses"]:
                    header = op["responses"]["401"]["headers"]["WWW-Authenticate"]
                    assert header["schema"]["enum"] == ["Bearer"], (method, path)

    def test_probes_need_no_key(self, client: TestClient) -> None:
        for path in ("/healthz", "/readyz", "/metrics"):
            assert client.get(path).status_code == 200


class TestRevokedKey:
    def test_every_route_refuses_a_revoked_key(
        self,
        app: FastAPI,
        db: Database,
        make_key: MakeKey,
        lin: dict[str, str],
        key_clock: ManualClock,
    ) -> None:
        secret = make_key("admin", name="to-revoke")
        with TestClient(
            app, headers={"Authorization": f"Bearer {secret}"}, raise_server_exceptions=False
        ) as c:
            assert c.get("/v1/users/lin").status_code == 200
            with db.transaction() as session:
                [key] = [k for k in list_keys(session) if k.name == "to-revoke"]
                revoke_key(session, key.id)
            key_clock.advance(app.state.settings.key_cache_seconds)
            for method, path, body in ALL_ROUTES:
                r = _call(c, method, path, body, lin)
                assert_error(r, 401, "Unauthorized")
                assert r.headers["WWW-Authenticate"] == "Bearer"


class TestKeyCache:
    """A worker keeps the keys it authenticated for ``key_cache_seconds``: a key revoked from
    outside (the command line, another worker) keeps working in it for at most that long; a
    revocation made in the worker itself takes effect at once."""

    def _revoked_outside(self, db: Database, name: str) -> None:
        with db.transaction() as session:
            [key] = [k for k in list_keys(session) if k.name == name]
            revoke_key(session, key.id)

    def test_a_revocation_from_outside_takes_effect_within_the_bound(
        self, app: FastAPI, db: Database, make_key: MakeKey, key_clock: ManualClock
    ) -> None:
        bound = app.state.settings.key_cache_seconds
        assert bound > 0  # the default keeps keys a few seconds
        secret = make_key("robot", name="cached")
        with TestClient(
            app, headers={"Authorization": f"Bearer {secret}"}, raise_server_exceptions=False
        ) as c:
            assert c.get("/v1/users").status_code == 200
            self._revoked_outside(db, "cached")
            key_clock.advance(bound * 0.9)
            assert c.get("/v1/users").status_code == 200  # still in this worker's cache
            key_clock.advance(bound * 0.1)
            assert_error(c.get("/v1/users"), 401, "Unauthorized")

    def test_a_revocation_in_the_worker_takes_effect_at_once(
        self, app: FastAPI, db: Database, make_key: MakeKey, key_clock: ManualClock
    ) -> None:
        secret = make_key("robot", name="cached")
        with TestClient(
            app, headers={"Authorization": f"Bearer {secret}"}, raise_server_exceptions=False
        ) as c:
            assert c.get("/v1/users").status_code == 200
            with db.transaction() as session:
                [key] = [k for k in list_keys(session) if k.name == "cached"]
                revoke_key(session, key.id, keys=app.state.ctx.keys)
            assert_error(c.get("/v1/users"), 401, "Unauthorized")

    def test_no_cache_reads_every_key(
        self, settings: Settings, empty_tables: None, make_key: MakeKey
    ) -> None:
        app = create_app(settings.model_copy(update={"key_cache_seconds": 0}))
        try:
            secret = make_key("robot", name="uncached")
            with TestClient(
                app, headers={"Authorization": f"Bearer {secret}"}, raise_server_exceptions=False
            ) as c:
                assert c.get("/v1/users").status_code == 200
                self._revoked_outside(app.state.db, "uncached")
                assert_error(c.get("/v1/users"), 401, "Unauthorized")
        finally:
            app.state.db.dispose()


class TestRobotOnAdminRoutes:
    @pytest.mark.one_engine
    @pytest.mark.parametrize(("method", "path", "body"), ADMIN_ROUTES)
    def test_forbidden(
        self, robot: TestClient, lin: dict[str, str], method: str, path: str, body: Any
    ) -> None:
        assert_error(_call(robot, method, path, body, lin), 403, "Forbidden")
        assert robot.get("/v1/users/lin").status_code == 200  # nothing was deleted

    @pytest.mark.parametrize(("method", "path", "body"), ADMIN_ROUTES[:4])
    def test_admin_may(
        self, admin: TestClient, lin: dict[str, str], method: str, path: str, body: Any
    ) -> None:
        if method == "PUT":  # import what was exported
            body = admin.get("/v1/users/lin/model/export").json()
        r = _call(admin, method, path, body, lin)
        assert r.status_code in (200, 204), r.text


class TestOtherFleet:
    # Routes naming a user or episode of lin's fleet that another fleet cannot reach. PUT of a
    # user and POST of an episode are missing here: from another fleet they mean that fleet's
    # own `lin` (TestSameIdsInTwoFleets).
    ABSENT = [
        r
        for r in USER_ROUTES + EPISODE_ROUTES
        if (r[0], r[1]) not in {("PUT", "/v1/users/{user}"), ("POST", "/v1/users/{user}/episodes")}
    ]

    @pytest.mark.parametrize(("method", "path", "body"), ABSENT)
    def test_another_fleets_resources_are_absent(
        self,
        other_robot: TestClient,
        robot: TestClient,
        lin: dict[str, str],
        method: str,
        path: str,
        body: Any,
    ) -> None:
        before = robot.get("/v1/users/lin").json()
        r = _call(other_robot, method, path, body, lin)
        body_out = assert_error(r, 404, "NotFound")
        assert "lin" not in body_out["detail"] or "No user" in body_out["detail"]
        assert robot.get("/v1/users/lin").json() == before  # and nothing changed

    def test_the_same_404_as_a_user_that_does_not_exist(
        self, other_robot: TestClient, lin: dict[str, str]
    ) -> None:
        hidden = other_robot.get("/v1/users/lin")
        absent = other_robot.get("/v1/users/nobody")
        assert (hidden.status_code, hidden.json()["error"]) == (
            absent.status_code,
            absent.json()["error"],
        )
        assert hidden.json()["detail"].replace("lin", "X") == absent.json()["detail"].replace(
            "nobody", "X"
        )

    @pytest.mark.parametrize(("method", "path", "body"), ADMIN_ROUTES[:4])
    def test_an_admin_of_any_fleet_reaches_every_fleet(
        self,
        app: FastAPI,
        make_key: MakeKey,
        lin: dict[str, str],
        method: str,
        path: str,
        body: Any,
    ) -> None:
        with TestClient(
            app,
            headers={"Authorization": f"Bearer {make_key('admin', 'other')}"},
            raise_server_exceptions=False,
        ) as other_admin:
            in_default = {"fleet": "default"}
            if method == "PUT":
                body = other_admin.get("/v1/users/lin/model/export", params=in_default).json()
            target = path.format(**lin)
            r = other_admin.request(method, target, json=body, params=in_default)
            assert r.status_code in (200, 204), r.text
            # Without ?fleet= an admin means its own key's fleet, where there is no lin.
            assert_error(other_admin.request(method, target, json=body), 404, "NotFound")

    def test_listing_shows_only_the_own_fleet(
        self, robot: TestClient, other_robot: TestClient, admin: TestClient, lin: dict[str, str]
    ) -> None:
        start(other_robot, "ming", "ming-1")
        assert [u["user_id"] for u in robot.get("/v1/users").json()["items"]] == ["lin"]
        assert [u["user_id"] for u in other_robot.get("/v1/users").json()["items"]] == ["ming"]
        assert {u["user_id"] for u in admin.get("/v1/users").json()["items"]} == {"lin", "ming"}

    def test_naming_another_fleet_is_answered_as_a_missing_user(
        self, other_robot: TestClient, lin: dict[str, str]
    ) -> None:
        """Only admins choose a fleet; anyone else naming lin's fleet finds no lin there."""
        named = other_robot.get("/v1/users/lin", params={"fleet": "default"})
        absent = other_robot.get("/v1/users/nobody", params={"fleet": "default"})
        assert_error(named, 404, "NotFound")
        assert named.json()["detail"].replace("lin", "X") == absent.json()["detail"].replace(
            "nobody", "X"
        )


class TestSameIdsInTwoFleets:
    def test_another_fleet_makes_its_own_user_of_the_same_id(
        self, robot: TestClient, other_robot: TestClient, lin: dict[str, str]
    ) -> None:
        before = robot.get("/v1/users/lin").json()
        made = other_robot.put("/v1/users/lin", json={"display_name": "Lin of other"})
        assert made.status_code == 201, made.text
        assert made.json()["fleet"] == "other"
        theirs = start(other_robot, "lin", "other-lin-1")
        assert theirs["episode_id"] != lin["episode"]
        assert robot.get("/v1/users/lin").json() == before  # the first lin is untouched
        assert other_robot.get("/v1/users/lin").json()["display_name"] == "Lin of other"
        assert other_robot.get(f"/v1/episodes/{lin['episode']}").status_code == 404
        assert robot.get(f"/v1/episodes/{theirs['episode_id']}").status_code == 404
        ours = robot.get("/v1/users/lin/episodes").json()["items"]
        assert [e["episode_id"] for e in ours] == [lin["episode"]]


# -- abuse limits ------------------------------------------------------------------------------
@pytest.fixture
def limited_app(settings: Settings, empty_tables: None) -> Iterator[FastAPI]:
    application = create_app(
        settings.model_copy(update={"rate_limit_per_s": 1.0, "rate_limit_burst": 3})
    )
    yield application
    application.state.db.dispose()


@pytest.mark.one_engine
class TestRateLimit:
    def test_429_with_retry_after_per_key(self, limited_app: FastAPI) -> None:
        db: Database = limited_app.state.db
        with db.transaction() as session:
            one = auth.create_key(session, role="robot")[1]
            two = auth.create_key(session, role="robot")[1]
        with TestClient(
            limited_app, headers={"Authorization": f"Bearer {one}"}, raise_server_exceptions=False
        ) as c:
            codes = [c.get("/v1/users").status_code for _ in range(5)]
            assert codes[:3] == [200, 200, 200]
            assert 429 in codes[3:]
            r = c.get("/v1/users")
            assert_error(r, 429, "TooManyRequests")
            assert r.headers["Retry-After"].isdigit()
            assert int(r.headers["Retry-After"]) >= 1
            assert c.get("/healthz").status_code == 200  # probes are never limited
        with TestClient(
            limited_app, headers={"Authorization": f"Bearer {two}"}, raise_server_exceptions=False
        ) as c:
            assert c.get("/v1/users").status_code == 200  # another key has its own bucket

    def test_the_bucket_refills(self) -> None:
        now = [0.0]
        limiter = KeyRateLimiter(rate=2.0, burst=2, clock=lambda: now[0])
        assert [limiter.acquire("k") for _ in range(3)] == [0, 0, 1]
        now[0] += 0.5  # one token back
        assert limiter.acquire("k") == 0
        assert limiter.acquire("k") == 1
        now[0] += 100.0  # idle: full again, and the idle bucket is forgotten
        assert limiter.acquire("other") == 0
        assert "k" not in limiter._buckets

    def test_zero_turns_it_off(self) -> None:
        limiter = KeyRateLimiter(rate=0.0, burst=1)
        assert all(limiter.acquire("k") == 0 for _ in range(1000))

    def test_documented(self, client: TestClient) -> None:
        spec = client.get("/openapi.json").json()
        r429 = spec["paths"]["/v1/users/{user_id}/episodes"]["post"]["responses"]["429"]
        assert "Retry-After" in r429["headers"]


@pytest.mark.one_engine
class TestOverload:
    def test_beyond_the_cap_answers_503_at_once(self) -> None:
        """Two requests held in flight; the third is refused immediately, probes still pass."""

        async def scenario() -> list[tuple[str, int, dict[str, str]]]:
            release = asyncio.Event()

            async def slow_app(scope: Any, receive: Any, send: Any) -> None:
                await release.wait()
                await send({"type": "http.response.start", "status": 200, "headers": []})
                await send({"type": "http.response.body", "body": b"{}"})

            mw = InFlightLimitMiddleware(slow_app, limit=2)
            results: list[tuple[str, int, dict[str, str]]] = []

            async def call(path: str) -> None:
                sent: list[Any] = []

                async def send(message: Any) -> None:
                    sent.append(message)

                async def receive() -> Any:
                    return {"type": "http.request", "body": b""}

                await mw(
                    {"type": "http", "path": path, "method": "GET", "headers": []}, receive, send
                )
                start_msg = sent[0]
                results.append(
                    (
                        path,
                        start_msg["status"],
                        {k.decode(): v.decode() for k, v in start_msg["headers"]},
                    )
                )

            held = [asyncio.create_task(call("/v1/users")) for _ in range(2)]
            await asyncio.sleep(0)
            await call("/v1/users")  # over the cap: answered without waiting
            probe = asyncio.create_task(call("/healthz"))  # exempt: waits like the others
            await asyncio.sleep(0)
            assert mw.in_flight == 2
            release.set()
            await asyncio.gather(*held, probe)
            assert mw.in_flight == 0
            assert mw.shed == 1
            return results

        results = asyncio.run(scenario())
        shed = [r for r in results if r[1] == 503]
        assert len(shed) == 1
        assert shed[0][2]["retry-after"] == "1"
        assert sorted(r[1] for r in results) == [200, 200, 200, 503]

    def test_the_503_is_the_contract_error_body(
        self, settings: Settings, empty_tables: None
    ) -> None:
        application = create_app(settings.model_copy(update={"max_in_flight": 1}))
        try:
            with TestClient(application, raise_server_exceptions=False) as c:
                # One request in flight (this test holds the only slot) shows the refusal.
                mw = _middleware(application, InFlightLimitMiddleware)
                mw.in_flight = 1
                r = c.get("/v1/users")
                mw.in_flight = 0
                assert_error(r, 503, "ServiceUnavailable")
                assert r.headers["Retry-After"] == "1"
                assert c.get("/readyz").status_code == 200
        finally:
            application.state.db.dispose()


def _middleware(application: FastAPI, kind: type) -> Any:
    stack = application.middleware_stack
    while stack is not None and not isinstance(stack, kind):
        stack = getattr(stack, "app", None)
    assert stack is not None, f"no {kind.__name__} in the stack"
    return stack


@pytest.mark.one_engine
class TestBodyLimit:
    def test_413_over_the_limit(self, robot: TestClient) -> None:
        big = {**event("big-1"), "robot_id": "x" * (65 * 1024)}
        assert_error(robot.post("/v1/users/lin/episodes", json=big), 413, "PayloadTooLarge")

    def test_413_before_authentication(self, client: TestClient) -> None:
        r = client.post(
            "/v1/users/lin/episodes",
            content=b"x" * (70 * 1024),
            headers={"Content-Type": "application/json"},
        )
        assert_error(r, 413, "PayloadTooLarge")


class TestKeyCheck:
    def test_the_stored_digest_must_match(
        self, db: Database, make_key: MakeKey, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        """The final check compares digests with compare_digest, whatever the lookup said."""
        secret = make_key("robot")
        with db.transaction() as session:
            assert auth.authenticate(session, f"Bearer {secret}").role == "robot"
            [key] = list_keys(session)
            stranger = dataclasses.replace(key, secret_hash="0" * 64)
            monkeypatch.setattr(keys_repo, "by_hash", lambda *_: stranger)
            with pytest.raises(Unauthorized):
                auth.authenticate(session, f"Bearer {secret}")

    def test_compared_in_constant_time(
        self, monkeypatch: pytest.MonkeyPatch, db: Database, make_key: MakeKey
    ) -> None:
        secret = make_key("robot")
        seen: list[tuple[str, str]] = []
        real = hmac.compare_digest

        def spy(a: str, b: str) -> bool:
            seen.append((a, b))
            return real(a, b)

        monkeypatch.setattr(hmac, "compare_digest", spy)
        with db.transaction() as session:
            auth.authenticate(session, f"Bearer {secret}")
        assert seen == [(auth.hash_secret(secret), auth.hash_secret(secret))]


class TestAudit:
    def test_admin_actions_are_logged_who_what_when(
        self, admin: TestClient, robot: TestClient, lin: dict[str, str], db: Database
    ) -> None:
        before = dt.datetime.now(dt.UTC)
        doc = admin.get("/v1/users/lin/model/export").json()
        assert admin.put("/v1/users/lin/model", json=doc).status_code == 200
        assert admin.delete("/v1/users/lin/model").status_code == 204
        assert admin.delete("/v1/users/lin").status_code == 204
        with db.transaction() as session:
            [key] = [k for k in list_keys(session) if k.role == "robot"]
            revoke_key(session, key.id)  # the command line's revocation
        items = admin.get("/v1/admin/audit").json()["items"]
        actions = [(e["action"], e["target"]) for e in items]
        assert actions[:5] == [
            ("key.revoke", key.id),
            ("user.delete", "lin"),
            ("model.reset", "lin"),
            ("model.import", "lin"),
            ("model.export", "lin"),
        ]
        for e in items[1:5]:
            assert e["actor"]["role"] == "admin"
            assert e["actor"]["key_id"].startswith("key_")
            assert e["fleet"] == "default"
            assert dt.datetime.fromisoformat(e["at"]) >= before - dt.timedelta(seconds=1)
        assert items[0]["actor"]["key_id"] == "cli"
        # The erasure's own entry, and the entries about the erased person, say nothing of them
        assert [e["detail"] for e in items[1:5]] == [{"erased": True}] * 4
        # key creation is an admin action too (the fixtures made the keys)
        assert {e["action"] for e in items[5:]} == {"key.create"}

    def test_failed_or_forbidden_actions_leave_no_entry(
        self, admin: TestClient, robot: TestClient, lin: dict[str, str]
    ) -> None:
        count = len(admin.get("/v1/admin/audit?limit=500").json()["items"])
        assert robot.delete("/v1/users/lin").status_code == 403
        assert admin.delete("/v1/users/nobody").status_code == 404
        assert admin.put("/v1/users/lin/model", json={"format": "x"}).status_code == 422
        assert len(admin.get("/v1/admin/audit?limit=500").json()["items"]) == count

    def test_pages_newest_first(self, admin: TestClient, robot: TestClient) -> None:
        for i in range(5):
            start(robot, f"u{i}", f"u{i}-1")
            assert admin.delete(f"/v1/users/u{i}/model").status_code == 204
        seen: list[str] = []
        cursor = None
        for _ in range(10):
            page = admin.get(
                "/v1/admin/audit", params={"limit": 2, **({"cursor": cursor} if cursor else {})}
            ).json()
            seen += [e["target"] for e in page["items"] if e["action"] == "model.reset"]
            cursor = page["next_cursor"]
            if cursor is None:
                break
        assert seen == [f"u{i}" for i in reversed(range(5))]
        assert_error(admin.get("/v1/admin/audit?cursor=abc"), 422, "ValidationError")

    def test_entries_are_append_only(
        self, db: Database, admin: TestClient, lin: dict[str, str]
    ) -> None:
        from sqlalchemy import text
        from sqlalchemy.exc import DatabaseError

        admin.delete("/v1/users/lin/model")
        for statement in ("UPDATE audit_log SET action = 'model.export'", "DELETE FROM audit_log"):
            with pytest.raises(DatabaseError, match="append only"), db.transaction() as session:
                session.execute(text(statement))
        assert [e["action"] for e in admin.get("/v1/admin/audit").json()["items"]] == [
            "model.reset",
            "key.create",
            "key.create",
        ]

    def test_storing_a_rebuilt_model_is_logged(
        self,
        admin: TestClient,
        robot: TestClient,
        lin: dict[str, str],
        db: Database,
        settings: Settings,
    ) -> None:
        from sqlalchemy import update
        from typer.testing import CliRunner

        from app import cli
        from app.db.models import LearnerModel
        from app.services.context import ServiceContext
        from app.services.person_model import fresh_learner
        from tests.support.rows import user_pk

        kind = robot.get(f"/v1/episodes/{lin['episode']}").json()["decisions"][0]["action"]
        response = "accepted" if kind["kind"] == "initiate" else "none"
        assert (
            robot.post(
                f"/v1/episodes/{lin['episode']}/outcomes",
                json={"decision_id": lin["decision"], "response": response},
            ).status_code
            == 200
        )
        with db.transaction() as session:  # the stored model no longer matches its history
            session.execute(
                update(LearnerModel)
                .where(LearnerModel.user_pk == user_pk(session, "lin"))
                .values(
                    state=fresh_learner(
                        "hri", None, ServiceContext.from_settings(settings).mission
                    ).to_state(),
                    state_version=LearnerModel.version,
                )
            )
        result = CliRunner().invoke(
            cli.app,
            ["models", "rebuild", "lin", "--save"],
            env={"ATTUNE_DATABASE_URL": settings.database_url, "ATTUNE_SEED": "0"},
        )
        with warnings.catch_warnings():  # the command leaves its connections to the collector
            warnings.simplefilter("ignore", ResourceWarning)
            gc.collect()
        assert result.exit_code == 1, result.output
        entry = admin.get("/v1/admin/audit").json()["items"][0]
        assert (entry["action"], entry["target"], entry["actor"]["key_id"]) == (
            "model.rebuild",
            "lin",
            "cli",
        )
