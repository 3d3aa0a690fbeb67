"""The database and app fixtures every test folder shares (a pytest plugin: ``tests/conftest.py``
loads it through ``pytest_plugins``).

A test that uses ``database_url`` (directly or through ``app``, ``db``, ``make_key``...) runs on
SQLite and on PostgreSQL, unless it is marked ``one_engine``: then it runs on SQLite only. Mark
``one_engine`` what is decided before any SQL runs (bad input refused by validation, HTTP
behaviours, the schema, auth header parsing) and nothing else; when in doubt, both engines.

Each pytest-xdist worker builds its own databases once per run, by the migrations, the first
time a test needs them (``WorkerDatabases``): a SQLite file in the worker's temporary folder and
a PostgreSQL database named after the worker (``attune_test_gw0_<pid>_<tag>``; ``master``
outside xdist) on the server at ``ATTUNE_TEST_POSTGRES_URL`` (default postgres@127.0.0.1:5432,
trust auth). If that server does not answer, the run fails; it does not skip. Every test starts
from empty tables (``EmptyTables``), and ``app`` is the service in the state of a new one, on
routes that earlier tests warmed up (``WarmApps``).
"""

from __future__ import annotations

import os
import shutil
import sqlite3
from collections.abc import Callable, Iterator
from contextlib import ExitStack, closing
from pathlib import Path

import pytest
from fastapi import FastAPI
from sqlalchemy import Engine, create_engine, text

from app.db import migrate
from app.db.base import Base
from app.db.session import Database
from app.main import create_app
from app.services.auth import create_key
from app.settings import Pooler, Settings

from .live import database_name, postgres_database
from .pgbouncer import Bouncer, running_pgbouncer

ENGINES = ("sqlite", "postgresql", "pgbouncer")
"""SQLite; PostgreSQL; and PostgreSQL through PgBouncer in transaction pooling (the database
made and migrated on the server directly, the service's URL through PgBouncer, with
``ATTUNE_DATABASE_POOLER=transaction``)."""
TESTS = Path(__file__).parent.parent
POOLED_FOLDERS = (TESTS / "api", TESTS / "stress")
"""The folders whose tests also run through PgBouncer by default (the rest, on two engines)."""


def engines(path: Path | None = None) -> tuple[str, ...]:
    """The engines the database tests of the file at ``path`` run on: SQLite and PostgreSQL,
    and PgBouncer too for those of ``POOLED_FOLDERS``; or those ``ATTUNE_TEST_ENGINES`` names
    (comma-separated; ``./scripts/test --fast`` sets ``sqlite``)."""
    chosen = os.environ.get("ATTUNE_TEST_ENGINES", "").strip()
    if not chosen:
        pooled = path is not None and any(path.is_relative_to(f) for f in POOLED_FOLDERS)
        return ENGINES if pooled else ENGINES[:2]
    names = tuple(dict.fromkeys(e.strip() for e in chosen.split(",") if e.strip()))
    unknown = [e for e in names if e not in ENGINES]
    if unknown or not names:
        raise pytest.UsageError(
            f"ATTUNE_TEST_ENGINES must name engines among {', '.join(ENGINES)}; got {chosen!r}."
        )
    return names


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """The engine rule: both engines, and PgBouncer in ``POOLED_FOLDERS`` (or those
    ``ATTUNE_TEST_ENGINES`` names), or SQLite alone for ``one_engine`` tests."""
    if "database_url" not in metafunc.fixturenames:
        return
    one = metafunc.definition.get_closest_marker("one_engine") is not None
    metafunc.parametrize(
        "database_url",
        ENGINES[:1] if one else engines(metafunc.definition.path),
        indirect=True,
        scope="session",
    )


_TRIGGERED = (
    "SELECT DISTINCT c.relname FROM pg_trigger t JOIN pg_class c ON c.oid = t.tgrelid "
    "WHERE NOT t.tgisinternal AND c.relnamespace = 'public'::regnamespace"
)


