"""The access matrix: every route of the API and of the console x every kind of caller
(docs/api.md, "Keys, roles and fleets"; docs/console.md). The cells whose write succeeds run on
both engines; refusals, reads and the probes, decided the same way on both, on SQLite.

The world of every test, made through the API: fleets ``fleet-a`` and ``fleet-b`` each have a
user ``lin`` (the same id, two people) with an answered episode that has feedback and an open
episode with its current decision, each made with its fleet's robot key; ``fleet-a`` also has
``only-a`` (on SQLite a worker makes it once and starts each later test from a copy of that
database file). The callers (the matrix's columns): no key, a revoked (admin) key, the robot and the
staff key of each fleet, and an admin key (fleet ``default``). Paths name A's resources: a user
route's ``{user_id}`` is ``lin``, which robot and staff keys of either fleet find in their own
fleet, and the admin key names ``fleet-a`` with ``?fleet=`` (the ``{q}`` of a path); an episode
route's ``{episode_id}`` is an episode of A's ``lin``.

- ``MATRIX``: one row per route (method, path, body, the status of each caller). A route the app
  serves without a row, or a row without a route, fails ``test_every_route_has_a_row``. Every
  cell checks the status and the contract's error body (or the console's error page), and that
  the fleet the caller did not address is unchanged; a write that succeeded changed the
  addressed fleet's ``lin``.
- ``FIELDS``: one row per field-level right of ``PUT /v1/users/{user_id}`` (each field of
  ``UserIn`` and each query parameter but ``fleet``): the status of each caller changing it on
  ``lin`` and setting it on a user the request creates. A field without a row, or without its
  right in the service's table (``USER_FIELD_RIGHTS``), fails
  ``test_every_field_has_a_decided_right``, and so does a row whose statuses are not the
  table's.
- ``PROBES``: another fleet's user or episode is answered exactly as an id that never existed:
  same status, same body once the two ids are swapped for one placeholder.
- Then: each fleet acts on its own ``lin``; the admin's ``?fleet=``; the console's sign-in; the
  audit log and the lists, per fleet.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from fastapi.routing import iter_route_contexts
from fastapi.testclient import TestClient

from app.console.auth import COOKIE, csrf_token
from app.learning import office_mission
from app.schemas.users import UserIn
from app.services.users import USER_FIELD_RIGHTS
from tests.support.contract import assert_error
from tests.support.episodes import event
from tests.support.fixtures import MakeKey, WorkerDatabases

A, B = "fleet-a", "fleet-b"
PRINCIPALS = ("none", "revoked", "robot_a", "robot_b", "staff_a", "staff_b", "admin")
# role and fleet of each caller's key ("none" has no key)
KEYS = {
    "revoked": ("admin", "default"),
    "robot_a": ("robot", A),
    "robot_b": ("robot", B),
    "staff_a": ("staff", A),
    "staff_b": ("staff", B),
    "admin": ("admin", "default"),
}
# The fleet whose ``lin`` a caller addresses: its own; the admin names fleet-a (``{q}``).
HOME = {"robot_a": A, "staff_a": A, "admin": A, "robot_b": B, "staff_b": B}
ADMIN_Q = f"?fleet={A}"
NEVER_EPISODE = "ep_" + "0" * 32  # an episode id that never existed
EXPORT = "{export}"  # a body: the export document of the caller's fleet's lin (A's for others)
LOGIN, CSRF = "login", "csrf"  # console forms: the caller's key; the page's CSRF token
MISSION = "mission"  # the mission page's form, applying COCOA's mission, with the CSRF token
CORRECT = "correct"  # a profile's correction form (a quiet correction), with the CSRF token
RETENTION = "retention"  # the history kept page's form (3650 days), with the CSRF token

Expect = tuple[int, int, int, int, int, int, int]  # one status per PRINCIPALS


@dataclass(frozen=True)
class Row:
    """One route: its method and path (placeholders ``{user_id}``, ``{episode_id}``,
    ``{open_episode_id}``, ``{key_id}``, ``{q}``), a body, the status for each caller."""

    method: str
    path: str
    expect: Expect
    json: Any = None
    form: str | None = None
    writes: bool = False  # a success changes the addressed fleet's lin
    route: str | None = None  # the app's path, when ``path`` does not spell it
    bugs: dict[str, str] = field(default_factory=dict)  # caller -> why the cell is xfail

    @property
    def key(self) -> tuple[str, str]:
        return self.method, self.route or self.path.replace("{q}", "")


OUTCOME = {"decision_id": "{decision_id}", "response": "{response}"}
FEEDBACK = {"feedback_id": "matrix-fb", "feedback": "positive"}
NEW_KEY = {"role": "robot", "fleet": A, "name": "matrix"}
CORRECTION = {
    "correction_id": "matrix-c",
    "time_slot": "afternoon",
    "situation": "working",
    "kind": "quiet",
}
# fleet-a's mission with one more detail: every model of fleet-a moves to its version 2.
COCOA = {
    "change_id": "matrix-change",
    "mission": {
        **office_mission().to_dict(),
        "services": [
            {
                "name": s.name,
                "details": [*s.details, "cocoa"] if s.name == "ProvideDrink" else list(s.details),
            }
            for s in office_mission().services
        ],
    },
}

# The console's form for the same change: the services as lines, the rest kept as it is.
MISSION_FORM = {
    "change_id": "matrix-change",
    "base_version": "1",
    "step": "confirm",
    "services": "\n".join(
        f"{s.name}: {', '.join(s.details)}" + (", cocoa" if s.name == "ProvideDrink" else "")
        for s in office_mission().services
    ),
}

# The whole matrix at a glance.
#   none / revoked: no key, a revoked key; rA rB sA sB: robot and staff of fleet-a / fleet-b;
#   adm: admin (with ?fleet=fleet-a where {q} is).
U = "/v1/users/{user_id}"
C = "/admin/users/{user_id}"
MATRIX: list[Row] = [
    #    method    path                                  none  rev   rA   rB   sA   sB  adm
    Row("GET", "/livez", (200, 200, 200, 200, 200, 200, 200)),
    Row("GET", "/healthz", (200, 200, 200, 200, 200, 200, 200)),
    Row("GET", "/readyz", (200, 200, 200, 200, 200, 200, 200)),
    Row("GET", "/metrics", (200, 200, 200, 200, 200, 200, 200)),
    Row("GET", "/v1/mission", (401, 401, 200, 200, 200, 200, 200)),
    Row("GET", "/v1/users{q}", (401, 401, 200, 200, 200, 200, 200)),
    Row("GET", U + "{q}", (401, 401, 200, 200, 200, 200, 200)),
    # Setting nothing: every key of the fleet. Each field is a right of its own (FIELDS).
    Row("PUT", U + "{q}", (401, 401, 200, 200, 200, 200, 200), json={}),
    Row("DELETE", U + "{q}", (401, 401, 403, 403, 204, 204, 204), writes=True),
    Row(
        "POST",
        U + "/episodes{q}",
        (401, 401, 201, 201, 201, 201, 201),
        json=event("matrix-1"),
        writes=True,
    ),
    Row("GET", U + "/episodes{q}", (401, 401, 200, 200, 200, 200, 200)),
    Row("GET", U + "/model{q}", (401, 401, 200, 200, 200, 200, 200)),
    Row("GET", U + "/stats{q}", (401, 401, 200, 200, 200, 200, 200)),
    Row("DELETE", U + "/model{q}", (401, 401, 403, 403, 204, 204, 204), writes=True),
    Row("GET", U + "/model/export{q}", (401, 401, 403, 403, 200, 200, 200)),
    Row("PUT", U + "/model{q}", (401, 401, 403, 403, 200, 200, 200), json=EXPORT, writes=True),
    Row("GET", U + "/profile{q}", (401, 401, 200, 200, 200, 200, 200)),
    Row("GET", U + "/corrections{q}", (401, 401, 200, 200, 200, 200, 200)),
    Row("GET", U + "/views{q}", (401, 401, 403, 403, 200, 200, 200)),
    Row("GET", U + "/changes{q}", (401, 401, 403, 403, 200, 200, 200)),
    Row("GET", U + "/export{q}", (401, 401, 403, 403, 200, 200, 200)),
    Row(
        "POST",
        U + "/corrections{q}",
        (401, 401, 403, 403, 201, 201, 201),
        json=CORRECTION,
        writes=True,
    ),
    Row(
        "DELETE",
        U + "/corrections/world-c{q}",
        (401, 401, 403, 403, 204, 204, 204),
        writes=True,
        route=U + "/corrections/{correction_id}",
    ),
    Row(
        "POST",
        "/v1/episodes/{open_episode_id}/outcomes",
        (401, 401, 200, 404, 200, 404, 200),
        json=OUTCOME,
        writes=True,
        route="/v1/episodes/{episode_id}/outcomes",
    ),
    Row(
        "POST",
        "/v1/episodes/{episode_id}/feedback",
        (401, 401, 200, 404, 200, 404, 200),
        json=FEEDBACK,
        writes=True,
    ),
    Row("GET", "/v1/episodes/{episode_id}", (401, 401, 200, 404, 200, 404, 200)),
    Row("GET", "/v1/admin/audit", (401, 401, 403, 403, 200, 200, 200)),
    Row("GET", "/v1/admin/views", (401, 401, 403, 403, 200, 200, 200)),
    Row("POST", "/v1/admin/keys", (401, 401, 403, 403, 403, 403, 201), json=NEW_KEY),
    Row("GET", "/v1/admin/keys", (401, 401, 403, 403, 403, 403, 200)),
    Row("DELETE", "/v1/admin/keys/{key_id}", (401, 401, 403, 403, 403, 403, 204)),
    Row("GET", "/v1/admin/fleets", (401, 401, 403, 403, 403, 403, 200)),
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/missions",
        (401, 401, 403, 403, 200, 403, 200),
        route="/v1/admin/fleets/{fleet}/missions",
    ),
    Row(
        "PUT",
        f"/v1/admin/fleets/{A}/mission",
        (401, 401, 403, 403, 200, 403, 200),
        json=COCOA,
        writes=True,
        route="/v1/admin/fleets/{fleet}/mission",
    ),
    # Turning a fleet's prior off changes no one's model: only the fleet's next newcomers.
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/prior",
        (401, 401, 403, 403, 200, 403, 200),
        route="/v1/admin/fleets/{fleet}/prior",
    ),
    Row(
        "PUT",
        f"/v1/admin/fleets/{A}/prior",
        (401, 401, 403, 403, 200, 403, 200),
        json={"enabled": False},
        route="/v1/admin/fleets/{fleet}/prior",
    ),
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/history",
        (401, 401, 403, 403, 200, 403, 200),
        route="/v1/admin/fleets/{fleet}/history",
    ),
    Row(
        "PUT",
        f"/v1/admin/fleets/{A}/history",
        (401, 401, 403, 403, 200, 403, 200),
        json={"history_days": 3650},
        route="/v1/admin/fleets/{fleet}/history",
    ),
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/changes",
        (401, 401, 403, 403, 200, 403, 200),
        route="/v1/admin/fleets/{fleet}/changes",
    ),
    # What if: an evaluation is a job of the fleet's staff and admins; it changes no one.
    Row(
        "POST",
        f"/v1/admin/fleets/{A}/evaluations",
        (401, 401, 403, 403, 202, 403, 202),
        json={"request_id": "matrix-e", "candidates": [{"algorithm": "dts"}]},
        route="/v1/admin/fleets/{fleet}/evaluations",
    ),
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/evaluations",
        (401, 401, 403, 403, 200, 403, 200),
        route="/v1/admin/fleets/{fleet}/evaluations",
    ),
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/evaluations/ev_{'0' * 32}",
        (401, 401, 403, 403, 404, 403, 404),
        route="/v1/admin/fleets/{fleet}/evaluations/{evaluation_id}",
    ),
    Row(
        "POST",
        f"/v1/admin/fleets/{A}/evaluations/ev_{'0' * 32}/cancel",
        (401, 401, 403, 403, 404, 403, 404),
        route="/v1/admin/fleets/{fleet}/evaluations/{evaluation_id}/cancel",
    ),
    # A rollout to everyone moves lin to the candidate; a shadow changes no one.
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/rollout",
        (401, 401, 403, 403, 404, 403, 404),
        route="/v1/admin/fleets/{fleet}/rollout",
    ),
    Row(
        "PUT",
        f"/v1/admin/fleets/{A}/rollout",
        (401, 401, 403, 403, 201, 403, 201),
        json={"candidate": {"algorithm": "hri", "params": {"tau": 0.005}}, "share": 1.0},
        writes=True,
        route="/v1/admin/fleets/{fleet}/rollout",
    ),
    Row(
        "POST",
        f"/v1/admin/fleets/{A}/rollout/promote",
        (401, 401, 403, 403, 409, 403, 409),
        route="/v1/admin/fleets/{fleet}/rollout/promote",
    ),
    Row(
        "POST",
        f"/v1/admin/fleets/{A}/rollout/rollback",
        (401, 401, 403, 403, 409, 403, 409),
        route="/v1/admin/fleets/{fleet}/rollout/rollback",
    ),
    Row(
        "GET",
        f"/v1/admin/fleets/{A}/shadow",
        (401, 401, 403, 403, 404, 403, 404),
        route="/v1/admin/fleets/{fleet}/shadow",
    ),
    Row(
        "PUT",
        f"/v1/admin/fleets/{A}/shadow",
        (401, 401, 403, 403, 201, 403, 201),
        json={"candidate": {"algorithm": "dts"}},
        route="/v1/admin/fleets/{fleet}/shadow",
    ),
    Row(
        "DELETE",
        f"/v1/admin/fleets/{A}/shadow",
        (401, 401, 403, 403, 409, 403, 409),
        route="/v1/admin/fleets/{fleet}/shadow",
    ),
    # The console: a cookie holding the key (staff and admin get it by signing in; robot and
    # revoked keys, refused there, send one made by hand). "none": no cookie, so the pages
    # send the browser to the login form (303).
    Row("GET", "/admin", (303, 303, 303, 303, 303, 303, 303)),
    Row("GET", "/admin/login", (200, 200, 200, 200, 200, 200, 200)),
    Row("POST", "/admin/login", (401, 401, 403, 403, 303, 303, 303), form=LOGIN),
    Row("POST", "/admin/logout", (303, 303, 303, 303, 303, 303, 303), form=CSRF),
    Row("GET", "/admin/users", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", C + "{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", C + "/details{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row(
        "POST",
        C + "/corrections{q}",
        (303, 401, 403, 403, 303, 303, 303),
        form=CORRECT,
        writes=True,
    ),
    Row(
        "POST",
        C + "/corrections/world-c/lift{q}",
        (303, 401, 403, 403, 303, 303, 303),
        form=CSRF,
        writes=True,
        route=C + "/corrections/{correction_id}/lift",
    ),
    Row("GET", C + "/why{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", C + "/episodes{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", C + "/episodes/{episode_id}/trace{q}", (303, 401, 403, 403, 200, 404, 200)),
    Row("GET", C + "/export{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", C + "/everything{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", C + "/reset{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("POST", C + "/reset{q}", (303, 401, 403, 403, 303, 303, 303), form=CSRF, writes=True),
    Row("GET", C + "/delete{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("POST", C + "/delete{q}", (303, 401, 403, 403, 303, 303, 303), form=CSRF, writes=True),
    Row("GET", "/admin/mission{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row(
        "POST", "/admin/mission{q}", (303, 401, 403, 403, 303, 303, 303), form=MISSION, writes=True
    ),
    Row("GET", "/admin/retention{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", "/admin/changes{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("POST", "/admin/retention{q}", (303, 401, 403, 403, 303, 303, 303), form=RETENTION),
    Row("GET", "/admin/evaluations{q}", (303, 401, 403, 403, 200, 200, 200)),
    # A form without its number (the page gives each form one): refused in words.
    Row("POST", "/admin/evaluations{q}", (303, 401, 403, 403, 400, 400, 400), form=CSRF),
    Row(
        "GET",
        f"/admin/evaluations/ev_{'0' * 32}{{q}}",
        (303, 401, 403, 403, 404, 404, 404),
        route="/admin/evaluations/{evaluation_id}",
    ),
    Row(
        "GET",
        f"/admin/evaluations/ev_{'0' * 32}/progress{{q}}",
        (303, 401, 403, 403, 404, 404, 404),
        route="/admin/evaluations/{evaluation_id}/progress",
    ),
    Row(
        "POST",
        f"/admin/evaluations/ev_{'0' * 32}/cancel{{q}}",
        (303, 401, 403, 403, 404, 404, 404),
        form=CSRF,
        route="/admin/evaluations/{evaluation_id}/cancel",
    ),
    Row("GET", C + "/whatif{q}", (303, 401, 403, 403, 200, 200, 200)),
    Row("GET", "/admin/rollout{q}", (303, 401, 403, 403, 200, 200, 200)),
    # The start forms without a learner chosen: refused in words.
    Row("POST", "/admin/rollout{q}", (303, 401, 403, 403, 422, 422, 422), form=CSRF),
    Row("POST", "/admin/rollout/shadow{q}", (303, 401, 403, 403, 422, 422, 422), form=CSRF),
    # Nothing runs: nothing to stop, change, promote or roll back, said in words.
    Row("GET", "/admin/rollout/shadow/stop{q}", (303, 401, 403, 403, 409, 409, 409)),
    Row("POST", "/admin/rollout/shadow/stop{q}", (303, 401, 403, 403, 409, 409, 409), form=CSRF),
    Row("POST", "/admin/rollout/share{q}", (303, 401, 403, 403, 409, 409, 409), form=CSRF),
    Row("GET", "/admin/rollout/promote{q}", (303, 401, 403, 403, 409, 409, 409)),
    Row("POST", "/admin/rollout/promote{q}", (303, 401, 403, 403, 409, 409, 409), form=CSRF),
    Row("GET", "/admin/rollout/rollback{q}", (303, 401, 403, 403, 409, 409, 409)),
    Row("POST", "/admin/rollout/rollback{q}", (303, 401, 403, 403, 409, 409, 409), form=CSRF),
    Row("GET", "/admin/nowhere", (404, 404, 404, 404, 404, 404, 404), route="/admin/{rest:path}"),
]
# Served to anyone, key or not: the schema, its two pages and the static files.
OPEN = {
    ("GET", "/openapi.json"): "/openapi.json",
    ("GET", "/docs"): "/docs",
    ("GET", "/redoc"): "/redoc",
    ("MOUNT", "/static/docs"): "/static/docs/redoc/LICENSE",
    ("MOUNT", "/admin/static"): "/admin/static/console.css",
}


# -- the world ---------------------------------------------------------------------------------
@dataclass
class Fleet:
    episode: str  # answered, with feedback
    open_episode: str  # open, with its current decision
    decision: str
    response: str  # one the current decision expects
    export: dict[str, Any]


@dataclass
class World:
    client: TestClient
    secrets: dict[str, str]
    victim: str  # the id of a key nobody uses, for DELETE /v1/admin/keys
    fleets: dict[str, Fleet]
    cookies: dict[str, str | None] = field(default_factory=dict)
    tokens: dict[str, str] = field(default_factory=dict)

    def secret(self, who: str) -> str | None:
        return self.secrets.get(who)

    def fill(self, value: Any, who: str) -> Any:
        """A path or body with the world's ids, as ``who`` sends it."""
        if value == EXPORT:
            return self.fleets[HOME.get(who, A)].export
        if isinstance(value, dict):
            return {k: self.fill(v, who) for k, v in value.items()}
        if not isinstance(value, str):
            return value
        a = self.fleets[A]
        ids = {
            "user_id": "lin",
            "episode_id": a.episode,
            "open_episode_id": a.open_episode,
            "decision_id": a.decision,
            "response": a.response,
            "key_id": self.victim,
            "q": ADMIN_Q if who == "admin" else "",
        }
        return re.sub(r"\{(\w+)\}", lambda m: ids[m.group(1)], value)

    def cookie(self, who: str) -> str | None:
        """The console cookie of ``who``: what signing in set for staff and admin keys; the
        key itself, by hand, for keys the sign-in refuses."""
        if who not in self.cookies:
            secret = self.secret(who)
            if secret is not None and KEYS[who][0] in ("staff", "admin") and who != "revoked":
                r = send(self, "POST", "/admin/login", who, form={"key": secret})
                assert r.status_code == 303, (who, r.status_code, r.text)
                assert r.cookies.get(COOKIE) == secret
            self.cookies[who] = secret
        return self.cookies[who]

    def csrf(self, who: str) -> str:
        """The CSRF token of ``who``'s console pages (as its own key would make it when the
        pages refuse it: the refusal must then be for the key, not the token)."""
        secret = self.secret(who)
        if secret is None:
            return ""
        if who not in self.tokens:
            page = send(self, "GET", "/admin/users", who)
            found = re.search(r'name="csrf" value="([0-9a-f]{64})"', page.text)
            if page.status_code == 200:
                assert found, "no CSRF token in the page"
                assert found.group(1) == csrf_token(secret)
            self.tokens[who] = found.group(1) if found else csrf_token(secret)
        return self.tokens[who]

    def snapshot(self) -> dict[str, Any]:
        """What each fleet's users look like (read with the admin key), once the moves a
        rollout owes are done (the worker does them in the background, after the answer)."""
        mover = getattr(self.client.app.state, "rollout_mover", None)  # type: ignore[attr-defined]
        if mover is not None:
            mover.join(30)
        out: dict[str, Any] = {}
        for fleet in (A, B):
            seen: dict[str, Any] = {}
            users = ("lin", "only-a") if fleet == A else ("lin",)
            for user in users:
                for tail in ("", "/model", "/stats", "/episodes"):
                    r = send(self, "GET", f"/v1/users/{user}{tail}?fleet={fleet}", "admin")
                    seen[user + tail] = r.json() if r.status_code == 200 else r.status_code
            out[fleet] = seen
        return out


