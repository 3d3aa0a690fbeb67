"""Connections the database drops (a restart, a failover, an idle timeout) cost retried
requests, never a 500, and never an acknowledged write: robots write through the service while
every server connection of its database is ended again and again (``pg_terminate_backend``),
directly on PostgreSQL and through PgBouncer in transaction pooling. Every answer is 2xx or
503 (which the robots retry), and afterwards the stored history holds each acknowledged write
exactly once (``tests/stress/history.py``'s check). Then a database restart's worth (every
connection ended at once, the service idle) costs at most one retried request: the first
request that meets a dead connection has the pool drop them all. And each kind of lost
connection answers 503 with Retry-After, while a statement refused on a live one stays a 500."""

from __future__ import annotations

import threading
from pathlib import Path

import httpx
import psycopg
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from psycopg import errors
from sqlalchemy.engine import make_url
from sqlalchemy.exc import InterfaceError, OperationalError, ProgrammingError

from app.main import create_app
from app.settings import Settings
from tests.stress.helpers import create_users
from tests.stress.history import Workload, check_history
from tests.support.contract import assert_error
from tests.support.fixtures import WorkerDatabases, engines
from tests.support.live import make_keys, postgres_url, serving

ROBOTS = 8


class Retrying(httpx.BaseTransport):
    """A client that retries 503 as robots do (the check reads through it)."""

    def __init__(self) -> None:
        self.inner = httpx.HTTPTransport()
        self.retried = 0

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        for _ in range(20):
            response = self.inner.handle_request(request)
            if response.status_code != 503:
                return response
            response.read()
            response.close()
            self.retried += 1
        return response

    def close(self) -> None:
        self.inner.close()


POSTGRESQL = [e for e in engines(Path(__file__)) if e != "sqlite"]


@pytest.fixture(params=POSTGRESQL)
def pg_url(request: pytest.FixtureRequest, worker_databases: WorkerDatabases) -> str:
    """This worker's PostgreSQL database (directly, or through PgBouncer), emptied."""
    url = worker_databases.url(request.param)
    worker_databases.empty(url)
    return url


def _terminate(database: str) -> int:
    """End every server connection to ``database`` but this one; how many were ended."""
    with psycopg.connect(postgres_url("postgres"), autocommit=True) as admin:
        row = admin.execute(
            "SELECT count(*) FILTER (WHERE pg_terminate_backend(pid)) FROM pg_stat_activity "
            "WHERE datname = %s AND pid <> pg_backend_pid()",
            (database,),
        ).fetchone()
    assert row is not None
    return int(row[0])


def test_dropped_connections_cost_retries_not_writes(
    pg_url: str, worker_databases: WorkerDatabases
) -> None:
    direct = worker_databases.direct(pg_url)
    settings = Settings(
        database_url=pg_url,
        database_pooler=worker_databases.pooler(pg_url),
        seed=0,
        _env_file=None,
    )  # type: ignore[call-arg]
    app = create_app(settings)
    keys = make_keys(direct, ROBOTS)
    admin_key = make_keys(direct, 1, role="admin")[0]
    database = make_url(direct).database
    assert database is not None
    ended: list[int] = []
    stop = threading.Event()

    def killer() -> None:  # the database ends its sessions, over and over, mid-traffic
        while not stop.wait(0.15):
            ended.append(_terminate(database))

    try:
        with (
            serving(app) as base_url,
            httpx.Client(
                base_url=base_url,
                timeout=60,
                headers={"Authorization": f"Bearer {admin_key}"},
                transport=Retrying(),
            ) as api,
            httpx.Client(
                base_url=base_url, timeout=60, headers={"Authorization": f"Bearer {admin_key}"}
            ) as plain,
        ):
            workload = Workload(
                base_url, keys, episodes_per_client=4, budget_s=120.0, conflict_rate=0.0
            )
            initial = create_users(api, workload.all_users)
            thread = threading.Thread(target=killer, daemon=True)
            thread.start()
            try:
                history = workload.run()
            finally:
                stop.set()
                thread.join(timeout=10)
            findings = check_history(history, api, direct, workload.all_users, initial)
            # A restart: every connection ends while the service is idle, then reads come in
            # one after the other (each on the next idle connection of the pool).
            restarted = _terminate(database)
            statuses = [plain.get("/v1/users/hot/model").status_code for _ in range(20)]
    finally:
        app.state.db.dispose()
    assert sum(ended) > 0, "no connection was ever ended: the test proves nothing"
    # No 500, nothing unexpected (check_history reports each as "during the run: ..."), nothing
    # lost or doubled, and every robot got through its episodes.
    assert findings == [], "\n".join(findings)
    assert not history.unknown, history.unknown
    episodes = {a.key for a in history.acks if a.kind == "episode"}
    assert len(episodes) == ROBOTS * 4
    assert history.retried[503] > 0, "no request met a dropped connection"
    assert restarted > 0
    assert set(statuses) <= {200, 503}, statuses
    assert statuses.count(503) <= 1, statuses


@pytest.mark.one_engine
@pytest.mark.parametrize(
    ("error", "status", "name"),
    [
        # the driver's "the connection is closed": a connection lost before SQL was sent
        (
            InterfaceError("SELECT 1", None, psycopg.InterfaceError("the connection is closed")),
            503,
            "ServiceUnavailable",
        ),
        # any driver error on a connection the pool dropped as lost
        (
            ProgrammingError("SELECT 1", None, psycopg.Error("lost"), connection_invalidated=True),
            503,
            "ServiceUnavailable",
        ),
        (
            OperationalError("SELECT 1", None, errors.AdminShutdown("terminating")),
            503,
            "ServiceUnavailable",
        ),
        # a statement the database refused on a live connection is a server failure
        (ProgrammingError("SELECT 1", None, psycopg.Error("syntax")), 500, "InternalError"),
    ],
)
def test_a_lost_connection_answers_503_with_retry_after(
    app: FastAPI, client: TestClient, error: Exception, status: int, name: str
) -> None:
    @app.get("/lost")
    def lost() -> None:
        raise error

    r = client.get("/lost")
    assert_error(r, status, name)
    if status == 503:
        assert r.headers["retry-after"] == "1"
