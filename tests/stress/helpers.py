"""Helpers of the stress and fuzz tests: keys and users made in a live service's database."""

from __future__ import annotations

import json
from typing import Any

import httpx2

from app.db.session import Database
from app.services.auth import create_key
from app.settings import Settings
from tests.live import LiveService


def make_keys(database_url: str, n: int, role: str = "robot") -> list[str]:
    """``n`` keys, made in-process (much faster than ``attune keys create`` n times)."""
    db = Database(Settings(database_url=database_url, _env_file=None))  # type: ignore[call-arg]
    try:
        with db.transaction() as session:
            return [create_key(session, role=role, name=f"stress-{i}")[1] for i in range(n)]
    finally:
        db.dispose()


def create_users(api: httpx2.Client, users: list[str]) -> dict[str, int]:
    """Create the users; their model versions before the run."""
    versions = {}
    for user_id in users:
        r = api.put(f"/v1/users/{user_id}", json={})
        assert r.status_code in (200, 201), r.text
        versions[user_id] = api.get(f"/v1/users/{user_id}/model").json()["version"]
    return versions


def live_rebuild(service: LiveService) -> Any:
    def rebuild(user_id: str) -> dict[str, Any]:
        done = service.attune("models", "rebuild", user_id)
        lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
        if not lines:
            return {"identical": None, "exit": done.returncode, "stderr": done.stderr[-500:]}
        summary: dict[str, Any] = json.loads(lines[-1])
        return summary

    return rebuild