def send(
    world: World,
    method: str,
    path: str,
    who: str,
    *,
    json: Any = None,
    form: dict[str, str] | None = None,
) -> httpx.Response:
    """One request as ``who``: its key in the Authorization header for the API, in the console's
    cookie for the console (no key or cookie for "none")."""
    client = world.client
    client.cookies.clear()  # only the cookie given here, never one a sign-in left in the jar
    headers: dict[str, str] = {}
    if path.startswith("/admin"):
        if path != "/admin/login" and who in KEYS:
            cookie = world.cookie(who)
            if cookie is not None:
                headers["Cookie"] = f"{COOKIE}={cookie}"
    elif who in KEYS:
        headers["Authorization"] = f"Bearer {world.secrets[who]}"
    r: httpx.Response
    if form is not None:
        r = client.request(method, path, data=form, headers=headers)
    elif json is not None:
        r = client.request(method, path, json=json, headers=headers)
    else:
        r = client.request(method, path, headers=headers)
    return r


def _ok(r: httpx.Response, status: int) -> dict[str, Any]:
    assert r.status_code == status, (r.request.method, str(r.request.url), r.status_code, r.text)
    body: dict[str, Any] = r.json()
    return body


def _answer(expects: list[str]) -> str:
    """A response the decision expects that needs no service or detail."""
    for response in ("none", "rejected", "terminated"):
        if response in expects:
            return response
    raise AssertionError(f"no simple response in {expects}")


