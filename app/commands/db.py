"""``attune db upgrade`` and ``attune db current``: the database's schema; ``attune db
backup``: a copy of a SQLite database, encrypted as it is."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ._help import Typer
from ._lazy import LazyModule, lazy_callable
from ._setup import (
    StartFailure,
    fail,
    load_settings,
    migrations_head,
    one_line,
    sqlite_file,
    tell,
    unreadable,
    upgrade_schema,
)

if TYPE_CHECKING:
    from pydantic import SecretStr

    from app.db import migrate
    from app.db.backup import BackupDone
    from app.db.session import Database
    from app.settings import Settings, mask_url
else:  # imported when a command runs: --help needs neither SQLAlchemy nor Alembic
    migrate = LazyModule("app.db.migrate")
    Database = lazy_callable("app.db.session", "Database")
    mask_url = lazy_callable("app.settings", "mask_url")

__all__ = ["db"]

db = Typer(
    help="The database: ATTUNE_DATABASE_URL (default sqlite:///./attune.db).", no_args_is_help=True
)


@db.command("upgrade")
def db_upgrade() -> None:
    """Apply pending migrations to ATTUNE_DATABASE_URL and exit."""
    try:
        upgrade_schema(load_settings())
    except StartFailure as exc:
        fail(exc)


@db.command("current")
def db_current() -> None:
    """Print the schema revision of the database and of this code (nothing is changed: a
    SQLite file that does not exist is not made)."""
    settings = load_settings()
    try:
        head = migrations_head()
        sqlite = sqlite_file(settings)
        if sqlite is not None and not sqlite.exists():
            current: str | None = None
            where = f" (no file at {sqlite})"
        else:
            database = Database(settings)
            url = mask_url(settings.database_url)
            try:
                current = migrate.current_revision(database.engine)
            except Exception as exc:  # the driver's error: refused, unknown host...
                why = unreadable(settings, exc)
                if why is not None:
                    raise why from None
                raise StartFailure(f"Cannot reach the database {url}: {one_line(exc)}.") from exc
            finally:
                database.dispose()
            where = ""
    except StartFailure as exc:
        fail(exc)
    typer.echo(f"database: {current or 'empty'}{where}\ncode:     {head}")


@db.command("backup")
def db_backup(
    target: Annotated[Path, typer.Argument(help="The file to write; it must not exist.")],
    key_file: Annotated[
        Path | None,
        typer.Option(
            "--key-file",
            help="Encrypt the copy with the key in this file (its content without surrounding "
            "whitespace) instead of the database's: to encrypt a plain database, or to change "
            "the key. Needs the encryption extra.",
        ),
    ] = None,
) -> None:
    """Copy the SQLite database of ATTUNE_DATABASE_URL to a new file, safely while the service
    runs: one consistent snapshot, a complete database, checked, readable by its owner only.
    It is encrypted with the database's key (ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE), or plain
    when the database is. PostgreSQL is backed up with pg_dump (docs/operations.md)."""
    settings = load_settings()
    if not settings.is_sqlite:
        tell("attune db backup copies a SQLite database; back PostgreSQL up with pg_dump.", "red")
        raise typer.Exit(2)
    source = sqlite_file(settings)
    if source is None:
        tell("attune db backup copies a SQLite file; an in-memory database has none.", "red")
        raise typer.Exit(2)
    new_key = _new_key(key_file) if key_file is not None else None
    url = mask_url(settings.database_url)
    try:
        if not source.exists():
            raise StartFailure(f"There is no SQLite database at {source}: nothing to back up.")
        target = target.absolute()
        if not target.parent.is_dir():
            raise StartFailure(f"The backup {target} cannot be made: the folder does not exist.")
        done = _backup(settings, source, target, new_key)
    except StartFailure as exc:
        fail(exc)
    if key_file is not None:
        how = f"encrypted with the key in {key_file}"
    elif settings.database_key is not None:
        how = "encrypted with the database's key"
    else:
        how = "not encrypted, as the database is not"
    if done.check != "ok":
        fail(StartFailure(f"The backup {done.path} of {url} fails SQLite's check: {done.check}."))
    tell(f"Backed up {url} to {done.path}: {done.pages} pages, checked, {how}.")


def _new_key(key_file: Path) -> SecretStr:
    """The key in ``--key-file``; one line and exit 2 when it cannot be read or is empty, or
    SQLCipher's driver is missing."""
    from pydantic import SecretStr

    from app.db.encryption import DRIVER, EXTRA

    from ._extras import require

    require(DRIVER, EXTRA, "attune db backup --key-file")
    try:
        key = key_file.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else "it is not UTF-8 text"
        tell(f"--key-file {key_file} cannot be read: {reason}.", "red")
        raise typer.Exit(2) from None
    if not key:
        tell(f"--key-file {key_file} is empty: it must hold the key.", "red")
        raise typer.Exit(2)
    return SecretStr(key)


def _backup(
    settings: Settings, source: Path, target: Path, new_key: SecretStr | None
) -> BackupDone:
    """The backup made, or :class:`StartFailure` saying why not (in words that hold no key)."""
    from app.db.backup import BackupExists, backup

    database = Database(settings)
    try:
        return backup(database, source, target, settings.database_key, new_key)
    except BackupExists as exc:
        raise StartFailure(str(exc)) from None
    except Exception as exc:  # the driver's error: a wrong key, a full disk, a missing folder
        why = unreadable(settings, exc)
        if why is not None:
            raise why from None
        raise StartFailure(
            f"Backing up the database {mask_url(settings.database_url)} to {target} failed: "
            f"{one_line(exc)}."
        ) from None
    finally:
        database.dispose()
