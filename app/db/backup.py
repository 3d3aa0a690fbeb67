"""``attune db backup``: a copy of the SQLite database in one file, taken while the service
runs, and encrypted as the database is.

The copy is one consistent snapshot (SQLite's online backup, or SQLCipher's ``sqlcipher_export``
inside one read transaction), a complete database with no write-ahead log beside it. By default
it is encrypted with the database's own key, or plain when the database is; given another key
(``new_key``), it is encrypted with that one instead: how a plain database is encrypted, or the
key changed, without touching the database in service.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import SecretStr

from . import encryption
from .session import Database

__all__ = ["BackupDone", "BackupExists", "backup"]

_COPY = "attune_copy"  # the copy's schema name while it is attached (sqlcipher_export)


class BackupExists(FileExistsError):
    """The backup's file already exists: a backup never overwrites one."""


@dataclass(frozen=True)
class BackupDone:
    """What was written: the file, its pages, and the result of SQLite's quick check of it."""

    path: Path
    pages: int
    check: str


def backup(
    database: Database,
    source: Path,
    target: Path,
    key: SecretStr | None,
    new_key: SecretStr | None = None,
) -> BackupDone:
    """Copy the SQLite database ``source`` (served by ``database``, opened with ``key``) to the
    new file ``target``, encrypted with ``new_key`` if given, else as the database is. The file
    is made readable by its owner only; on failure nothing is left of it."""
    _make_private(target)
    try:
        if new_key is None:
            _online_backup(database, target, key)
            copy = _open(database, target, key)
        else:
            _export(source, target, key, new_key)
            copy = encryption.connect(target, new_key)
        return _checked(target, copy)
    except BaseException:
        for suffix in ("", "-journal", "-wal", "-shm"):
            Path(f"{target}{suffix}").unlink(missing_ok=True)
        raise


def _make_private(target: Path) -> None:
    """An empty ``target``, mode 0600 (SQLite takes an empty file for a new database), or
    :class:`BackupExists`."""
    try:
        os.close(os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
    except FileExistsError:
        raise BackupExists(f"{target} already exists: a backup never overwrites a file.") from None


def _open(database: Database, path: Path, key: SecretStr | None) -> Any:
    """A connection of the database's own driver to ``path``, keyed with ``key`` if any."""
    connection = database.engine.dialect.loaded_dbapi.connect(str(path))
    return encryption.keyed(connection, key) if key is not None else connection


def _online_backup(database: Database, target: Path, key: SecretStr | None) -> None:
    """SQLite's online backup, from a connection of the service's pool into ``target`` keyed
    with the database's key: the pages are encrypted again as they are written."""
    copy = _open(database, target, key)
    try:
        with database.engine.connect() as conn:
            driver: Any = conn.connection.driver_connection
            driver.backup(copy)
    finally:
        copy.close()


def _export(source: Path, target: Path, key: SecretStr | None, new_key: SecretStr) -> None:
    """SQLCipher's export of every table, index and trigger into ``target`` attached with
    ``new_key``, in one read transaction of the source."""
    connection = encryption.connect(source, key)
    try:
        connection.isolation_level = None  # the transaction below, and nothing implicit
        connection.execute(
            f"ATTACH DATABASE ? AS {_COPY} KEY ?", (str(target), new_key.get_secret_value())
        )
        try:
            connection.execute("BEGIN")
            try:
                connection.execute(f"SELECT sqlcipher_export('{_COPY}')").fetchall()
            except BaseException:
                connection.execute("ROLLBACK")
                raise
            connection.execute("COMMIT")
        finally:
            connection.execute(f"DETACH DATABASE {_COPY}")
    finally:
        connection.close()


def _checked(target: Path, copy: Any) -> BackupDone:
    """The copy, on ``copy``, a connection opened as a restore will (with the copy's key), and
    checked."""
    try:
        check = str(copy.execute("PRAGMA quick_check").fetchone()[0])
        pages = int(copy.execute("PRAGMA page_count").fetchone()[0])
    finally:
        copy.close()
    return BackupDone(path=target, pages=pages, check=check)
