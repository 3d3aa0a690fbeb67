"""The database and app fixtures every test folder shares (a pytest plugin: ``tests/conftest.py``
loads it through ``pytest_plugins``).

A test that uses ``database_url`` (directly or through ``app``, ``db``, ``make_key``...) runs on
SQLite and on PostgreSQL, unless it is marked ``one_engine``: then it runs on SQLite only. Mark
``one_engine`` what is decided before any SQL runs (bad input refused by validation, HTTP
behaviours, the schema, auth header parsing) and nothing else; when in doubt, both engines.

Each pytest-xdist worker builds its own databases once per run, by the migrations: a SQLite file
in the worker's temporary folder and a PostgreSQL database named after the worker
(``attune_test_gw0_<pid>_<tag>``; ``master`` outside xdist) on the server at
``ATTUNE_TEST_POSTGRES_URL`` (default postgres@127.0.0.1:5432, trust auth). If that server does
not answer, the run fails; it does not skip. Every test starts from empty tables.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI
from sqlalchemy import create_engine, text

from app.db import migrate
from app.db.base import Base
from app.db.session import Database
from app.main import create_app
from app.services.auth import create_key
from app.settings import Settings

from .live import database_name, postgres_database

ENGINES = ("sqlite", "postgresql")


def engines() -> tuple[str, ...]:
    """The engines the database tests run on: both, or those ``ATTUNE_TEST_ENGINES`` names
    (comma-separated; ``./scripts/test --fast`` sets ``sqlite``)."""
    chosen = os.environ.get("ATTUNE_TEST_ENGINES", "").strip()
    if not chosen:
        return ENGINES
    names = tuple(dict.fromkeys(e.strip() for e in chosen.split(",") if e.strip()))
    unknown = [e for e in names if e not in ENGINES]
    if unknown or not names:
        raise pytest.UsageError(f"ATTUNE_TEST_ENGINES must name engines among "
                                f"{', '.join(ENGINES)}; got {chosen!r}.")
    return names


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """The engine rule: both engines (or those ``ATTUNE_TEST_ENGINES`` names), or SQLite alone
    for ``one_engine`` tests."""
    if "database_url" not in metafunc.fixturenames:
        return
    one = metafunc.definition.get_closest_marker("one_engine") is not None
    metafunc.parametrize("database_url", ENGINES[:1] if one else engines(), indirect=True,
                         scope="session")


@pytest.fixture(scope="session")
def database_url(request: pytest.FixtureRequest, worker_id: str,
                 tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A migrated database of the engine ``request.param``, for this worker's whole run."""
    if request.param == "sqlite":
        folder = tmp_path_factory.mktemp(f"sqlite-{worker_id}")
        migrate.upgrade(f"sqlite:///{folder / 'template.db'}")
        shutil.copyfile(folder / "template.db", folder / "attune.db")
        yield f"sqlite:///{folder / 'attune.db'}"
        return
    with postgres_database(database_name("test", worker_id)) as server_url:
        settings = Settings(database_url=server_url, _env_file=None)  # type: ignore[call-arg]
        migrate.upgrade(settings.database_url)
        yield settings.database_url


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