class EmptyTables:
    """Brings one test database back to its migrated, empty schema, cheaply, before each test.

    SQLite: a copy of the template the migrations made (in WAL mode, as the app opens it),
    moved into place, so that a connection a test left open keeps the file it had.

    PostgreSQL: one round trip on a connection kept for the run: ``DELETE`` from every table,
    children first, and every sequence back to 1 (as ``TRUNCATE ... RESTART IDENTITY``, which
    costs tens of milliseconds per test: it makes new files for every table). The append-only
    audit log refuses deletes by a trigger: the tables' own triggers are off inside that one
    transaction only, so no other connection ever sees them off.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        self._engine: Engine | None = None
        self._sql = ""
        if url.startswith("sqlite"):
            self._path = Path(url.removeprefix("sqlite:///"))
            self._template = self._path.with_name("template.db")
            migrate.upgrade(f"sqlite:///{self._template}")
            with closing(sqlite3.connect(self._template)) as conn:
                conn.execute("PRAGMA journal_mode=WAL")
            return
        migrate.upgrade(url)
        self._engine = create_engine(url, pool_size=1, max_overflow=0)
        tables = [t.name for t in reversed(Base.metadata.sorted_tables)]
        with self._engine.connect() as conn:
            triggered = set(conn.scalars(text(_TRIGGERED)))
            sequences = list(
                conn.scalars(
                    text("SELECT sequencename FROM pg_sequences WHERE schemaname = 'public'")
                )
            )
        off = [f'ALTER TABLE "{t}" DISABLE TRIGGER USER;' for t in tables if t in triggered]
        on = [f'ALTER TABLE "{t}" ENABLE TRIGGER USER;' for t in tables if t in triggered]
        self._sql = " ".join(
            [
                *off,
                *(f'DELETE FROM "{t}";' for t in tables),
                *on,
                *(f"SELECT setval('\"{q}\"', 1, false);" for q in sequences),
            ]
        )

    def __call__(self) -> None:
        if self._engine is None:
            self.restore(self._template)
            return
        with self._engine.begin() as conn:
            conn.exec_driver_sql(self._sql)

    def restore(self, saved: Path) -> None:
        """SQLite: put a copy of ``saved`` (the template, or a file :meth:`save` wrote) in
        place of the database."""
        for extra in ("-wal", "-shm"):
            self._path.with_name(self._path.name + extra).unlink(missing_ok=True)
        copy = self._path.with_name(self._path.name + ".new")
        shutil.copyfile(saved, copy)
        os.replace(copy, self._path)

    def save(self, name: str) -> Path:
        """SQLite: a consistent copy of the database as it is now (open connections and their
        WAL included), for :meth:`restore`."""
        saved = self._path.with_name(f"saved-{name}.db")
        with (
            closing(sqlite3.connect(self._path)) as source,
            closing(sqlite3.connect(saved)) as target,
        ):
            source.backup(target)
        return saved

    def close(self) -> None:
        if self._engine is not None:
            self._engine.dispose()


class WorkerDatabases:
    """This worker's test databases, one per engine, each made (and migrated) the first time a
    test asks for it and kept until the end of the run, however the tests of the engines come
    in turn: a SQLite file in the worker's temporary folder, a PostgreSQL database named after
    the worker, and for ``pgbouncer`` another one, made and migrated directly on the server and
    reached through this worker's PgBouncer (started the first time it is needed)."""

    def __init__(self, worker_id: str, tmp_path_factory: pytest.TempPathFactory) -> None:
        self._worker, self._tmp = worker_id, tmp_path_factory
        self._stack = ExitStack()
        self._urls: dict[str, str] = {}
        self._empty: dict[str, EmptyTables] = {}
        self._bouncer: Bouncer | None = None
        self.pooled: dict[str, str] = {}  # a URL through PgBouncer -> the same database direct

    def bouncer(self) -> Bouncer:
        """This worker's PgBouncer, started on first use and stopped at the end of the run."""
        if self._bouncer is None:
            self._bouncer = self._stack.enter_context(running_pgbouncer())
        return self._bouncer

    def url(self, engine: str) -> str:
        if engine not in self._urls:
            if engine == "sqlite":
                url = f"sqlite:///{self._tmp.mktemp(f'sqlite-{self._worker}') / 'attune.db'}"
                direct = url
            else:
                name = database_name("test", self._worker)
                server_url = self._stack.enter_context(postgres_database(name))
                direct = url = _normal(server_url)
                if engine == "pgbouncer":
                    url = _normal(self.bouncer().url(name))
                    self.pooled[url] = direct
            emptier = self._empty[url] = EmptyTables(direct)
            self._stack.callback(emptier.close)
            emptier()
            self._urls[engine] = url
        return self._urls[engine]

    def pooler(self, url: str) -> Pooler:
        """The ``ATTUNE_DATABASE_POOLER`` of the service on ``url``."""
        return "transaction" if url in self.pooled else "none"

    def direct(self, url: str) -> str:
        """``url``, or the same database on the server directly when ``url`` goes through
        PgBouncer (for what is not the service: a test's own engine, keys made in bulk)."""
        return self.pooled.get(url, url)

    def empty(self, url: str) -> None:
        self._empty[url]()

    def tables(self, url: str) -> EmptyTables:
        """The emptier of ``url`` (SQLite's can also save and restore a whole database)."""
        return self._empty[url]

    def close(self) -> None:
        self._stack.close()