@dataclass(frozen=True)
class Saved:
    """A world built once by this worker on SQLite: its database file and what the tests
    need to know of it (every later SQLite test starts from a copy of that file)."""

    path: Path
    secrets: dict[str, str]
    victim: str
    fleets: dict[str, Fleet]


_SAVED: dict[str, Saved] = {}


@pytest.fixture
def world(
    app: FastAPI, make_key: MakeKey, database_url: str, worker_databases: WorkerDatabases
) -> Iterator[World]:
    saved = _SAVED.get(database_url)
    if saved is not None:
        worker_databases.tables(database_url).restore(saved.path)
        with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as client:
            yield World(client, dict(saved.secrets), saved.victim, copy.deepcopy(saved.fleets))
        return
    with _built(app, make_key) as w:
        if database_url.startswith("sqlite"):
            path = worker_databases.tables(database_url).save("fleet-matrix")
            _SAVED[database_url] = Saved(path, dict(w.secrets), w.victim, copy.deepcopy(w.fleets))
        yield w


@contextmanager
def _built(app: FastAPI, make_key: MakeKey) -> Iterator[World]:
    """The world, made through the API (see the module's docstring)."""
    secrets = {who: make_key(role, fleet, who) for who, (role, fleet) in KEYS.items()}
    make_key("robot", A, "victim")
    with TestClient(app, raise_server_exceptions=False, follow_redirects=False) as client:
        w = World(client, secrets, "", {})
        ids = {
            k["name"]: k["key_id"]
            for k in _ok(send(w, "GET", "/v1/admin/keys", "admin"), 200)["items"]
        }
        w.victim = ids["victim"]
        # Used once (the worker keeps it in its key cache), then revoked over HTTP: it stops
        # at once.
        assert send(w, "GET", "/v1/mission", "revoked").status_code == 200
        assert send(w, "DELETE", f"/v1/admin/keys/{ids['revoked']}", "admin").status_code == 204
        for fleet, robot, staff in ((A, "robot_a", "staff_a"), (B, "robot_b", "staff_b")):
            _ok(
                send(w, "PUT", "/v1/users/lin", robot, json={"display_name": f"Lin of {fleet}"}),
                201,
            )
            first = _ok(send(w, "POST", "/v1/users/lin/episodes", robot, json=event("lin-1")), 201)
            episode, decision = first["episode_id"], first["decision"]
            _ok(
                send(
                    w,
                    "POST",
                    f"/v1/episodes/{episode}/outcomes",
                    robot,
                    json={
                        "decision_id": decision["decision_id"],
                        "response": _answer(decision["expects"]),
                    },
                ),
                200,
            )
            _ok(
                send(
                    w,
                    "POST",
                    f"/v1/episodes/{episode}/feedback",
                    robot,
                    json={"feedback_id": "fb-1", "feedback": "positive"},
                ),
                200,
            )
            second = _ok(
                send(w, "POST", "/v1/users/lin/episodes", robot, json=event("lin-2", "working")),
                201,
            )
            _ok(
                send(
                    w,
                    "POST",
                    "/v1/users/lin/corrections",
                    staff,
                    json={
                        **CORRECTION,
                        "correction_id": "world-c",
                        "kind": "avoid",
                        "service": "BriefInformation",
                    },
                ),
                201,
            )
            export = _ok(send(w, "GET", "/v1/users/lin/model/export", staff), 200)
            w.fleets[fleet] = Fleet(
                episode,
                second["episode_id"],
                second["decision"]["decision_id"],
                _answer(second["decision"]["expects"]),
                export,
            )
        _ok(send(w, "POST", "/v1/users/only-a/episodes", "robot_a", json=event("only-1")), 201)
        yield w


