"""A real ``attune serve`` process on 127.0.0.1, for tests that need the whole service.

``serving(app)`` is the in-process variant: an app object under uvicorn in a background thread,
for tests that patch the app before serving it.

``LiveService`` runs the command line exactly as an operator would (migrations applied at start,
uvicorn with N workers), on a free port, with its own database. It can be stopped gently, killed
with SIGKILL, and started again on the same port and database. ``fresh_database(engine)`` gives a
new SQLite file or a new PostgreSQL database (dropped afterwards), so live runs never collide;
``make_keys`` puts keys in it.

The benchmarks import this module too (``bench/``, with the repository's root on ``sys.path``).
"""

from __future__ import annotations

import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType
from typing import Any

import httpx
import psycopg
import pytest
import uvicorn

from app.db.session import Database
from app.services.auth import create_key
from app.settings import Settings

PG_SERVER = os.environ.get("ATTUNE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432")
ATTUNE = str(Path(sys.executable).with_name("attune"))


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextmanager
def serving(app: Any) -> Iterator[str]:
    """An ASGI app under uvicorn in a background thread on a free port of 127.0.0.1."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 15
        while not server.started:
            assert thread.is_alive(), "uvicorn stopped while starting"
            assert time.monotonic() < deadline, "uvicorn did not start within 15 s"
            time.sleep(0.02)
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=15)
        sock.close()
        assert not thread.is_alive(), "uvicorn did not stop"


def postgres_url(name: str) -> str:
    """The URL of database ``name`` on the test server."""
    return f"{PG_SERVER.rstrip('/')}/{name}"


def database_name(kind: str, worker: str | None = None) -> str:
    """A PostgreSQL database name no other process uses: the kind (``test``, ``live``), the
    pytest-xdist worker (``gw0``...; ``master`` outside xdist, as xdist's ``worker_id`` says),
    the process and a random tag."""
    worker = worker or os.environ.get("PYTEST_XDIST_WORKER", "master")
    return f"attune_{kind}_{worker}_{os.getpid()}_{secrets.token_hex(4)}"


@contextmanager
def postgres_database(name: str) -> Iterator[str]:
    """Create database ``name`` on the test server; its URL; dropped afterwards. Fails the test
    (never skips it) when the server does not answer."""
    try:
        admin = psycopg.connect(postgres_url("postgres"), autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.fail(
            f"PostgreSQL at {PG_SERVER} does not answer ({exc}); the tests need it. "
            "Start it (.ci/run does) or set ATTUNE_TEST_POSTGRES_URL.",
            pytrace=False,
        )
    with admin:
        admin.execute(f'CREATE DATABASE "{name}"')
    try:
        yield postgres_url(name)
    finally:
        with psycopg.connect(postgres_url("postgres"), autocommit=True) as admin:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@contextmanager
def fresh_database(engine: str, folder: Path | None = None) -> Iterator[str]:
    """A URL of an empty database of ``engine`` (``sqlite``, or ``postgresql``: also for
    ``pgbouncer``, whose service reaches it through PgBouncer), removed after."""
    if engine == "sqlite":
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            yield f"sqlite:///{Path(tmp) / 'attune.db'}"
        return
    with postgres_database(database_name("live")) as url:
        yield url


def make_keys(database_url: str, n: int, role: str = "robot", fleet: str = "default") -> list[str]:
    """``n`` keys of ``fleet`` in a service's database, made in this process (much faster than
    ``attune keys create`` n times)."""
    db = Database(Settings(database_url=database_url, _env_file=None))  # type: ignore[call-arg]
    try:
        with db.transaction() as session:
            return [
                create_key(session, role=role, fleet=fleet, name=f"test-{role}-{i}")[1]
                for i in range(n)
            ]
    finally:
        db.dispose()


class LiveService:
    """``attune serve --host 127.0.0.1 --port P --workers N [ARGS...]`` as a child process.

    Use as a context manager (started on entry, stopped on exit). ``url`` stays the same across
    ``kill()`` / ``stop()`` and ``start()``, so clients can reconnect to the restarted service.
    The process's output goes to ``log_path``; ``log()`` returns it (for assertion messages).
    """

    def __init__(
        self,
        database_url: str,
        *,
        workers: int = 1,
        log_path: Path | None = None,
        env: dict[str, str] | None = None,
        seed: int = 0,
        args: Sequence[str] = (),
    ) -> None:
        """``env`` is added to the environment (``ATTUNE_*`` settings), ``args`` to the
        command line (``--root-path /attune``)."""
        self.database_url = database_url
        self.workers = workers
        self.args = list(args)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path or Path(tempfile.mkstemp(prefix="attune-serve-", suffix=".log")[1])
        self.env = {
            **os.environ,
            "ATTUNE_DATABASE_URL": database_url,
            "ATTUNE_SEED": str(seed),
            "ATTUNE_LOG_LEVEL": "warning",
            **(env or {}),
        }
        self.process: subprocess.Popen[bytes] | None = None

    # -- the command line ---------------------------------------------------------------------
    def attune(self, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        """Run another ``attune`` command against the same database."""
        return subprocess.run(
            [ATTUNE, *args],
            env=self.env,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )

    def create_key(
        self, role: str = "robot", fleet: str = "default", name: str | None = None
    ) -> str:
        """``attune keys create``: the secret (the last line it prints)."""
        args = ["keys", "create", "--role", role, "--fleet", fleet]
        if name:
            args += ["--name", name]
        done = self.attune(*args)
        assert done.returncode == 0, done.stderr
        return done.stdout.strip().splitlines()[-1]

    # -- the process --------------------------------------------------------------------------
    def start(self, timeout: float = 60) -> None:
        assert self.process is None or self.process.poll() is not None, "already running"
        with open(self.log_path, "ab") as log:
            self.process = subprocess.Popen(
                [
                    ATTUNE,
                    "serve",
                    "--host",
                    "127.0.0.1",
                    "--port",
                    str(self.port),
                    "--workers",
                    str(self.workers),
                    *self.args,
                ],
                env=self.env,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        deadline = time.monotonic() + timeout
        while True:
            if self.process.poll() is not None:
                raise AssertionError(
                    f"attune serve exited with {self.process.returncode}:\n{self.log()}"
                )
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                self.kill()
                raise AssertionError(f"attune serve not ready within {timeout} s:\n{self.log()}")
            time.sleep(0.1)

    def _signal(self, sig: signal.Signals, timeout: float) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        os.killpg(self.process.pid, sig)  # the whole group: uvicorn's workers too
        try:
            self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout=10)

    def stop(self, timeout: float = 20) -> None:
        """SIGTERM (uvicorn finishes the requests in flight), then SIGKILL if it hangs."""
        self._signal(signal.SIGTERM, timeout)

    def kill(self) -> None:
        """SIGKILL to the server and its workers: no chance to finish anything."""
        self._signal(signal.SIGKILL, 10)

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")[-4000:]
        except OSError:
            return ""

    def __enter__(self) -> LiveService:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
