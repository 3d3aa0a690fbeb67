"""Helpers of the stress tests: users made through the API."""

from __future__ import annotations

import httpx


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