# -- every route has a row -----------------------------------------------------------------------
def _served(app: FastAPI) -> set[tuple[str, str]]:
    served: set[tuple[str, str]] = set()
    for route in iter_route_contexts(app.routes):
        path = route.path
        assert path is not None, route
        if route.methods is None:  # a mounted app (static files)
            served.add(("MOUNT", path))
        else:
            served |= {(method, path) for method in route.methods if method != "HEAD"}
    return served


@pytest.mark.one_engine
def test_every_route_has_a_row(app: FastAPI) -> None:
    rows = [row.key for row in MATRIX]
    assert len(rows) == len(set(rows)), "a route has two rows"
    served = _served(app)
    assert len(served) >= len(MATRIX)
    assert sorted(served - set(rows) - set(OPEN)) == [], "routes without a row in MATRIX"
    assert sorted(set(rows) - served) == [], "rows of MATRIX without a route"
    assert sorted(set(OPEN) - served) == [], "OPEN lists a route the app does not serve"


def test_open_routes_answer_anyone(world: World) -> None:
    for path in OPEN.values():
        for who in PRINCIPALS:
            r = send(world, "GET", path, who)
            assert r.status_code == 200, (path, who, r.status_code)


# -- the matrix ----------------------------------------------------------------------------------
def _cells(*, writes: bool) -> Iterator[Any]:
    """The cells whose request succeeds in changing the addressed fleet (``writes``: these
    run on both engines), or every other cell (refusals and reads: decided the same way on
    both, so SQLite alone)."""
    for row in MATRIX:
        for who, status in zip(PRINCIPALS, row.expect, strict=True):
            if (row.writes and status < 400 and who in HOME) != writes:
                continue
            marks = (
                [pytest.mark.xfail(strict=True, reason=row.bugs[who])] if who in row.bugs else []
            )
            yield pytest.param(row, who, status, id=f"{row.method} {row.path} {who}", marks=marks)


