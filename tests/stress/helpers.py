"""Helpers of the stress tests: the engines they run on, and users made through the API."""

from __future__ import annotations

from pathlib import Path

import httpx
from sqlalchemy.engine import make_url

from app.db import migrate
from tests.support.fixtures import WorkerDatabases, engines


def create_users(api: httpx.Client, users: list[str], fleet: str = "default") -> dict[str, int]:
    """Create the users of ``fleet`` (``api`` is an admin's client); their model versions
    before the run."""
    versions = {}
    in_fleet = {"fleet": fleet}
    for user_id in users:
        r = api.put(f"/v1/users/{user_id}", json={}, params=in_fleet)
        assert r.status_code in (200, 201), r.text
        versions[user_id] = api.get(f"/v1/users/{user_id}/model", params=in_fleet).json()["version"]
    return versions


STRESS = Path(__file__).parent
CASES = [
    case
    for case in (("sqlite", 1), ("postgresql", 2), ("pgbouncer", 2))
    if case[0] in engines(STRESS)
]
"""(engine, workers) of the stress runs: SQLite with 1 worker, PostgreSQL with 2, directly and
through PgBouncer (or those of ``ATTUNE_TEST_ENGINES``)."""


def service_env(engine: str, url: str, databases: WorkerDatabases) -> dict[str, str]:
    """The service's environment for database ``url`` (made by ``fresh_database(engine)``):
    nothing more, or for ``pgbouncer`` the same database through this worker's PgBouncer in
    transaction pooling, migrated on the server directly first. The tests' own reads and the
    command line's rebuilds use ``url``, directly."""
    if engine != "pgbouncer":
        return {}
    migrate.upgrade(url)
    name = make_url(url).database
    assert name is not None
    return {
        "ATTUNE_DATABASE_URL": databases.bouncer().url(name),
        "ATTUNE_DATABASE_POOLER": "transaction",
    }
