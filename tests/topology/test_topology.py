"""The production topology on this machine: Debian's nginx, on the site configuration the
repository ships (``docker/nginx/attune.conf``), serves Attune under ``/attune/`` over two
``attune serve --root-path /attune`` processes that share one PostgreSQL database through
PgBouncer in transaction pooling (migrated beforehand, as a migration job does). Robots drive
it through the Python client (its retries with the same ids, nothing else).

- SIGTERM to one instance mid-traffic: the robots see no failed request (it drains: its
  responses close their connections, it exits once nothing is in flight, within
  ATTUNE_DRAIN_TIMEOUT_S; nginx passes what it refuses to the other instance).
- SIGKILL to one instance mid-traffic: the client's retries carry every write through the
  other; no acknowledged write is lost or stored twice (checked in the database), and every
  model rebuilds identically from its history (``attune models rebuild --all``).
- The console works through nginx under the prefix: sign in, a user's page, a redirect.
"""

from __future__ import annotations

import html
import re
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import psycopg
import pytest
from attune_client import Client
from sqlalchemy.engine import make_url

from app.db import migrate
from tests.support.commands import rebuild_all
from tests.support.episodes import EVENT_TIME
from tests.support.live import LiveService, fresh_database, make_keys
from tests.support.nginx import Nginx
from tests.support.people import cooperative
from tests.support.pgbouncer import running_pgbouncer

pytestmark = [pytest.mark.live, pytest.mark.xdist_group("topology")]

PREFIX = "/attune"
DRAIN_TIMEOUT_S = 10
ROBOTS = 6
BEFORE = 40  # acknowledged writes before the signal
AFTER = 60  # and after it, all through the other instance


@dataclass(frozen=True)
class Database:
    """The one database of the topology: ``direct`` on PostgreSQL (the test's own checks, the
    migration), ``served`` through PgBouncer in transaction pooling (both instances)."""

    direct: str
    served: str


@pytest.fixture
def instances_database() -> Iterator[Database]:
    """A fresh PostgreSQL database, migrated directly (as a deployment's migration job does),
    and PgBouncer in front of it for the instances."""
    with fresh_database("postgresql") as url, running_pgbouncer() as bouncer:
        migrate.upgrade(url)
        yield Database(url, bouncer.url(make_url(url).database or ""))


@dataclass
class Topology:
    nginx: Nginx
    instances: list[LiveService]
    database_url: str

    @property
    def url(self) -> str:
        return self.nginx.url


@pytest.fixture
def topology(instances_database: Database, tmp_path: Path) -> Iterator[Topology]:
    instances = [
        LiveService(
            instances_database.served,
            log_path=tmp_path / f"attune-{n}.log",
            args=["--root-path", PREFIX, "--no-migrate"],
            env={
                "ATTUNE_DRAIN_TIMEOUT_S": str(DRAIN_TIMEOUT_S),
                "ATTUNE_LOG_LEVEL": "info",
                "ATTUNE_DATABASE_POOLER": "transaction",
            },
        )
        for n in (1, 2)
    ]
    (tmp_path / "nginx").mkdir()
    nginx = Nginx([f"127.0.0.1:{i.port}" for i in instances], tmp_path / "nginx")
    try:
        for instance in instances:
            instance.start()
        nginx.start()
        yield Topology(nginx, instances, instances_database.direct)
    finally:
        nginx.stop()
        for instance in instances:
            instance.stop()


@dataclass
class Robots:
    """Robots serving one person each through the client, until told to stop: every write the
    service acknowledged (the event ids of the episodes, the decisions answered and how), and
    every call that failed in the end (after the client's own retries)."""

    url: str
    keys: list[str]
    episodes: dict[str, set[str]] = field(default_factory=dict)  # user -> event ids
    answered: dict[str, str] = field(default_factory=dict)  # decision id -> response
    failures: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    stop: threading.Event = field(default_factory=threading.Event)
    threads: list[threading.Thread] = field(default_factory=list)

    @property
    def acks(self) -> int:
        with self.lock:
            return sum(map(len, self.episodes.values())) + len(self.answered)

    def wait_for(self, acks: int, timeout: float = 120) -> None:
        deadline = time.monotonic() + timeout
        while self.acks < acks:
            assert not self.failures, self.failures
            assert time.monotonic() < deadline, f"only {self.acks} writes in {timeout} s"
            time.sleep(0.05)

    def start(self) -> None:
        for n, key in enumerate(self.keys):
            thread = threading.Thread(target=self._serve, args=(f"person-{n}", key), daemon=True)
            thread.start()
            self.threads.append(thread)

    def finish(self) -> None:
        self.stop.set()
        for thread in self.threads:
            thread.join(timeout=120)
            assert not thread.is_alive(), "a robot did not stop"

    def _serve(self, user: str, key: str) -> None:
        with Client(self.url, key) as client:
            n = 0
            while not self.stop.is_set():
                n += 1
                event_id = f"{user}-e{n}"
                try:
                    started = client.start_episode(
                        user, event_id=event_id, occurred_at=EVENT_TIME, situation="stretching"
                    )
                    with self.lock:
                        self.episodes.setdefault(user, set()).add(event_id)
                    decision, step = started.decision, 0
                    while decision is not None:
                        answer = cooperative(decision.action.model_dump(), n * 7 + step)
                        result = client.report_outcome(
                            started.episode_id, decision_id=decision.decision_id, **answer
                        )
                        with self.lock:
                            self.answered[decision.decision_id] = answer["response"]
                        decision = result.decision  # type: ignore[union-attr]
                        step += 1
                except Exception as exc:  # every failure the robot would see
                    with self.lock:
                        self.failures.append(f"{user} {event_id}: {type(exc).__name__}: {exc}")
                    return


