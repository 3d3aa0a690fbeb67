"""PgBouncer in transaction pooling, in front of the test PostgreSQL, as the test's own process.

``launch()`` starts Debian's ``/usr/sbin/pgbouncer`` on a free port of 127.0.0.1 with an ini,
a log, a pid file and a users file of its own in a temporary folder, in ``pool_mode =
transaction`` for every database of the test server (a ``*`` entry), and stops it at the end;
it raises ``PgBouncerFailed`` when PgBouncer is missing or does not start.
``running_pgbouncer()``, the tests' form of it, fails the test with that message instead (it
never skips); ``bench/remote_db.py --pooler pgbouncer`` uses ``launch()``. PgBouncer refuses
to run as root: under root it is started with ``-u postgres`` (it drops to that user itself;
the folder is given to that user). Clients authenticate with ``auth_type = trust``; PgBouncer
logs in to the server as the test URL's user (and password).

The ``pgbouncer`` test engine (``tests/support/fixtures.py``) and the stress tests put the
service's URL through it, with ``ATTUNE_DATABASE_POOLER=transaction``; databases are made and
migrated on the server directly.
"""

from __future__ import annotations

import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from sqlalchemy.engine import make_url

from .live import PG_SERVER, free_port

PGBOUNCER = Path(os.environ.get("ATTUNE_TEST_PGBOUNCER", "/usr/sbin/pgbouncer"))
POOL_SIZE = 20
"""PgBouncer's server connections per database and user (its ``default_pool_size``)."""


@dataclass(frozen=True)
class Bouncer:
    """A running PgBouncer: ``url(name)`` is database ``name`` of the test server through it."""

    port: int
    log_path: Path

    def url(self, name: str) -> str:
        server = make_url(PG_SERVER)
        auth = server.username or "postgres"
        if server.password:
            auth += f":{server.password}"
        return f"postgresql://{auth}@127.0.0.1:{self.port}/{name}"

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""


def _answers(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    except OSError:
        return False
    return True


def _ini(folder: Path, port: int) -> str:
    server = make_url(PG_SERVER)
    target = f"host={server.host or '127.0.0.1'} port={server.port or 5432}"
    if server.password:
        target += f" password={server.password}"
    return "\n".join(
        [
            "[databases]",
            f"* = {target}",
            "[pgbouncer]",
            "listen_addr = 127.0.0.1",
            f"listen_port = {port}",
            "unix_socket_dir =",
            "auth_type = trust",
            f"auth_file = {folder / 'users.txt'}",
            "pool_mode = transaction",
            f"default_pool_size = {POOL_SIZE}",
            "max_client_conn = 1000",
            "server_reset_query =",
            f"logfile = {folder / 'pgbouncer.log'}",
            f"pidfile = {folder / 'pgbouncer.pid'}",
            "",
        ]
    )


class PgBouncerFailed(RuntimeError):
    """PgBouncer is missing, or did not start (the message has its log)."""


@contextmanager
def running_pgbouncer() -> Iterator[Bouncer]:
    """``launch()`` for a test: fails the test (it never skips) when PgBouncer is missing or
    does not start."""
    with ExitStack() as stack:
        try:
            bouncer = stack.enter_context(launch())
        except PgBouncerFailed as failure:
            pytest.fail(str(failure), pytrace=False)
        yield bouncer


@contextmanager
def launch() -> Iterator[Bouncer]:
    """PgBouncer on a free port, transaction pooling, until the block ends; raises
    ``PgBouncerFailed`` when it is missing or does not start."""
    if not PGBOUNCER.exists():
        raise PgBouncerFailed(
            f"{PGBOUNCER} is missing: PgBouncer in transaction pooling needs Debian's pgbouncer "
            "(apt-get install pgbouncer; .ci/run installs it)."
        )
    folder = Path(tempfile.mkdtemp(prefix="attune-pgbouncer-"))
    user = make_url(PG_SERVER).username or "postgres"
    (folder / "users.txt").write_text(f'"{user}" ""\n')
    command = [str(PGBOUNCER)]
    if os.geteuid() == 0:  # "PgBouncer should not run as root": it switches user itself
        owner = pwd.getpwnam("postgres")
        for path in (folder, *folder.iterdir()):
            os.chown(path, owner.pw_uid, owner.pw_gid)
        command += ["-u", "postgres"]
    port = free_port()
    (folder / "pgbouncer.ini").write_text(_ini(folder, port))
    os.chmod(folder / "pgbouncer.ini", 0o644)
    bouncer = Bouncer(port, folder / "pgbouncer.log")
    process = subprocess.Popen(
        [*command, str(folder / "pgbouncer.ini")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 15
        while not _answers(port):
            if process.poll() is not None or time.monotonic() > deadline:
                raise PgBouncerFailed(f"PgBouncer did not start:\n{bouncer.log()}")
            time.sleep(0.05)
        yield bouncer
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        shutil.rmtree(folder, ignore_errors=True)
