"""The API tests' clients: ``TestClient`` on the app of the shared fixtures
(``tests/support/fixtures.py``: every test on SQLite and PostgreSQL, unless ``one_engine``),
without a key or with a robot, staff or admin key."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from tests.support.fixtures import MakeKey


def _client(app: FastAPI, key: str | None) -> TestClient:
    headers = {"Authorization": f"Bearer {key}"} if key else {}
    # From 127.0.0.1, as a robot on the service's machine (a trusted peer by default:
    # ATTUNE_FORWARDED_ALLOW_IPS), not TestClient's "testclient".
    return TestClient(
        app, headers=headers, raise_server_exceptions=False, client=("127.0.0.1", 50000)
    )


@pytest.fixture
def client(app: FastAPI) -> Iterator[TestClient]:
    """No API key."""
    with _client(app, None) as c:
        yield c


@pytest.fixture
def robot(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """A robot key of fleet ``default``."""
    with _client(app, make_key("robot", "default")) as c:
        yield c


@pytest.fixture
def admin(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """An admin key of fleet ``default``."""
    with _client(app, make_key("admin", "default")) as c:
        yield c


@pytest.fixture
def staff(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """A staff key of fleet ``default``."""
    with _client(app, make_key("staff", "default")) as c:
        yield c


@pytest.fixture
def other_staff(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """A staff key of fleet ``other``."""
    with _client(app, make_key("staff", "other")) as c:
        yield c


@pytest.fixture
def other_robot(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """A robot key of another fleet, ``other``."""
    with _client(app, make_key("robot", "other")) as c:
        yield c