def _check_console(r: httpx.Response, row: Row, who: str, status: int) -> None:
    if status == 303:
        location = r.headers["location"]
        if who == "none" and row.path.startswith(
            (
                "/admin/users",
                "/admin/mission",
                "/admin/retention",
                "/admin/changes",
                "/admin/evaluations",
                "/admin/rollout",
            )
        ):
            # Back to the page asked for, once signed in (the path's first words, before ids).
            path = row.path.split("{")[0]
            assert location.startswith(f"/admin/login?next={path}"), location
        else:
            assert not location.startswith("/admin/login?next="), location
    elif status >= 400:
        assert r.headers["content-type"].startswith("text/html")
        assert f'data-status="{status}"' in r.text
        assert "Lin of" not in r.text  # a refusal shows no one's data
    elif row.path.endswith("/export{q}"):
        assert r.json()["format"] == "attune.learner-state"
    elif row.path.endswith("/everything{q}"):
        assert r.json()["format"] == "attune.subject"
    else:
        assert r.headers["content-type"].startswith("text/html")


@pytest.mark.one_engine
@pytest.mark.parametrize(("row", "who", "status"), list(_cells(writes=False)))
def test_matrix(world: World, row: Row, who: str, status: int) -> None:
    _check_cell(world, row, who, status)


@pytest.mark.parametrize(("row", "who", "status"), list(_cells(writes=True)))
def test_matrix_writes(world: World, row: Row, who: str, status: int) -> None:
    _check_cell(world, row, who, status)


def _check_cell(world: World, row: Row, who: str, status: int) -> None:
    before = world.snapshot()
    path = world.fill(row.path, who)
    form: dict[str, str] | None = None
    if row.form == LOGIN:
        form = {"key": world.secret(who) or ""}
    elif row.form == CSRF:
        form = {"csrf": world.csrf(who)}
    elif row.form == MISSION:
        form = {"csrf": world.csrf(who), **MISSION_FORM}
    elif row.form == RETENTION:
        form = {"csrf": world.csrf(who), "keep": "days", "days": "3650"}
    elif row.form == CORRECT:
        form = {"csrf": world.csrf(who), **CORRECTION, "correction_id": "matrix-console-c"}
    r = send(world, row.method, path, who, json=world.fill(row.json, who), form=form)
    assert r.status_code == status, f"{row.method} {path} as {who}: {r.status_code} {r.text}"
    if row.path.startswith("/admin"):
        _check_console(r, row, who, status)
    elif status >= 400:
        assert_error(r, status)
    after = world.snapshot()
    done = r.status_code < 300 or (
        r.status_code == 303 and not r.headers["location"].startswith("/admin/login")
    )
    addressed = HOME.get(who)
    for fleet in (A, B):
        if row.writes and done and fleet == addressed:
            assert after[fleet] != before[fleet], f"{fleet} unchanged by {row.method} {path}"
        else:
            assert after[fleet] == before[fleet], f"{fleet} changed by {row.method} {path}"


# -- who may set what on PUT /v1/users/{user_id} -----------------------------------------------
@dataclass(frozen=True)
class Field:
    """One field-level right of ``PUT /v1/users/{user_id}`` (a field of ``UserIn``, or a query
    parameter of the route): the request that changes it on the addressed fleet's ``lin``
    (``change``, with the query ``change_query``) and the status for each caller, and the
    request that sets it on a user the request creates (``create``, ``create_query``)."""

    name: str
    change: dict[str, Any]
    changes: Expect
    create: dict[str, Any]
    creates: Expect
    change_query: str = ""
    create_query: str = ""
    writes: bool = True  # a change that succeeds changes lin


NEWCOMER = "newcomer"  # the user the create cells make
FIELDS: list[Field] = [
    #                                                   none  rev   rA   rB   sA   sB  adm
    Field(
        "display_name",
        {"display_name": "Renamed"},
        (401, 401, 403, 403, 200, 200, 200),
        {"display_name": "Newcomer"},
        (401, 401, 201, 201, 201, 201, 201),
    ),
    Field(
        "learner",
        {"learner": {"algorithm": "qlearning"}},
        (401, 401, 403, 403, 200, 200, 200),
        {"learner": {"algorithm": "qlearning"}},
        (401, 401, 201, 201, 201, 201, 201),
        change_query="reset_model=true",  # lin has history
    ),
    Field(
        "fleet_prior",
        {"fleet_prior": False},
        (401, 401, 403, 403, 200, 200, 200),
        {"fleet_prior": False},
        (401, 401, 201, 201, 201, 201, 201),
    ),
    Field(
        "reset_model",
        {},
        (401, 401, 403, 403, 200, 200, 200),
        {},
        (401, 401, 403, 403, 201, 201, 201),
        change_query="reset_model=true",
        create_query="reset_model=true",
        writes=False,  # alone, it allows a change of learner and changes nothing
    ),
]


def _put_user_route(app: FastAPI) -> Any:
    [route] = [
        r
        for r in iter_route_contexts(app.routes)
        if r.path == "/v1/users/{user_id}" and "PUT" in (r.methods or ())
    ]
    return route


