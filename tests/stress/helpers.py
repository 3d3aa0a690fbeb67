"""Helpers of the stress tests: users made through the API, and ``models rebuild`` run in this
process."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import httpx

from app.db.session import Database
from app.services import audit
from app.services.context import ServiceContext
from app.services.models import rebuild_model
from app.settings import Settings


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


def rebuild(
    database_url: str, seed: int = 0, fleet: str = "default"
) -> Callable[[str], dict[str, Any]]:
    """``rebuild(user_id)``: what ``attune models rebuild USER_ID --fleet FLEET`` does, in this
    process (the same service function, in one transaction, as the command line's principal)
    against the service's database and seed; its summary, with the keys of the command's JSON
    line."""
    settings = Settings(database_url=database_url, seed=seed, _env_file=None)  # type: ignore[call-arg]
    ctx = ServiceContext.from_settings(settings)

    def run(user_id: str) -> dict[str, Any]:
        database = Database(settings)
        try:
            with database.transaction() as session:
                report = rebuild_model(session, ctx, audit.CLI, user_id, fleet=fleet)
        finally:
            database.dispose()
        return {
            "fleet": fleet,
            "user_id": user_id,
            "version": report.version,
            "writes_replayed": report.writes,
            "samples_replayed": report.samples,
            "decisions_redrawn": report.decisions,
            "mismatched_decisions": report.mismatched_decisions,
            "identical": report.identical,
        }

    return run
