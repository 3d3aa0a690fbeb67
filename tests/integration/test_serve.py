"""``attune serve`` as an operator runs it: a start that cannot succeed says why in one line,
exits non-zero and leaves no file behind; a worker that dies is reported with its cause; the
workers leave with their supervisor, even after ``kill -9``; SIGTERM drains; a database URL
never shows its password; the logs are one JSON object per line when asked."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families
from sqlalchemy import create_engine, text

from app.db import migrate
from tests.support.live import ATTUNE, LiveService, free_port, fresh_database, make_keys

pytestmark = pytest.mark.live

REPO = Path(__file__).resolve().parents[2]
UNKNOWN = "ffffffffffff"  # a schema revision no release of this code has


def _env(**more: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ATTUNE_")}
    return {**env, **more}


def _serve(
    cwd: Path, env: dict[str, str], port: int, command: tuple[str, ...] = (ATTUNE,)
) -> subprocess.CompletedProcess[str]:
    """``attune serve`` that is expected to give up; a start that succeeds is a failure."""
    try:
        return subprocess.run(
            [*command, "serve", "--host", "127.0.0.1", "--port", str(port)],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=90,
            check=False,
        )
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f"attune serve did not give up: {exc.stderr!r}") from None


def _one_sentence(done: subprocess.CompletedProcess[str], *words: str) -> str:
    assert done.returncode == 1, (done.returncode, done.stderr)
    assert done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    line = lines[0]
    assert "Traceback" not in line
    assert line.endswith("."), line
    for word in words:
        assert word in line, (word, line)
    return line


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    """An empty working folder: the default database, ./attune.db, would land here."""
    path = tmp_path / "run"
    path.mkdir()
    return path


@pytest.fixture
def taken_port() -> Iterator[int]:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        yield sock.getsockname()[1]


def _tables(url: str) -> set[str]:
    from sqlalchemy import inspect

    engine = create_engine(url)
    try:
        return set(inspect(engine).get_table_names())
    finally:
        engine.dispose()


def _stamp(url: str, revision: str) -> None:
    """A database whose schema revision is ``revision``."""
    engine = create_engine(url)
    try:
        with engine.begin() as conn:
            conn.execute(text("CREATE TABLE alembic_version (version_num VARCHAR(32) PRIMARY KEY)"))
            conn.execute(text("INSERT INTO alembic_version VALUES (:r)"), {"r": revision})
    finally:
        engine.dispose()


class TestFailedStart:
    def test_port_taken_on_the_default_database(self, folder: Path, taken_port: int) -> None:
        done = _serve(folder, _env(), taken_port)
        _one_sentence(done, f"Port {taken_port}", "already in use", "--port")
        assert list(folder.iterdir()) == []  # no ./attune.db

    def test_port_taken_touches_no_postgresql_database(
        self, folder: Path, tmp_path: Path, taken_port: int
    ) -> None:
        with fresh_database("postgresql", tmp_path) as url:
            done = _serve(folder, _env(ATTUNE_DATABASE_URL=url), taken_port)
            _one_sentence(done, "already in use")
            assert _tables(url) == set()  # the port is checked before the database

    def test_sqlite_folder_that_does_not_exist(self, folder: Path, tmp_path: Path) -> None:
        missing = tmp_path / "no" / "such" / "folder"
        url = f"sqlite:///{missing / 'attune.db'}"
        done = _serve(folder, _env(ATTUNE_DATABASE_URL=url), free_port())
        _one_sentence(done, str(missing / "attune.db"), "does not exist")
        assert not (tmp_path / "no").exists()
        assert list(folder.iterdir()) == []

    def test_postgresql_unreachable(self, folder: Path) -> None:
        closed = free_port()  # nothing listens there
        url = f"postgresql://postgres@127.0.0.1:{closed}/attune"
        done = _serve(folder, _env(ATTUNE_DATABASE_URL=url), free_port())
        line = _one_sentence(done, "Cannot reach the database", f"127.0.0.1:{closed}", "refused")
        assert "postgresql+psycopg://postgres@127.0.0.1" in line
        assert list(folder.iterdir()) == []

    def test_postgresql_database_that_does_not_exist(self, folder: Path) -> None:
        server = os.environ.get("ATTUNE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432")
        url = f"{server.rstrip('/')}/attune_never_created_{os.getpid()}"
        done = _serve(folder, _env(ATTUNE_DATABASE_URL=url), free_port())
        _one_sentence(done, "Cannot reach the database", "does not exist")

    @pytest.mark.parametrize("engine", ["sqlite", "postgresql"])
    def test_schema_of_a_newer_release(self, folder: Path, tmp_path: Path, engine: str) -> None:
        with fresh_database(engine, tmp_path) as url:
            _stamp(url, UNKNOWN)
            done = _serve(folder, _env(ATTUNE_DATABASE_URL=url), free_port())
            _one_sentence(
                done, f"schema revision {UNKNOWN}", "does not know", str(migrate.head_revision())
            )
            assert _tables(url) == {"alembic_version"}  # nothing migrated, nothing dropped
            engine_ = create_engine(url)
            try:
                assert migrate.current_revision(engine_) == UNKNOWN
            finally:
                engine_.dispose()
        assert list(folder.iterdir()) == []

    def test_migrations_missing(self, folder: Path, tmp_path: Path) -> None:
        """An installation whose migration scripts are gone: no database is made."""
        copy = tmp_path / "install"

        def skip_migrations(where: str, names: list[str]) -> list[str]:
            return [
                n
                for n in names
                if n == "__pycache__"
                or (Path(where, n).is_dir() and (Path(where, n) / "env.py").exists())
            ]

        shutil.copytree(REPO / "app", copy / "app", ignore=skip_migrations)
        command = (sys.executable, "-c", "from app.cli import main; main()")
        done = _serve(folder, _env(PYTHONPATH=str(copy)), free_port(), command)
        _one_sentence(done, "migrations", "reinstall")
        assert list(folder.iterdir()) == []

    def test_db_upgrade_says_the_same_in_one_line(self, folder: Path, tmp_path: Path) -> None:
        url = f"sqlite:///{tmp_path / 'missing' / 'attune.db'}"
        done = subprocess.run(
            [ATTUNE, "db", "upgrade"],
            cwd=folder,
            capture_output=True,
            text=True,
            env=_env(ATTUNE_DATABASE_URL=url),
            timeout=60,
            check=False,
        )
        _one_sentence(done, "does not exist")
        done = subprocess.run(
            [ATTUNE, "keys", "list"],
            cwd=folder,
            capture_output=True,
            text=True,
            env=_env(ATTUNE_DATABASE_URL=url),
            timeout=60,
            check=False,
        )
        _one_sentence(done, "does not exist")
        assert not (tmp_path / "missing").exists()

    def test_db_current_changes_nothing_and_fails_in_one_line(
        self, folder: Path, tmp_path: Path
    ) -> None:
        fresh = folder / "fresh.db"
        done = subprocess.run(
            [ATTUNE, "db", "current"],
            cwd=folder,
            capture_output=True,
            text=True,
            env=_env(ATTUNE_DATABASE_URL=f"sqlite:///{fresh}"),
            timeout=60,
            check=False,
        )
        assert done.returncode == 0, done.stderr
        assert done.stdout.splitlines()[0] == f"database: empty (no file at {fresh})"
        assert list(folder.iterdir()) == []  # reading the revision made no database
        closed = f"postgresql://attune@127.0.0.1:{free_port()}/attune"
        done = subprocess.run(
            [ATTUNE, "db", "current"],
            cwd=folder,
            capture_output=True,
            text=True,
            env=_env(ATTUNE_DATABASE_URL=closed),
            timeout=60,
            check=False,
        )
        _one_sentence(done, "Cannot reach the database")

    def test_a_bad_setting_is_one_line_naming_the_variable(self, folder: Path) -> None:
        done = subprocess.run(
            [ATTUNE, "serve"],
            cwd=folder,
            capture_output=True,
            text=True,
            env=_env(ATTUNE_LOG_FORMAT="xml"),
            timeout=60,
            check=False,
        )
        assert done.returncode == 2
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1, done.stderr
        assert lines[0].startswith("Bad setting ATTUNE_LOG_FORMAT:"), lines[0]
        assert "'xml'" in lines[0]
        assert list(folder.iterdir()) == []

    @pytest.mark.parametrize(
        ("args", "env", "variable", "given"),
        [
            (["--root-path", "attune"], {}, "ATTUNE_ROOT_PATH", "attune"),
            ([], {"ATTUNE_ROOT_PATH": "/a b"}, "ATTUNE_ROOT_PATH", "/a b"),
            (
                ["--forwarded-allow-ips", "10.0.0.0/8,nginx"],
                {},
                "ATTUNE_FORWARDED_ALLOW_IPS",
                "10.0.0.0/8,nginx",
            ),
            (
                [],
                {"ATTUNE_FORWARDED_ALLOW_IPS": "300.1.1.1"},
                "ATTUNE_FORWARDED_ALLOW_IPS",
                "300.1.1.1",
            ),
        ],
    )
    def test_a_bad_proxy_setting_is_one_line_naming_the_variable(
        self, folder: Path, args: list[str], env: dict[str, str], variable: str, given: str
    ) -> None:
        done = subprocess.run(
            [ATTUNE, "serve", *args],
            cwd=folder,
            capture_output=True,
            text=True,
            env=_env(**env),
            timeout=60,
            check=False,
        )
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1, done.stderr
        assert lines[0].startswith(f"Bad setting {variable}:"), lines[0]
        assert f"(got {given!r})" in lines[0]
        assert list(folder.iterdir()) == []


def _workers(pid: int) -> list[int]:
    """The worker processes of the supervisor ``pid`` (multiprocessing's spawned children)."""
    found = []
    for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        cmdline = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ")
        if b"spawn_main" in cmdline:
            found.append(int(child))
    return found


def _wait_for(predicate: object, what: str, log: LiveService, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():  # type: ignore[operator]
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} within {timeout} s:\n{log.log()}")
        time.sleep(0.2)


def test_a_dead_worker_is_reported_with_its_cause(tmp_path: Path) -> None:
    with (
        fresh_database("sqlite", tmp_path) as url,
        LiveService(url, workers=2, log_path=tmp_path / "serve.log") as service,
    ):
        assert service.process is not None
        _wait_for(lambda: len(_workers(service.process.pid)) == 2, "two workers", service)
        victim = _workers(service.process.pid)[0]
        os.kill(victim, signal.SIGKILL)
        said = f"Worker process {victim} was killed by signal SIGKILL (9); starting a new one."
        _wait_for(lambda: said in service.log(), "the supervisor said why", service)
        _wait_for(
            lambda: (
                len(_workers(service.process.pid)) == 2
                and victim not in _workers(service.process.pid)
            ),
            "a new worker",
            service,
        )
        assert httpx.get(f"{service.url}/readyz", timeout=10).status_code == 200
        assert "Traceback" not in service.log()


def test_a_hung_worker_and_a_dead_one_are_told_apart(tmp_path: Path) -> None:
    """One worker stops answering (SIGSTOP) while the other is killed: the supervisor's health
    check waits on the first, and the second's death, seen meanwhile, is still a death."""
    with (
        fresh_database("sqlite", tmp_path) as url,
        LiveService(url, workers=2, log_path=tmp_path / "serve.log") as service,
    ):
        assert service.process is not None
        _wait_for(lambda: len(_workers(service.process.pid)) == 2, "two workers", service)
        hung, killed = _workers(service.process.pid)
        os.kill(hung, signal.SIGSTOP)
        time.sleep(1)
        os.kill(killed, signal.SIGKILL)
        died = f"Worker process {killed} was killed by signal SIGKILL (9); starting a new one."
        stuck = f"Worker process {hung} did not answer its health check"
        _wait_for(
            lambda: died in service.log() and stuck in service.log(),
            "both causes reported",
            service,
        )
        assert f"Worker process {killed} did not answer" not in service.log()
        _wait_for(
            lambda: len(set(_workers(service.process.pid)) - {hung, killed}) == 2,
            "two new workers",
            service,
        )


def test_json_logs_one_object_per_line(tmp_path: Path) -> None:
    env = {"ATTUNE_LOG_FORMAT": "json", "ATTUNE_LOG_LEVEL": "info"}
    with fresh_database("sqlite", tmp_path) as url:
        service = LiveService(url, log_path=tmp_path / "serve.log", env=env)
        with service:
            secret = service.create_key("robot")
            headers = {"Authorization": f"Bearer {secret}", "X-Request-ID": "json-1"}
            r = httpx.put(f"{service.url}/v1/users/lin", json={}, headers=headers, timeout=10)
            assert r.status_code == 201
            httpx.head(f"{service.url}/healthz", headers={"X-Request-ID": "json-2"}, timeout=10)
        raw = (tmp_path / "serve.log").read_text()
    lines = [json.loads(line) for line in raw.splitlines() if line.strip()]
    for line in lines:
        assert {"time", "level", "logger", "message"} <= set(line), line
    access = [
        line for line in lines if line["logger"] == "attune.access" and line["route"] != "/readyz"
    ]  # LiveService waits on /readyz
    assert [a["request_id"] for a in access] == ["json-1", "json-2"], access
    put, head = access
    assert (put["method"], put["route"], put["status"]) == ("PUT", "/v1/users/{user_id}", 201)
    assert put["key_id"].startswith("key_")
    assert (head["method"], head["route"], head["status"], head["key_id"]) == (
        "HEAD",
        "/healthz",
        200,
        None,
    )
    assert not [line for line in lines if line["logger"] == "uvicorn.access"]
    assert any(
        line["logger"] == "attune.serve" and line["message"].startswith("Attune on ")
        for line in lines
    )
    assert secret not in raw


def _gone(pid: int) -> bool:
    """The process is no more (or a zombie that nobody reaped yet: it holds nothing)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


def _serving_workers(service: LiveService) -> float:
    """The workers that started serving, as the metrics (summed over them) say."""
    text = httpx.get(f"{service.url}/metrics", timeout=10).text
    for family in text_string_to_metric_families(text):
        if family.name == "attune_workers":
            return sum(s.value for s in family.samples)
    return 0.0


def test_kill_9_of_the_supervisor_takes_its_workers_along(tmp_path: Path) -> None:
    """``kill -9`` cannot be caught: each worker notices that its supervisor is gone, drains and
    exits, so the port is free and the next ``attune serve`` on it starts."""
    with fresh_database("sqlite", tmp_path) as url:
        service = LiveService(url, workers=2, log_path=tmp_path / "serve.log")
        service.start()
        assert service.process is not None
        group = service.process.pid  # its own session: the workers are in its group
        try:
            _wait_for(lambda: _serving_workers(service) == 2, "two workers serving", service)
            workers = _workers(service.process.pid)
            os.kill(service.process.pid, signal.SIGKILL)
            service.process.wait(timeout=30)
            _wait_for(lambda: all(_gone(w) for w in workers), "the workers gone", service)
            for pid in workers:
                said = f"The supervisor (process {group}) is gone; worker process {pid} stops."
                assert said in service.log()
            service.start()  # the same port: it starts, since nothing holds it any more
            assert httpx.get(f"{service.url}/readyz", timeout=10).status_code == 200
            assert "already in use" not in service.log()
        finally:
            service.stop()
            with contextlib.suppress(ProcessLookupError):
                os.killpg(group, signal.SIGKILL)  # anything of the first run left behind


def _in_use(service: LiveService) -> float:
    """The service's database connections in use, as its metrics say."""
    text = httpx.get(f"{service.url}/metrics", timeout=10).text
    for family in text_string_to_metric_families(text):
        if family.name == "attune_db_pool_connections_in_use":
            return sum(s.value for s in family.samples)
    return 0.0


@contextlib.contextmanager
def _user_locked(url: str, user_id: str) -> Iterator[None]:
    """Hold what a write of ``user_id`` has to wait for: SQLite's write lock, or PostgreSQL's
    lock on the user's row."""
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            if conn.dialect.name == "sqlite":
                conn.exec_driver_sql("BEGIN IMMEDIATE")
            else:
                conn.execute(
                    text(
                        "SELECT id FROM users WHERE fleet = 'default' AND user_id = :u FOR UPDATE"
                    ),
                    {"u": user_id},
                )
            try:
                yield
            finally:
                conn.rollback()
    finally:
        engine.dispose()


@pytest.mark.parametrize(("engine", "workers"), [("sqlite", 1), ("postgresql", 2)])
def test_sigterm_drains_the_requests_in_flight(tmp_path: Path, engine: str, workers: int) -> None:
    """SIGTERM while a robot's write waits for its user's lock: /readyz answers 503 at once, the
    process still serves, the write is answered and stored once, then the service exits 0."""
    env = {
        "ATTUNE_DRAIN_TIMEOUT_S": "120",
        "ATTUNE_SQLITE_BUSY_TIMEOUT_S": "120",
        "ATTUNE_LOG_LEVEL": "info",
    }
    with fresh_database(engine, tmp_path) as url:
        service = LiveService(url, workers=workers, log_path=tmp_path / "serve.log", env=env)
        service.start()
        try:
            assert service.process is not None
            key = service.create_key("robot")
            api = httpx.Client(
                base_url=service.url, headers={"Authorization": f"Bearer {key}"}, timeout=120
            )
            body = {
                "event_id": "held",
                "occurred_at": "2026-11-22T15:10:00+08:00",
                "situation": "working",
                "initiator": "robot",
            }
            assert api.put("/v1/users/lin", json={}).status_code == 201
            answered: list[httpx.Response] = []
            with _user_locked(url, "lin"):
                writer = threading.Thread(
                    target=lambda: answered.append(api.post("/v1/users/lin/episodes", json=body))
                )
                writer.start()
                _wait_for(lambda: _in_use(service) >= 1, "the write in flight", service)
                os.kill(service.process.pid, signal.SIGTERM)  # as an orchestrator does
                _wait_for(
                    lambda: httpx.get(f"{service.url}/readyz", timeout=10).status_code == 503,
                    "/readyz at 503",
                    service,
                )
                ready = httpx.get(f"{service.url}/readyz", timeout=10)
                assert "shutting down" in ready.json()["detail"], ready.text
                assert httpx.get(f"{service.url}/livez", timeout=10).status_code == 200
                assert api.get("/v1/mission").status_code == 200  # it still serves
                assert not answered  # the write still waits
            writer.join(timeout=120)
            assert [r.status_code for r in answered] == [201], answered
            assert service.process.wait(timeout=120) == 0
            log = service.log()
            assert "is shutting down: it finishes the requests in flight" in log
            assert "Traceback" not in log
            api.close()
            engine_ = create_engine(url)
            try:
                with engine_.connect() as conn:
                    stored = conn.execute(
                        text("SELECT count(*) FROM episodes WHERE event_id = 'held'")
                    ).scalar_one()
            finally:
                engine_.dispose()
            assert stored == 1
        finally:
            service.stop()


class TestBadDatabaseUrl:
    """A database URL is a secret: no message shows its password, and a malformed one is a bad
    setting (one line, exit 2), for the service and for the command that migrates."""

    @pytest.mark.parametrize("command", [("serve",), ("db", "upgrade")])
    @pytest.mark.parametrize(
        ("url", "words"),
        [
            ("postgresql://attune:hunter2secret@db.internal:notaport/attune", "notaport"),
            ("postgresql://attune:hunter2secret@db.internal:70000/attune", "70000"),
            ("mysql://attune:hunter2secret@db.internal/attune", "sqlite:///PATH"),
            ("postgresql://attune:hunter2@secret@db.internal/attune", "%40"),
        ],
    )
    def test_one_line_exit_2_and_no_password(
        self, folder: Path, command: tuple[str, ...], url: str, words: str
    ) -> None:
        done = subprocess.run(
            [ATTUNE, *command],
            cwd=folder,
            capture_output=True,
            text=True,
            env=_env(ATTUNE_DATABASE_URL=url),
            timeout=60,
            check=False,
        )
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1, done.stderr
        assert lines[0].startswith("Bad setting ATTUNE_DATABASE_URL:"), lines[0]
        assert words in lines[0], lines[0]
        assert "hunter2" not in done.stderr + done.stdout
        assert "secret" not in done.stderr + done.stdout
        assert "attune:***@" in lines[0]
        assert list(folder.iterdir()) == []

    def test_a_refused_connection_masks_the_password(self, folder: Path) -> None:
        url = f"postgresql://postgres:hunter2secret@127.0.0.1:{free_port()}/attune"
        done = _serve(folder, _env(ATTUNE_DATABASE_URL=url), free_port())
        line = _one_sentence(done, "Cannot reach the database", "postgres:***@127.0.0.1")
        assert "hunter2" not in line


def test_the_metrics_port_taken_is_one_line(folder: Path, taken_port: int) -> None:
    done = _serve(folder, _env(ATTUNE_METRICS_PORT=str(taken_port)), free_port())
    _one_sentence(done, f"Port {taken_port}", "already in use", "ATTUNE_METRICS_PORT")
    assert list(folder.iterdir()) == []


ROBOTS = 4
MOST_EPISODES = 2000  # per robot: each goes on until it played two episodes after the restart
# While it drains, the service goes on serving the robots (they come to it directly, with no
# balancer to turn them away) until no request is in flight or the drain's time is up: within
# it, fast robots could play a small bound whole, and meet no restart.
SIGTERM_DRAIN_S = 5


@pytest.mark.parametrize(("engine", "workers"), [("sqlite", 1), ("postgresql", 2)])
def test_sigterm_under_robot_traffic_fails_no_request(
    tmp_path: Path, engine: str, workers: int
) -> None:
    """Robots on the Python client (which retries) play episodes while the service is stopped
    with SIGTERM and started again: none of their calls fails, and every episode and outcome is
    stored once (the models rebuild identically)."""
    from attune_client import Client

    from tests.support import people

    with fresh_database(engine, tmp_path) as url:
        service = LiveService(
            url,
            workers=workers,
            log_path=tmp_path / "serve.log",
            env={"ATTUNE_DRAIN_TIMEOUT_S": str(SIGTERM_DRAIN_S)},
        )
        service.start()
        try:
            keys = make_keys(url, ROBOTS)
            failures: list[str] = []
            played: dict[str, list[str]] = {f"person{n}": [] for n in range(ROBOTS)}
            answered: dict[str, int] = {}  # episode id -> outcomes the robot got answers to
            lock = threading.Lock()
            restarted = threading.Event()
            refused: list[str] = []  # transport failures the client met (and retried)

            class Wire(httpx.HTTPTransport):
                def handle_request(self, request: httpx.Request) -> httpx.Response:
                    try:
                        return super().handle_request(request)
                    except httpx.TransportError as exc:
                        refused.append(type(exc).__name__)
                        raise

            def robot(n: int) -> None:
                user, after = f"person{n}", 0
                try:
                    with Client(service.url, keys[n], max_retries=12, transport=Wire()) as client:
                        for e in range(MOST_EPISODES):
                            if restarted.is_set():
                                after += 1
                                if after > 2:
                                    return
                            ep = client.start_episode(
                                user,
                                event_id=f"{user}-{e}",
                                occurred_at="2026-11-22T15:10:00+08:00",
                                situation="working",
                            )
                            played[user].append(f"{user}-{e}")
                            decision = ep.decision
                            for _ in range(20):
                                if decision is None:
                                    break
                                need = people.TEA if e % 2 else None
                                out = client.report_outcome(
                                    ep.episode_id,
                                    decision_id=decision.decision_id,
                                    **people.answer(decision.action, need=need),
                                )
                                with lock:
                                    answered[ep.episode_id] = answered.get(ep.episode_id, 0) + 1
                                decision = out.decision  # type: ignore[union-attr]
                except Exception as exc:  # what the robot would see
                    failures.append(f"{user}: {type(exc).__name__}: {exc}")

            threads = [threading.Thread(target=robot, args=(n,)) for n in range(ROBOTS)]
            for thread in threads:
                thread.start()
            _wait_for(lambda: sum(answered.values()) >= 8 or failures, "robot traffic", service)
            assert service.process is not None
            os.kill(service.process.pid, signal.SIGTERM)
            assert service.process.wait(timeout=120) == 0, service.log()
            service.start()  # the robots' retries reach it again
            restarted.set()
            for thread in threads:
                thread.join(timeout=600)
            assert not any(thread.is_alive() for thread in threads)
            assert failures == []
            assert refused, "the robots never met the stopped service"
            assert all(len(events) < MOST_EPISODES for events in played.values())
            with Client(service.url, make_keys(url, 1, role="admin")[0]) as admin:
                for user, events in played.items():
                    stored = list(admin.iter_episodes(user))
                    assert sorted(s.event_id for s in stored) == sorted(events)
                    for summary in stored:
                        assert summary.status == "closed"
                        trace = admin.get_episode(summary.episode_id)
                        outcomes = [d for d in trace.decisions if d.response is not None]
                        assert len(outcomes) == answered[summary.episode_id]
            rebuilt = service.attune("models", "rebuild", "--all")
            assert rebuilt.returncode == 0, rebuilt.stdout + rebuilt.stderr
            assert "Traceback" not in service.log()
        finally:
            service.stop()