@pytest.mark.one_engine
def test_every_field_has_a_decided_right(app: FastAPI) -> None:
    """Every field of ``UserIn`` and every query parameter of the PUT (but ``fleet``, which
    says whose user is meant) has its right in the service's table and its row here, and the
    row's statuses are what the table decides: a field added without a decided right fails."""
    route = _put_user_route(app)
    query = {q.alias for q in route.dependant.query_params} - {"fleet"}
    assert route.body_field is not None
    assert UserIn in getattr(route.body_field.field_info.annotation, "__args__", ()), (
        "the PUT's body is no longer UserIn"
    )
    decided = set(UserIn.model_fields) | query
    rows = [f.name for f in FIELDS]
    assert len(rows) == len(set(rows)), "a field has two rows"
    assert sorted(decided - set(USER_FIELD_RIGHTS)) == [], "fields without a right in the service"
    assert sorted(decided - set(rows)) == [], "fields without a row in FIELDS"
    assert sorted(set(rows) - decided) == [], "rows of FIELDS without a field"
    assert sorted(set(USER_FIELD_RIGHTS) - decided) == [], "rights of fields that do not exist"
    for f in FIELDS:
        right = USER_FIELD_RIGHTS[f.name]
        for who, change, create in zip(PRINCIPALS, f.changes, f.creates, strict=True):
            if who not in HOME:
                assert change == create == 401, (f.name, who)
                continue
            role = KEYS[who][0]
            assert (change == 403) == (role not in right.changes), (f.name, who, "change")
            assert (create == 403) == (role not in right.creates), (f.name, who, "create")


def _field_cells(*, keyed: bool) -> Iterator[Any]:
    """The cells of the callers with a key of the fleets (``keyed``: decided by what is
    stored, so on both engines), or of no key and a revoked one (refused before any SQL)."""
    for f in FIELDS:
        for kind, expect in (("change", f.changes), ("create", f.creates)):
            for who, status in zip(PRINCIPALS, expect, strict=True):
                if (who in HOME) == keyed:
                    yield pytest.param(f, kind, who, status, id=f"{f.name} {kind} {who}")


def _with_query(path: str, query: str) -> str:
    if not query:
        return path
    return path + ("&" if "?" in path else "?") + query


@pytest.mark.one_engine
@pytest.mark.parametrize(("field", "kind", "who", "status"), list(_field_cells(keyed=False)))
def test_who_may_set_what_needs_a_key(
    world: World, field: Field, kind: str, who: str, status: int
) -> None:
    _check_field(world, field, kind, who, status)


@pytest.mark.parametrize(("field", "kind", "who", "status"), list(_field_cells(keyed=True)))
def test_who_may_set_what(world: World, field: Field, kind: str, who: str, status: int) -> None:
    """A right of its own per field: a refusal is 403 naming the field, and changes nothing;
    a change changes the addressed fleet's lin only; a create makes the user with the field
    set."""
    _check_field(world, field, kind, who, status)


def _check_field(world: World, field: Field, kind: str, who: str, status: int) -> None:
    before = world.snapshot()
    user, body, query = (
        ("lin", field.change, field.change_query)
        if kind == "change"
        else (NEWCOMER, field.create, field.create_query)
    )
    path = _with_query(world.fill(f"/v1/users/{user}{{q}}", who), query)
    r = send(world, "PUT", path, who, json=body)
    assert r.status_code == status, f"PUT {path} {body} as {who}: {r.status_code} {r.text}"
    if status >= 400:
        err = assert_error(r, status)
        if status == 403:
            assert field.name in err["detail"], err
    after = world.snapshot()
    addressed = HOME.get(who)
    for fleet in (A, B):
        if kind == "change" and field.writes and status < 400 and fleet == addressed:
            assert after[fleet] != before[fleet], f"{fleet} unchanged by PUT {path} {body}"
        else:
            assert after[fleet] == before[fleet], f"{fleet} changed by PUT {path} {body}"
    if kind == "create" and addressed is not None:
        made = send(world, "GET", f"/v1/users/{NEWCOMER}?fleet={addressed}", "admin")
        if status == 201:
            shown = _ok(made, 200)
            for key, value in body.items():
                if key == "learner":
                    assert shown["learner"]["algorithm"] == value["algorithm"]
                else:
                    assert shown[key] == value, (key, shown)
        else:
            assert_error(made, 404, "NotFound")


# -- another fleet's user or episode: exactly an id that never existed ----------------------------
@dataclass(frozen=True)
class Probe:
    method: str
    hidden: str  # a path naming A's user or episode (from fleet B)
    absent: str  # the same path with an id that never existed
    expect: tuple[int, int]  # robot_b, staff_b
    json: Any = None
    form: bool = False  # a console POST with the page's CSRF token
    creates: bool = False  # both create B's own user: compare what is not an id
    bugs: dict[str, str] = field(default_factory=dict)


EP, NEVER = "{episode_id}", NEVER_EPISODE
OPEN_EP = "{open_episode_id}"
ONLY, NOBODY = "/v1/users/only-a", "/v1/users/nobody"
PROBES: list[Probe] = [
    #      method    hidden                          absent                     rB   sB
    Probe("GET", ONLY, NOBODY, (404, 404)),
    Probe("GET", ONLY + "/episodes", NOBODY + "/episodes", (404, 404)),
    Probe("GET", ONLY + "/model", NOBODY + "/model", (404, 404)),
    Probe("GET", ONLY + "/stats", NOBODY + "/stats", (404, 404)),
    Probe("DELETE", ONLY, NOBODY, (403, 404)),
    Probe("DELETE", ONLY + "/model", NOBODY + "/model", (403, 404)),
    Probe("GET", ONLY + "/model/export", NOBODY + "/model/export", (403, 404)),
    Probe("PUT", ONLY + "/model", NOBODY + "/model", (403, 404), json=EXPORT),
    Probe("PUT", ONLY, NOBODY, (201, 201), json={"display_name": "Someone"}, creates=True),
    Probe(
        "POST",
        ONLY + "/episodes",
        NOBODY + "/episodes",
        (201, 201),
        json=event("probe-1"),
        creates=True,
    ),
    Probe("GET", f"/v1/users/lin?fleet={A}", "/v1/users/lin?fleet=nofleet", (404, 404)),
    Probe("GET", f"/v1/users/lin?fleet={A}", NOBODY, (404, 404)),
    Probe("GET", f"/v1/users?fleet={A}", "/v1/users?fleet=nofleet", (404, 404)),
    Probe("GET", f"/v1/episodes/{EP}", f"/v1/episodes/{NEVER}", (404, 404)),
    Probe(
        "POST",
        f"/v1/episodes/{OPEN_EP}/outcomes",
        f"/v1/episodes/{NEVER}/outcomes",
        (404, 404),
        json=OUTCOME,
    ),
    Probe(
        "POST",
        f"/v1/episodes/{EP}/feedback",
        f"/v1/episodes/{NEVER}/feedback",
        (404, 404),
        json=FEEDBACK,
    ),
]
CONSOLE_ONLY, CONSOLE_NOBODY = "/admin/users/only-a", "/admin/users/nobody"
# Staff of B on A's users in the console (robot keys get 403 on every console page).
CONSOLE_PROBES: list[Probe] = (
    [
        Probe("GET", CONSOLE_ONLY + tail, CONSOLE_NOBODY + tail, (403, 404))
        for tail in ("", "/details", "/why", "/episodes", "/export", "/reset", "/delete")
    ]
    + [
        Probe("POST", CONSOLE_ONLY + tail, CONSOLE_NOBODY + tail, (403, 404), form=True)
        for tail in ("/reset", "/delete", "/corrections", "/corrections/world-c/lift")
    ]
    + [
        Probe("GET", f"/admin/users/lin?fleet={A}", "/admin/users/lin?fleet=nofleet", (403, 404)),
        # Another fleet's mission, or a fleet that does not exist: refused alike (as the API's
        # GET /v1/admin/fleets/{fleet}/missions refuses staff of another fleet).
        Probe("GET", f"/admin/mission?fleet={A}", "/admin/mission?fleet=nofleet", (403, 403)),
        Probe(
            "POST",
            f"/admin/mission?fleet={A}",
            "/admin/mission?fleet=nofleet",
            (403, 403),
            form=True,
        ),
        Probe(
            "GET",
            f"/admin/users/lin/episodes/{EP}/trace",
            f"/admin/users/lin/episodes/{NEVER}/trace",
            (403, 404),
        ),
    ]
)