def _normal(url: str) -> str:
    """``url`` as the service's settings write it (``postgresql+psycopg://``)."""
    return Settings(database_url=url, _env_file=None).database_url  # type: ignore[call-arg]


@pytest.fixture(scope="session")
def worker_databases(
    worker_id: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[WorkerDatabases]:
    databases = WorkerDatabases(worker_id, tmp_path_factory)
    yield databases
    databases.close()


@pytest.fixture(scope="session")
def database_url(request: pytest.FixtureRequest, worker_databases: WorkerDatabases) -> str:
    """A migrated database of the engine ``request.param``, for this worker's whole run."""
    return worker_databases.url(request.param)


@pytest.fixture
def settings(database_url: str, worker_databases: WorkerDatabases) -> Settings:
    # PostgreSQL's robot writes inline, as ATTUNE_PG_INLINE_WRITES=auto chooses for a local
    # database once it measured the round trip (which it does at startup, which these apps'
    # TestClients never run): the suite takes the same path whatever the machine's load.
    return Settings(
        database_url=database_url,
        database_pooler=worker_databases.pooler(database_url),
        seed=0,
        pg_inline_writes="true",
        _env_file=None,
    )  # type: ignore[call-arg]


@pytest.fixture
def engine_name(database_url: str) -> str:
    """``sqlite`` or ``postgresql`` (also through PgBouncer: the same database behind it)."""
    return "sqlite" if database_url.startswith("sqlite") else "postgresql"


@pytest.fixture
def empty_tables(database_url: str, worker_databases: WorkerDatabases) -> None:
    """Every test starts from the migrated, empty schema (``EmptyTables``)."""
    worker_databases.empty(database_url)


class WarmApps:
    """This worker's apps, one per settings, each handed to one test at a time with the state of
    a new one.

    ``create_app`` is cheap, but an app's first requests are not: FastAPI works out each route's
    parameters, models and dependencies on first use, per app (about 0.1 s for a test's first
    requests). So each test gets the app that earlier tests with the same settings warmed up,
    after it adopted everything ``create_app`` makes per call from a new app: ``app.state``
    (database, caches, metrics, rate limiter), the middleware (rebuilt on the next request, with
    no counts carried over), the exception handlers and the lifespan. A test that changes the app
    itself (adds a route, overrides a dependency, patches a method) leaves it to no one: the next
    test builds a new one.
    """

    def __init__(self) -> None:
        self._apps: dict[str, tuple[FastAPI, tuple[object, ...]]] = {}

    def take(self, settings: Settings) -> FastAPI:
        fresh = create_app(settings)
        key = settings.model_dump_json()
        warm = self._apps.pop(key, None)
        if warm is None:
            self._apps[key] = (fresh, _shape(fresh))
            return fresh
        application, shape = warm
        application.state = fresh.state
        application.user_middleware = fresh.user_middleware
        application.middleware_stack = None
        application.exception_handlers = fresh.exception_handlers
        application.router.lifespan_context = fresh.router.lifespan_context
        application.openapi_schema = None
        self._apps[key] = (application, shape)
        return application

    def give_back(self, settings: Settings, application: FastAPI) -> None:
        """Keep ``application`` for the next test, unless this one changed it."""
        key = settings.model_dump_json()
        warm = self._apps.get(key)
        if warm is not None and warm[0] is application and _shape(application) != warm[1]:
            del self._apps[key]


def _shape(application: FastAPI) -> tuple[object, ...]:
    """What a test could change on an app beyond its state (identities, not values)."""
    router = application.router
    return (
        tuple(map(id, router.routes)),
        len(application.user_middleware),
        len(router.on_startup),
        len(router.on_shutdown),
        tuple(application.dependency_overrides.items()),
        application.__dict__.get("openapi"),
        application.title,
        application.root_path,
    )


@pytest.fixture(scope="session")
def warm_apps() -> WarmApps:
    return WarmApps()


@pytest.fixture
def app(settings: Settings, empty_tables: None, warm_apps: WarmApps) -> Iterator[FastAPI]:
    """The service on the test's empty database, in the state of a new app (``WarmApps``)."""
    application = warm_apps.take(settings)
    try:
        yield application
    finally:
        warm_apps.give_back(settings, application)
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