def _robots(topology: Topology) -> Robots:
    return Robots(topology.url, make_keys(topology.database_url, ROBOTS))


def _stored(database_url: str) -> tuple[dict[str, list[str]], dict[str, str]]:
    """What the database holds: each user's episodes' event ids (with repeats, if any), and
    every answered decision's response."""
    with psycopg.connect(database_url.replace("postgresql+psycopg://", "postgresql://")) as conn:
        episodes: dict[str, list[str]] = {}
        for user, event_id in conn.execute(
            "SELECT u.user_id, e.event_id FROM episodes e JOIN users u ON u.id = e.user_pk"
        ):
            episodes.setdefault(user, []).append(event_id)
        answered: dict[str, str] = dict(
            conn.execute("SELECT id, response FROM decisions WHERE response IS NOT NULL")
        )
    return episodes, answered


def _assert_stored_exactly_once(topology: Topology, robots: Robots) -> None:
    episodes, answered = _stored(topology.database_url)
    for user, event_ids in robots.episodes.items():
        assert sorted(episodes[user]) == sorted(event_ids), user  # none lost, none twice
    assert set(episodes) == set(robots.episodes)
    assert answered == robots.answered


def _upstreams(nginx: Nginx) -> list[str]:
    """The instance each request went to, in order (the last one nginx tried)."""
    found = [re.search(r"upstream=(\S+(?:, \S+)*) ", line) for line in nginx.access()]
    return [m.group(1).split(", ")[-1] for m in found if m]


def test_sigterm_to_one_instance_mid_traffic_fails_no_request(topology: Topology) -> None:
    robots = _robots(topology)
    robots.start()
    try:
        robots.wait_for(BEFORE)
        draining, other = topology.instances
        began = time.monotonic()
        draining.stop(timeout=DRAIN_TIMEOUT_S + 10)
        took = time.monotonic() - began
        assert draining.process is not None
        assert draining.process.returncode == 0, draining.log()
        assert took < DRAIN_TIMEOUT_S + 5, f"drained in {took:.1f} s"
        after = robots.acks
        robots.wait_for(after + AFTER)
    finally:
        robots.finish()
    assert robots.failures == [], "\n".join(robots.failures) + "\n" + topology.nginx.log()
    _assert_stored_exactly_once(topology, robots)
    went = _upstreams(topology.nginx)
    assert {f"127.0.0.1:{i.port}" for i in topology.instances} <= set(went)  # both served
    # Once it was gone, the other instance took everything.
    assert went[-AFTER // 2 :] == [f"127.0.0.1:{other.port}"] * (AFTER // 2)


def test_sigkill_to_one_instance_mid_traffic_loses_and_doubles_no_write(
    topology: Topology,
) -> None:
    robots = _robots(topology)
    robots.start()
    try:
        robots.wait_for(BEFORE)
        topology.instances[0].kill()
        robots.wait_for(robots.acks + AFTER)
    finally:
        robots.finish()
    assert robots.failures == [], "\n".join(robots.failures) + "\n" + topology.nginx.log()
    _assert_stored_exactly_once(topology, robots)
    exit_code, lines = rebuild_all(topology.database_url)
    assert exit_code == 0, lines
    assert {line["user_id"] for line in lines} == set(robots.episodes)
    assert all(line["identical"] for line in lines), lines


def test_the_console_works_through_nginx_under_the_prefix(topology: Topology) -> None:
    [robot_key] = make_keys(topology.database_url, 1)
    [admin_key] = make_keys(topology.database_url, 1, role="admin")
    with Client(topology.url, robot_key) as client:
        client.put_user("lin")
    origin = topology.nginx.origin
    with httpx.Client(base_url=origin, timeout=30, follow_redirects=False) as browser:
        r = browser.get(f"{PREFIX}/admin/users/lin?fleet=default")
        assert r.status_code == 303
        assert r.headers["location"] == (
            f"{PREFIX}/admin/login?next={PREFIX}/admin/users/lin%3Ffleet%3Ddefault"
        )
        login = browser.get(r.headers["location"])
        assert login.status_code == 200
        assert f'action="{PREFIX}/admin/login"' in login.text
        next_path = html.unescape(re.findall(r'name="next" value="([^"]*)"', login.text)[0])
        # A caller's own X-Forwarded-Proto does not reach the service: nginx sets it.
        signed = browser.post(
            f"{PREFIX}/admin/login",
            data={"key": admin_key, "next": next_path},
            headers={"origin": origin, "x-forwarded-proto": "https"},
        )
        assert signed.status_code == 303, signed.text
        assert signed.headers["location"] == f"{PREFIX}/admin/users/lin?fleet=default"
        cookie = signed.headers["set-cookie"]
        assert f"Path={PREFIX}/admin" in cookie
        assert "Secure" not in cookie  # the browser used http
        page = browser.get(signed.headers["location"])
        assert page.status_code == 200, page.text
        assert f'href="{PREFIX}/admin/users"' in page.text
        assert f'href="{PREFIX}/admin/static/console.css"' in page.text
        assert browser.get(f"{PREFIX}/admin/static/console.css").status_code == 200
        # From another site, refused; the request id the caller sent comes back.
        refused = browser.post(
            f"{PREFIX}/admin/logout",
            data={"csrf": "x"},
            headers={"origin": "http://evil.example", "x-request-id": "from-the-robot-1"},
        )
        assert refused.status_code == 403
        assert refused.headers["x-request-id"] == "from-the-robot-1"
        docs = browser.get(f"{PREFIX}/docs")
        assert f"{PREFIX}/openapi.json" in docs.text
        assert browser.get(f"{PREFIX}/openapi.json").json()["servers"] == [{"url": PREFIX}]