def _ids(world: World, hidden: str, absent: str) -> list[tuple[str, str]]:
    """The (hidden, absent) ids a probe's two paths differ by, and so may its two answers."""
    a = world.fleets[A]
    pairs = [
        ("lin", "nobody"),
        ("only-a", "nobody"),
        (a.episode, NEVER),
        (a.open_episode, NEVER),
        (A, "nofleet"),
    ]
    return [(one, two) for one, two in pairs if one in hidden and two in absent]


def _same(value: Any, hidden: str, absent: str) -> Any:
    """``value`` with ``hidden`` and ``absent`` replaced by one placeholder, and what changes
    from one request to the next (request ids) left out."""
    if isinstance(value, dict):
        return {k: _same(v, hidden, absent) for k, v in value.items() if k != "request_id"}
    if isinstance(value, list):
        return [_same(v, hidden, absent) for v in value]
    if isinstance(value, str):
        return value.replace(hidden, "<id>").replace(absent, "<id>")
    return value


def _created(body: dict[str, Any]) -> dict[str, Any]:
    """A new user's or episode's answer without what differs from one id to another (the time,
    the server's ids, the drawn action, and the chances it was drawn with: a new learner that
    samples its beliefs draws them from the user's own seed stream)."""
    out = {k: v for k, v in body.items() if k not in ("created_at", "episode_id", "user_id")}
    if isinstance(out.get("decision"), dict):
        out["decision"] = {
            k: v
            for k, v in out["decision"].items()
            if k not in ("decision_id", "action", "expects")
        }
        out["decision"]["probabilities"] = [
            p["action"] for p in out["decision"].get("probabilities", [])
        ]
    return out


def _probe_cells() -> Iterator[Any]:
    for probes, callers in ((PROBES, ("robot_b", "staff_b")), (CONSOLE_PROBES, ("staff_b",))):
        for probe in probes:
            for who in callers:
                status = probe.expect[0 if who == "robot_b" else 1]
                marks = (
                    [pytest.mark.xfail(strict=True, reason=probe.bugs[who])]
                    if who in probe.bugs
                    else []
                )
                yield pytest.param(
                    probe, who, status, id=f"{probe.method} {probe.hidden} {who}", marks=marks
                )


@pytest.mark.one_engine  # answered before or by the same lookups on both engines
@pytest.mark.parametrize(("probe", "who", "status"), list(_probe_cells()))
def test_another_fleets_ids_are_ids_that_never_existed(
    world: World, probe: Probe, who: str, status: int
) -> None:
    only_a = send(world, "GET", "/v1/users/only-a", "robot_a").json()
    before_a = world.snapshot()[A]
    answers = []
    urls = world.fill(probe.hidden, who), world.fill(probe.absent, who)
    for url in urls:
        form = {"csrf": world.csrf(who)} if probe.form else None
        r = send(world, probe.method, url, who, json=world.fill(probe.json, who), form=form)
        assert r.status_code == status, f"{probe.method} {url} as {who}: {r.text}"
        answers.append(r)
    hidden, absent = answers
    assert hidden.headers["content-type"] == absent.headers["content-type"]
    if hidden.headers["content-type"].startswith("application/json"):
        one, two = hidden.json(), absent.json()
        if probe.creates:
            one, two = _created(one), _created(two)
        else:
            assert_error(hidden, status)
    else:
        one, two = hidden.text, absent.text
    for a_id, never_id in _ids(world, *urls):
        one, two = _same(one, a_id, never_id), _same(two, a_id, never_id)
    assert one == two, f"{probe.method} {probe.hidden} as {who} differs from an absent id"
    # A's users are as they were; a create made B's own user of that id.
    assert world.snapshot()[A] == before_a
    assert send(world, "GET", "/v1/users/only-a", "robot_a").json() == only_a
    if probe.creates:
        mine = _ok(send(world, "GET", "/v1/users/only-a", who), 200)
        assert mine["fleet"] == B
        assert mine["episodes"] == (1 if probe.method == "POST" else 0)
        assert mine["display_name"] == (None if probe.method == "POST" else "Someone")


# -- the same id, two people ---------------------------------------------------------------------
def _model(world: World, fleet: str) -> dict[str, Any]:
    return _ok(send(world, "GET", f"/v1/users/lin/model?fleet={fleet}", "admin"), 200)


@pytest.mark.parametrize(
    ("who", "q", "fleet"),
    [
        ("staff_a", "", A),
        ("staff_b", "", B),
        ("admin", f"?fleet={A}", A),
        ("admin", f"?fleet={B}", B),
    ],
)
def test_a_reset_stays_in_its_fleet(world: World, who: str, q: str, fleet: str) -> None:
    other = B if fleet == A else A
    before = world.snapshot()
    version = _model(world, fleet)["version"]
    assert send(world, "DELETE", f"/v1/users/lin/model{q}", who).status_code == 204
    after = world.snapshot()
    assert _model(world, fleet)["version"] == version + 1
    assert after[fleet]["lin/episodes"] == before[fleet]["lin/episodes"]  # history kept
    assert after[other] == before[other]  # the other lin: model, version, stats, history


