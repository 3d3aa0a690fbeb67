"""Encryption at rest.

SQLite with a key (``ATTUNE_DB_KEY`` or ``ATTUNE_DB_KEY_FILE``, SQLCipher from the
``encryption`` extra): a database made by ``attune db upgrade`` and written by the service holds
no readable resident id, in its file, its write-ahead log or its backup; the plain ``sqlite3``
module cannot open it, the key reads it back, a wrong key or none stops a command with one
sentence, and no log, output or setting's repr holds the key. ``attune db backup --key-file``
encrypts a plain database's copy, or changes the key. PostgreSQL: the service reaches a server
that accepts TLS connections only, verifying its certificate (``sslmode=verify-full``), and so
does ``pg_dump``; that test runs where PostgreSQL's programs and openssl are installed.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import pwd
import shutil
import sqlite3
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import text
from typer.testing import CliRunner, Result

from app.cli import app as cli
from app.db.session import Database
from app.main import create_app
from app.settings import Settings, shown
from tests.support.live import free_port

RESIDENT = "resident-ZQX-4711"
NAME = "Mrs. Quixley-Zander"
KEY = "correct horse battery staple 7f3a"
OTHER_KEY = "an entirely different passphrase 91c2"

needs_sqlcipher = pytest.mark.skipif(
    importlib.util.find_spec("sqlcipher3") is None,
    reason="the encryption extra (sqlcipher3) is not installed: pip install '.[encryption]'",
)


def attune(url: str, *args: str, key: str | None = None, key_file: Path | None = None) -> Result:
    """``attune ARGS`` in this process on the database ``url``, keyed as given (else no key)."""
    env = {
        "ATTUNE_DATABASE_URL": url,
        "ATTUNE_DB_KEY": key,
        "ATTUNE_DB_KEY_FILE": str(key_file) if key_file is not None else None,
        "COLUMNS": "200",
    }
    return CliRunner(env=env).invoke(cli, list(args))


def settings(url: str, **values: object) -> Settings:
    return Settings(database_url=url, _env_file=None, **values)  # type: ignore[arg-type,call-arg]


def robot_key(url: str, key: str | None) -> str:
    """The secret of a new robot key, made by ``attune keys create``."""
    done = attune(url, "keys", "create", "--role", "robot", key=key)
    assert done.exit_code == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


def raw(path: Path) -> bytes:
    return path.read_bytes()


def assert_unreadable_by_sqlite3(path: Path) -> None:
    connection = sqlite3.connect(path)
    try:
        with pytest.raises(sqlite3.DatabaseError, match="file is not a database"):
            connection.execute("SELECT name FROM sqlite_master").fetchall()
    finally:
        connection.close()


def read_user(url: str, key: str) -> tuple[str, str | None]:
    """The resident's row, read with ``key`` through the service's own engine."""
    database = Database(settings(url, db_key=key))
    try:
        with database.engine.connect() as conn:
            row = conn.execute(
                text("SELECT user_id, display_name FROM users WHERE user_id = :id"),
                {"id": RESIDENT},
            ).one()
    finally:
        database.dispose()
    return row[0], row[1]


@needs_sqlcipher
def test_an_encrypted_database_holds_no_readable_resident_id(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capfd: pytest.CaptureFixture[str]
) -> None:
    # Every statement SQLAlchemy runs is logged: the key must not be among them.
    caplog.set_level(logging.DEBUG)
    caplog.set_level(logging.INFO, logger="sqlalchemy.engine")
    path = tmp_path / "attune.db"
    url = f"sqlite:///{path}"
    outputs = []

    upgraded = attune(url, "db", "upgrade", key=KEY)
    assert upgraded.exit_code == 0, upgraded.stderr
    secret = robot_key(url, KEY)
    outputs += [upgraded.output, secret]

    service = settings(url, db_key=KEY)
    assert KEY not in repr(service)
    with TestClient(create_app(service), headers={"Authorization": f"Bearer {secret}"}) as robot:
        made = robot.put(f"/v1/users/{RESIDENT}", json={"display_name": NAME})
        assert made.status_code == 201, made.text
        assert robot.get(f"/v1/users/{RESIDENT}").json()["display_name"] == NAME
        # While the service runs, the latest writes are in the write-ahead log.
        wal = Path(f"{path}-wal")
        assert wal.stat().st_size > 0
        backed_up = attune(url, "db", "backup", str(tmp_path / "backup.db"), key=KEY)
        assert backed_up.exit_code == 0, backed_up.stderr
        assert "encrypted with the database's key" in backed_up.stderr
        outputs.append(backed_up.output)
        files = {"database": raw(path), "write-ahead log": raw(wal)}
    files["backup"] = raw(tmp_path / "backup.db")
    files["database, closed"] = raw(path)

    for what, content in files.items():
        assert RESIDENT.encode() not in content, what
        assert NAME.encode() not in content, what
        assert b"SQLite format 3" not in content, what  # not even SQLite's header is readable
    assert files["backup"]
    assert_unreadable_by_sqlite3(path)
    assert_unreadable_by_sqlite3(tmp_path / "backup.db")
    assert read_user(url, KEY) == (RESIDENT, NAME)
    assert read_user(f"sqlite:///{tmp_path / 'backup.db'}", KEY) == (RESIDENT, NAME)

    logged = caplog.text + "".join(outputs) + "".join(capfd.readouterr())
    assert any(r.name.startswith("sqlalchemy.engine") for r in caplog.records)  # SQL was logged
    assert KEY not in logged


@needs_sqlcipher
def test_a_backup_restores_with_the_same_key(tmp_path: Path) -> None:
    """The restore of docs/operations.md: the backup copied in place of the database (the old
    files moved aside), and the service reads it with the key it was taken with."""
    url = f"sqlite:///{tmp_path / 'attune.db'}"
    assert attune(url, "db", "upgrade", key=KEY).exit_code == 0
    secret = robot_key(url, KEY)
    with TestClient(
        create_app(settings(url, db_key=KEY)), headers={"Authorization": f"Bearer {secret}"}
    ) as robot:
        assert robot.put(f"/v1/users/{RESIDENT}", json={"display_name": NAME}).status_code == 201
    backup = tmp_path / "attune-2026-12-02.db"
    assert attune(url, "db", "backup", str(backup), key=KEY).exit_code == 0
    assert backup.stat().st_mode & 0o777 == 0o600

    restored = tmp_path / "restored"
    restored.mkdir()
    shutil.copyfile(backup, restored / "attune.db")
    restored_url = f"sqlite:///{restored / 'attune.db'}"
    current = attune(restored_url, "db", "current", key=KEY)
    assert current.exit_code == 0, current.stderr
    assert "empty" not in current.stdout
    assert attune(restored_url, "db", "upgrade", key=KEY).exit_code == 0
    with TestClient(
        create_app(settings(restored_url, db_key=KEY)),
        headers={"Authorization": f"Bearer {secret}"},
    ) as robot:
        assert robot.get(f"/v1/users/{RESIDENT}").json()["display_name"] == NAME


@needs_sqlcipher
def test_a_wrong_key_or_none_is_one_sentence_not_a_traceback(tmp_path: Path) -> None:
    path = tmp_path / "attune.db"
    url = f"sqlite:///{path}"
    assert attune(url, "db", "upgrade", key=KEY).exit_code == 0
    before = raw(path)

    wrong = attune(url, "db", "upgrade", key=OTHER_KEY)
    assert wrong.exit_code == 1
    assert wrong.stderr == (
        f"The database {url} cannot be read with the key of ATTUNE_DB_KEY: the key is wrong, or "
        "the file is not encrypted with it (a plain SQLite file: see Encryption at rest in "
        "docs/operations.md to encrypt it).\n"
    )
    key_file = tmp_path / "db.key"
    key_file.write_text(OTHER_KEY + "\n")
    for args in (["keys", "list"], ["db", "current"], ["db", "backup", str(tmp_path / "b.db")]):
        done = attune(url, *args, key_file=key_file)
        assert done.exit_code == 1, args
        assert done.stderr.startswith(f"The database {url} cannot be read with the key of "), args
        assert "ATTUNE_DB_KEY_FILE" in done.stderr
        assert "Traceback" not in done.output
        assert OTHER_KEY not in done.output
    assert not (tmp_path / "b.db").exists()

    unkeyed = attune(url, "db", "upgrade")
    assert unkeyed.exit_code == 1
    assert unkeyed.stderr == (
        f"The database {url} cannot be read: it is not a SQLite database, or it is encrypted "
        "(then set ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE to its key).\n"
    )
    assert raw(path) == before  # nothing was written


@needs_sqlcipher
def test_the_key_from_a_file(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'attune.db'}"
    key_file = tmp_path / "db.key"
    key_file.write_text(f"  {KEY}\n")  # what surrounds the key is not part of it
    done = attune(url, "db", "upgrade", key_file=key_file)
    assert done.exit_code == 0, done.stderr
    from_file = settings(url, db_key_file=key_file)
    assert from_file.database_key is not None
    assert from_file.database_key.get_secret_value() == KEY
    assert KEY not in repr(from_file)
    assert KEY not in from_file.model_dump_json()
    assert attune(url, "db", "current", key=KEY).exit_code == 0  # the same key as ATTUNE_DB_KEY
    assert_unreadable_by_sqlite3(tmp_path / "attune.db")


def test_bad_key_settings_say_so_without_the_key(tmp_path: Path) -> None:
    key_file = tmp_path / "db.key"
    key_file.write_text(KEY)
    sqlite = f"sqlite:///{tmp_path / 'attune.db'}"
    both = CliRunner(
        env={
            "ATTUNE_DATABASE_URL": sqlite,
            "ATTUNE_DB_KEY": KEY,
            "ATTUNE_DB_KEY_FILE": str(key_file),
        }
    ).invoke(cli, ["db", "upgrade"])
    assert both.exit_code == 2
    assert both.stderr == (
        "Bad setting ATTUNE_DB_KEY_FILE: set ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE, not both "
        f"(got {str(key_file)!r}).\n"
    )
    postgres = attune("postgresql://attune:pw@127.0.0.1:9/attune", "db", "upgrade", key=KEY)
    assert postgres.exit_code == 2
    assert postgres.stderr == (
        "Bad setting ATTUNE_DB_KEY: a database key is for an encrypted SQLite file; PostgreSQL "
        "is encrypted by its storage, and reached over TLS (docs/operations.md, Encryption at "
        "rest) (got '***').\n"
    )
    empty = attune(sqlite, "db", "upgrade", key_file=tmp_path / "missing.key")
    assert empty.exit_code == 2
    assert "db_key_file cannot be read: No such file or directory" in empty.stderr
    for done in (both, postgres, empty):
        assert KEY not in done.output
    assert not (tmp_path / "attune.db").exists()
    assert shown("db_key", KEY) == "***"


@needs_sqlcipher
def test_backup_with_another_key_encrypts_a_plain_database_and_changes_a_key(
    tmp_path: Path,
) -> None:
    plain = f"sqlite:///{tmp_path / 'plain.db'}"
    assert attune(plain, "db", "upgrade").exit_code == 0
    secret = robot_key(plain, None)
    with TestClient(
        create_app(settings(plain)), headers={"Authorization": f"Bearer {secret}"}
    ) as robot:
        assert robot.put(f"/v1/users/{RESIDENT}", json={"display_name": NAME}).status_code == 201
    assert read_plain(tmp_path / "plain.db") == [(RESIDENT,)]  # anyone can read this one
    assert RESIDENT.encode() in raw(tmp_path / "plain.db")  # and the bytes show the id

    first, second = tmp_path / "first.key", tmp_path / "second.key"
    first.write_text(KEY + "\n")
    second.write_text(OTHER_KEY + "\n")
    encrypted = tmp_path / "encrypted.db"
    done = attune(plain, "db", "backup", str(encrypted), "--key-file", str(first))
    assert done.exit_code == 0, done.stderr
    assert f"encrypted with the key in {first}" in done.stderr
    assert RESIDENT.encode() not in raw(encrypted)
    assert_unreadable_by_sqlite3(encrypted)
    encrypted_url = f"sqlite:///{encrypted}"
    assert read_user(encrypted_url, KEY) == (RESIDENT, NAME)

    rekeyed = tmp_path / "rekeyed.db"
    done = attune(encrypted_url, "db", "backup", str(rekeyed), "--key-file", str(second), key=KEY)
    assert done.exit_code == 0, done.stderr
    assert read_user(f"sqlite:///{rekeyed}", OTHER_KEY) == (RESIDENT, NAME)
    assert attune(f"sqlite:///{rekeyed}", "db", "current", key=KEY).exit_code == 1
    current = attune(f"sqlite:///{rekeyed}", "db", "current", key_file=second)
    assert current.exit_code == 0, current.stderr
    assert OTHER_KEY not in current.output


def read_plain(path: Path) -> list[tuple[str]]:
    """The user ids of a plain SQLite file, read with the standard library's ``sqlite3``."""
    connection = sqlite3.connect(path)
    try:
        return connection.execute("SELECT user_id FROM users").fetchall()
    finally:
        connection.close()


