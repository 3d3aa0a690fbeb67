"""An encrypted SQLite database: SQLCipher (the ``encryption`` extra), keyed from the settings
(``ATTUNE_DB_KEY`` or ``ATTUNE_DB_KEY_FILE``).

The key is never part of the database URL (SQLAlchemy's own SQLCipher dialect takes it as the
URL's password, which every message that shows the URL would then have to hide). The URL stays
``sqlite:///PATH``; the engine uses SQLCipher's driver in place of the standard library's
``sqlite3``, and each new connection is given the key with ``PRAGMA key`` on the driver's
connection, before anything reads the file. SQLAlchemy logs only the statements it runs itself,
so no log holds the key.

SQLCipher encrypts every page of the file, and of its write-ahead log, with the key: without it
the file reads as random bytes (``file is not a database``).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType
from typing import Any

from pydantic import SecretStr
from sqlalchemy import Engine, event

__all__ = [
    "DRIVER",
    "EXTRA",
    "EncryptionUnavailable",
    "apply_key",
    "connect",
    "driver",
    "is_wrong_key",
    "key_pragma",
    "keyed",
]

DRIVER = "sqlcipher3"
"""The module of SQLCipher's DB-API driver, which the ``encryption`` extra installs."""
EXTRA = "encryption"

_NOT_A_DATABASE = "file is not a database"


class EncryptionUnavailable(RuntimeError):
    """A database key is set, but SQLCipher's driver is not installed."""

    def __init__(self) -> None:
        super().__init__(
            "An encrypted SQLite database (ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE) needs the "
            f"'{EXTRA}' extra: in the folder of the Attune clone, run pip install '.[{EXTRA}]'"
        )


def driver() -> ModuleType:
    """SQLCipher's DB-API module, or :class:`EncryptionUnavailable`."""
    try:
        return importlib.import_module(f"{DRIVER}.dbapi2")
    except ImportError:
        raise EncryptionUnavailable() from None


def key_pragma(key: SecretStr) -> str:
    """``PRAGMA key`` with ``key`` as an SQL string (a raw key, ``x'...'``, stays one)."""
    quoted = key.get_secret_value().replace("'", "''")
    return f"PRAGMA key = '{quoted}'"


def keyed(connection: Any, key: SecretStr) -> Any:
    """``connection`` given ``key``; SQLCipher's own log (a failed page check on stderr) off,
    since a wrong key is told by the error it raises."""
    connection.execute("PRAGMA cipher_log_level = NONE")
    connection.execute(key_pragma(key))
    return connection


def apply_key(engine: Engine, key: SecretStr) -> None:
    """Give every connection ``engine`` opens ``key``, first thing (before its ``connect``
    listeners: journal mode, foreign keys)."""

    @event.listens_for(engine, "do_connect")
    def _connect(dialect: Any, _record: Any, cargs: Any, cparams: Any) -> Any:
        return keyed(dialect.loaded_dbapi.connect(*cargs, **cparams), key)


def connect(path: Path, key: SecretStr | None) -> Any:
    """A SQLCipher connection to the file ``path``, keyed with ``key`` (None: a plain file)."""
    connection = driver().connect(str(path), check_same_thread=False)
    if key is None:
        connection.execute("PRAGMA cipher_log_level = NONE")
        return connection
    return keyed(connection, key)


def is_wrong_key(exc: BaseException) -> bool:
    """Whether ``exc`` (a driver's error, or SQLAlchemy's around one) says the file could not
    be read as a database: a wrong key, a key for a plain file, or none for an encrypted one."""
    return _NOT_A_DATABASE in str(getattr(exc, "orig", None) or exc)