@pytest.mark.parametrize("who", ["robot_a", "robot_b", "staff_a", "staff_b"])
def test_each_fleet_writes_its_own_lin(world: World, who: str) -> None:
    fleet = HOME[who]
    other = B if fleet == A else A
    staff = "staff_a" if fleet == A else "staff_b"
    before = world.snapshot()
    mine = _ok(send(world, "GET", "/v1/users/lin", who), 200)
    assert (mine["fleet"], mine["display_name"]) == (fleet, f"Lin of {fleet}")
    renamed = _ok(send(world, "PUT", "/v1/users/lin", staff, json={"display_name": who}), 200)
    assert (renamed["fleet"], renamed["display_name"]) == (fleet, who)
    _ok(send(world, "POST", "/v1/users/lin/episodes", who, json=event(f"{who}-1")), 201)
    episodes = _ok(send(world, "GET", "/v1/users/lin/episodes", who), 200)["items"]
    assert len(episodes) == 3
    assert {e["fleet"] for e in episodes} == {fleet}
    after = world.snapshot()
    assert after[fleet]["lin"]["display_name"] == who
    assert after[fleet]["lin"]["episodes"] == before[fleet]["lin"]["episodes"] + 1
    assert after[other] == before[other]


def test_the_admin_names_the_fleet(world: World) -> None:
    for fleet in (A, B):
        lin = _ok(send(world, "GET", f"/v1/users/lin?fleet={fleet}", "admin"), 200)
        assert (lin["fleet"], lin["display_name"]) == (fleet, f"Lin of {fleet}")
        trace = _ok(send(world, "GET", f"/v1/episodes/{world.fleets[fleet].episode}", "admin"), 200)
        assert (trace["fleet"], trace["user_id"]) == (fleet, "lin")
    # Without ?fleet: the admin key's own fleet, "default", which has no lin.
    absent = assert_error(send(world, "GET", "/v1/users/lin", "admin"), 404, "NotFound")
    nobody = assert_error(send(world, "GET", "/v1/users/nobody", "admin"), 404, "NotFound")
    assert _same(absent, "'lin'", "'nobody'") == _same(nobody, "'lin'", "'nobody'")
    before = world.snapshot()
    made = _ok(send(world, "PUT", "/v1/users/lin", "admin", json={}), 201)
    assert made["fleet"] == "default"
    assert world.snapshot() == before
    listed = _ok(send(world, "GET", "/v1/users", "admin"), 200)["items"]
    assert [(u["fleet"], u["user_id"]) for u in listed] == [
        ("default", "lin"),
        (A, "lin"),
        (A, "only-a"),
        (B, "lin"),
    ]
    listed = _ok(send(world, "GET", f"/v1/users?fleet={B}", "admin"), 200)["items"]
    assert [(u["fleet"], u["user_id"]) for u in listed] == [(B, "lin")]
    # The keys: revoking one stops it at once.
    victim = {"Authorization": f"Bearer {world.secrets['robot_a']}"}
    assert world.client.get("/v1/users/lin", headers=victim).status_code == 200
    keys = _ok(send(world, "GET", "/v1/admin/keys", "admin"), 200)["items"]
    [robot_a] = [k["key_id"] for k in keys if k["name"] == "robot_a"]
    assert send(world, "DELETE", f"/v1/admin/keys/{robot_a}", "admin").status_code == 204
    assert_error(world.client.get("/v1/users/lin", headers=victim), 401, "Unauthorized")
    # Robot and staff keys may name their own fleet: the same as not naming it.
    for who in ("robot_b", "staff_b"):
        named = _ok(send(world, "GET", f"/v1/users/lin?fleet={B}", who), 200)
        assert named == _ok(send(world, "GET", "/v1/users/lin", who), 200)


def test_lists_and_audit_log_are_per_fleet(world: World) -> None:
    for who in ("robot_a", "robot_b", "staff_a", "staff_b"):
        listed = _ok(send(world, "GET", "/v1/users", who), 200)["items"]
        expected = [(A, "lin"), (A, "only-a")] if HOME[who] == A else [(B, "lin")]
        assert [(u["fleet"], u["user_id"]) for u in listed] == expected, who
    assert send(world, "DELETE", "/v1/users/lin/model", "staff_a").status_code == 204
    for who in ("staff_a", "staff_b"):
        items = _ok(send(world, "GET", "/v1/admin/audit?limit=500", who), 200)["items"]
        assert {e["fleet"] for e in items} == {HOME[who]}, who
        assert ("model.export", "lin") in {(e["action"], e["target"]) for e in items}
        assert (("model.reset", "lin") in {(e["action"], e["target"]) for e in items}) == (
            who == "staff_a"
        )
    items = _ok(send(world, "GET", "/v1/admin/audit?limit=500", "admin"), 200)["items"]
    assert {A, B, "default"} <= {e["fleet"] for e in items}


# -- the console's sign-in -------------------------------------------------------------------------
def test_console_sign_in_by_key_kind(world: World) -> None:
    """docs/console.md and api.md: staff (their fleet) and admin keys sign in; a robot key is
    refused (403), an unknown or revoked one too (401); a refusal sets no session."""
    for who, status in (
        ("none", 401),
        ("revoked", 401),
        ("robot_a", 403),
        ("robot_b", 403),
        ("staff_a", 303),
        ("staff_b", 303),
        ("admin", 303),
    ):
        secret = world.secret(who) or ""
        r = send(world, "POST", "/admin/login", who, form={"key": secret})
        assert r.status_code == status, (who, r.text)
        set_cookie = r.headers.get("set-cookie", "")
        if status == 303:
            assert r.headers["location"] == "/admin/users"
            assert r.cookies.get(COOKIE) == secret
            assert "httponly" in set_cookie.lower()
            assert "samesite=strict" in set_cookie.lower()
            assert "path=/admin" in set_cookie.lower()
        else:
            assert r.cookies.get(COOKIE) is None, who
            assert secret == "" or secret not in r.text
    # A console POST needs the token of the signed-in key's own pages: none, or another key's,
    # is refused (403) and changes nothing.
    before = world.snapshot()
    for who, token in (
        ("staff_b", ""),
        ("staff_b", world.csrf("staff_a")),
        ("admin", world.csrf("staff_a")),
    ):
        q = ADMIN_Q if who == "admin" else ""
        for action in ("reset", "delete"):
            r = send(world, "POST", f"/admin/users/lin/{action}{q}", who, form={"csrf": token})
            assert r.status_code == 403, (who, action, r.status_code)
    assert world.snapshot() == before
    # Staff see their fleet's users, the admin every fleet's.
    for who, shown, hidden in (
        ("staff_a", ["only-a", f"Lin of {A}"], [f"Lin of {B}"]),
        ("staff_b", [f"Lin of {B}"], ["only-a", f"Lin of {A}"]),
        ("admin", ["only-a", f"Lin of {A}", f"Lin of {B}"], []),
    ):
        page = send(world, "GET", "/admin/users", who)
        assert page.status_code == 200, who
        for text in shown:
            assert text in page.text, (who, text)
        for text in hidden:
            assert text not in page.text, (who, text)
