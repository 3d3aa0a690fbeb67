"""API tests run against SQLite and PostgreSQL over real connections (every test twice).

The PostgreSQL half gets its own database per run (``attune_test_<pid>_<random>``) on the server
at ``ATTUNE_TEST_POSTGRES_URL`` (default: postgres@127.0.0.1:5432, trust auth). If that server
does not answer, the run fails; it does not skip. Each database is built by the migrations, and
every test starts from empty tables.
"""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import psycopg
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from app.db import migrate
from app.db.base import Base
from app.db.session import Database
from app.main import create_app
from app.services.auth import create_key
from app.settings import Settings

PG_SERVER = os.environ.get("ATTUNE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432")


def _pg_database(name: str) -> str:
    return f"{PG_SERVER.rstrip('/')}/{name}"


@pytest.fixture(scope="session", params=["sqlite", "postgresql"])
def database_url(request: pytest.FixtureRequest,
                 tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A migrated database of each engine, for the whole session."""
    if request.param == "sqlite":
        folder = tmp_path_factory.mktemp("sqlite")
        migrate.upgrade(f"sqlite:///{folder / 'template.db'}")
        shutil.copyfile(folder / "template.db", folder / "attune.db")
        yield f"sqlite:///{folder / 'attune.db'}"
        return
    name = f"attune_test_{os.getpid()}_{secrets.token_hex(4)}"
    try:
        admin = psycopg.connect(_pg_database("postgres"), autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.fail(f"PostgreSQL at {PG_SERVER} does not answer ({exc}); the API tests need it. "
                    "Start it (.ci/run does) or set ATTUNE_TEST_POSTGRES_URL.", pytrace=False)
    with admin:
        admin.execute(f'CREATE DATABASE "{name}"')
    url = Settings(database_url=_pg_database(name)).database_url
    try:
        migrate.upgrade(url)
        yield url
    finally:
        with psycopg.connect(_pg_database("postgres"), autocommit=True) as admin:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture
def settings(database_url: str) -> Settings:
    return Settings(database_url=database_url, seed=0, _env_file=None)  # type: ignore[call-arg]


@pytest.fixture
def engine_name(database_url: str) -> str:
    return "sqlite" if database_url.startswith("sqlite") else "postgresql"


@pytest.fixture
def empty_tables(database_url: str) -> None:
    """Every test starts from the migrated, empty schema: a copy of the SQLite template, or the
    PostgreSQL tables truncated (the audit log refuses row deletes; TRUNCATE is not one)."""
    if database_url.startswith("sqlite"):
        path = Path(database_url.removeprefix("sqlite:///"))
        for extra in ("-wal", "-shm"):
            path.with_name(path.name + extra).unlink(missing_ok=True)
        shutil.copyfile(path.with_name("template.db"), path)
        return
    engine = create_engine(database_url)
    with engine.begin() as conn:
        names = ", ".join(t.name for t in Base.metadata.sorted_tables)
        conn.execute(text(f"TRUNCATE {names} RESTART IDENTITY CASCADE"))
    engine.dispose()


@pytest.fixture
def app(settings: Settings, empty_tables: None) -> Iterator[FastAPI]:
    application = create_app(settings)
    yield application
    application.state.db.dispose()


class ManualClock:
    """A clock the test moves: ``advance(seconds)``."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


@pytest.fixture
def key_clock(app: FastAPI) -> ManualClock:
    """The clock of the app's key cache, moved by the test (a revocation made outside the
    worker takes effect once the cache's bound has passed)."""
    clock = ManualClock()
    app.state.ctx.keys.clock = clock
    return clock


@pytest.fixture
def db(app: FastAPI) -> Database:
    """The app's own database object (for looking at what was stored)."""
    database: Database = app.state.db
    return database


MakeKey = Callable[..., str]


@pytest.fixture
def make_key(db: Database) -> MakeKey:
    """``make_key(role="robot", fleet="default")`` -> the secret of a new key."""

    def make(role: str = "robot", fleet: str = "default", name: str | None = None) -> str:
        with db.transaction() as session:
            _, secret = create_key(session, role=role, fleet=fleet, name=name)
        return secret

    return make


def _client(app: FastAPI, key: str | None) -> TestClient:
    headers = {"Authorization": f"Bearer {key}"} if key else {}
    return TestClient(app, headers=headers, raise_server_exceptions=False)


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
def other_robot(app: FastAPI, make_key: MakeKey) -> Iterator[TestClient]:
    """A robot key of another fleet, ``other``."""
    with _client(app, make_key("robot", "other")) as c:
        yield c