# PostgreSQL: TLS to the database.


def _run(*command: str, user: str | None = None) -> None:
    prefix = ["runuser", "-u", user, "--"] if user else []
    subprocess.run([*prefix, *command], check=True, capture_output=True, timeout=120)


def _certificates(folder: Path) -> tuple[Path, Path, Path, Path]:
    """A CA, a server certificate it signed for 127.0.0.1 and the server's key, and another
    CA that signed nothing of this server."""
    folder.mkdir()
    ca, ca_key, other = folder / "ca.pem", folder / "ca.key", folder / "other-ca.pem"
    cert, key = folder / "server.pem", folder / "server.key"
    for name, out, out_key in (("ca", ca, ca_key), ("other", other, folder / "other.key")):
        _run(
            "openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
            "-subj", f"/CN=attune-test-{name}", "-keyout", str(out_key), "-out", str(out),
        )  # fmt: skip
    _run(
        "openssl", "req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1",
        "-keyout", str(key), "-out", str(folder / "server.csr"),
    )  # fmt: skip
    (folder / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
    _run(
        "openssl", "x509", "-req", "-in", str(folder / "server.csr"), "-CA", str(ca),
        "-CAkey", str(ca_key), "-CAcreateserial", "-days", "2",
        "-extfile", str(folder / "san.ext"), "-out", str(cert),
    )  # fmt: skip
    return ca, other, cert, key


@contextmanager
def tls_only_postgres() -> Iterator[tuple[int, Path, Path]]:
    """A PostgreSQL of its own on a free port of 127.0.0.1 that accepts TLS connections only
    (``hostssl``), in a temporary folder (under root, given to the ``postgres`` user, since
    PostgreSQL refuses to run as root); its port, its CA and another CA. Skips where the
    programs are missing."""
    programs = {name: shutil.which(name) for name in ("initdb", "pg_ctl", "pg_dump", "openssl")}
    missing = sorted(name for name, found in programs.items() if found is None)
    if missing:
        pytest.skip(f"TLS to PostgreSQL is tested where {', '.join(missing)} is installed")
    folder = Path(tempfile.mkdtemp(prefix="attune-tls-postgres-"))
    try:
        with _tls_only_postgres(folder, programs) as found:
            yield found
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@contextmanager
def _tls_only_postgres(
    folder: Path, programs: dict[str, str | None]
) -> Iterator[tuple[int, Path, Path]]:
    ca, other, cert, key = _certificates(folder / "certs")
    data, user = folder / "data", None
    data.mkdir()
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        user = "postgres"
        owner = pwd.getpwnam(user)
        for path in (folder, data, cert, key):
            os.chown(path, owner.pw_uid, owner.pw_gid)
    key.chmod(0o600)
    _run(str(programs["initdb"]), "-D", str(data), "-A", "trust", "-U", "postgres", "--no-sync",
         user=user)  # fmt: skip
    port = free_port()
    with (data / "postgresql.conf").open("a") as conf:
        conf.write(
            f"port = {port}\nlisten_addresses = '127.0.0.1'\nunix_socket_directories = ''\n"
            f"ssl = on\nssl_cert_file = '{cert}'\nssl_key_file = '{key}'\nfsync = off\n"
        )
    (data / "pg_hba.conf").write_text("hostssl all all 127.0.0.1/32 trust\n")
    log = folder / "postgres.log"
    if user is not None:
        log.touch()
        os.chown(log, pwd.getpwnam(user).pw_uid, pwd.getpwnam(user).pw_gid)
    pg_ctl = str(programs["pg_ctl"])
    _run(pg_ctl, "-D", str(data), "-l", str(log), "-w", "start", user=user)
    try:
        yield port, ca, other
    finally:
        _run(pg_ctl, "-D", str(data), "-m", "immediate", "-w", "stop", user=user)


def test_the_service_reaches_postgresql_over_verified_tls(tmp_path: Path) -> None:
    with tls_only_postgres() as (port, ca, other):
        base = f"postgresql://postgres@127.0.0.1:{port}/postgres"
        url = f"{base}?sslmode=verify-full&sslrootcert={ca}"
        done = attune(url, "db", "upgrade")
        assert done.exit_code == 0, done.stderr
        database = Database(settings(url))
        try:
            with database.engine.connect() as conn:
                in_tls = conn.execute(
                    text("SELECT ssl FROM pg_stat_ssl WHERE pid = pg_backend_pid()")
                ).scalar_one()
        finally:
            database.dispose()
        assert in_tls is True

        # Without TLS the server refuses; with a CA that did not sign its certificate, so
        # does the service.
        refused = attune(f"{base}?sslmode=disable", "db", "current")
        assert refused.exit_code == 1
        assert "no encryption" in refused.stderr
        unverified = attune(f"{base}?sslmode=verify-full&sslrootcert={other}", "db", "current")
        assert unverified.exit_code == 1
        assert "certificate verify failed" in unverified.stderr

        # A backup with pg_dump travels over the same verified TLS.
        dump = tmp_path / "attune.dump"
        subprocess.run(
            ["pg_dump", "--format=custom", "--file", str(dump), url],
            check=True,
            capture_output=True,
            timeout=120,
        )
        assert dump.stat().st_size > 0
