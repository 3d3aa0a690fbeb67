"""What the commands that run and administer the service share.

The settings (one line per wrong ``ATTUNE_*`` variable, exit 2); :class:`StartFailure`, a start
that cannot succeed told in one sentence (exit 1); the database's schema brought up to date
(``attune serve``, ``attune db upgrade``, and every command that opens the database first); the
database opened for one command; a message on stderr.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import typer
from rich.console import Console

from ._lazy import LazyModule, lazy_callable

if TYPE_CHECKING:
    from app.db import migrate
    from app.db.session import Database
    from app.settings import Settings, mask_url
else:  # imported when a command runs: --help needs neither SQLAlchemy, Alembic nor pydantic
    migrate = LazyModule("app.db.migrate")
    Database = lazy_callable("app.db.session", "Database")
    Settings = lazy_callable("app.settings", "Settings")
    mask_url = lazy_callable("app.settings", "mask_url")

__all__ = [
    "ENCRYPTED",
    "StartFailure",
    "fail",
    "load_settings",
    "migrations_head",
    "one_line",
    "open_database",
    "sqlite_file",
    "tell",
    "unreadable",
    "upgrade_schema",
]

ENCRYPTED = "An encrypted SQLite database (ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE)"
"""What needs the ``encryption`` extra, as the line that names the extra says it."""

err = Console(stderr=True)


def load_settings() -> Settings:
    """The settings from the ``ATTUNE_*`` environment variables; when one is wrong, one line per
    wrong variable on stderr and exit 2. A database key without SQLCipher's driver installed
    stops the command the same way, with the line that names the extra."""
    try:
        settings = Settings()
    except Exception as exc:  # pydantic's ValidationError: say which variable is wrong
        typer.echo(_bad_settings(exc), err=True)
        raise typer.Exit(2) from None
    if settings.is_sqlite and settings.database_key is not None:
        from app.db.encryption import DRIVER, EXTRA

        from ._extras import require

        require(DRIVER, EXTRA, ENCRYPTED)
    return settings


def _bad_settings(exc: Exception) -> str:
    """One line per wrong ``ATTUNE_*`` variable: its name, what is wrong, what it was."""
    errors = getattr(exc, "errors", None)
    if not callable(errors):
        return f"Bad ATTUNE_* setting: {one_line(exc)}."
    from app.settings import shown  # a database URL without its password, no secret

    lines = []
    for e in errors():
        field = "_".join(str(part) for part in e.get("loc", ()))
        message = str(e.get("msg", "invalid")).removeprefix("Value error, ").rstrip(".")
        got = shown(field, e.get("input"))
        lines.append(f"Bad setting ATTUNE_{field.upper()}: {message} (got {got!r}).")
    return "\n".join(lines) or f"Bad ATTUNE_* setting: {one_line(exc)}."


class StartFailure(Exception):
    """Why the service (or a command) cannot start, as one sentence for the operator."""


def fail(exc: StartFailure) -> NoReturn:
    """Tell the operator why, in one line on stderr, and exit 1."""
    typer.echo(str(exc), err=True)  # plain: rich would wrap the sentence at 80 columns
    raise typer.Exit(1)


def one_line(exc: BaseException) -> str:
    """The first line of an error's message (a driver's hints follow on further lines)."""
    lines = str(getattr(exc, "orig", None) or exc).strip().splitlines()
    text = " ".join(lines[0].split()) if lines else ""
    return text.rstrip(".") or type(exc).__name__


def sqlite_file(settings: Settings) -> Path | None:
    """The SQLite database's file, or None (PostgreSQL, or an in-memory database)."""
    if not settings.is_sqlite:
        return None
    from sqlalchemy.engine import make_url

    name = make_url(settings.database_url).database
    if not name or name == ":memory:" or name.startswith("file:"):
        return None
    return Path(name).absolute()


def unreadable(settings: Settings, exc: BaseException) -> StartFailure | None:
    """Why a SQLite file could not be read as a database (a wrong key, a key for a plain file,
    none for an encrypted one), as one sentence that holds no key; None for another error."""
    from app.db.encryption import is_wrong_key

    if not settings.is_sqlite or not is_wrong_key(exc):
        return None
    url = mask_url(settings.database_url)
    if settings.database_key is None:
        return StartFailure(
            f"The database {url} cannot be read: it is not a SQLite database, or it is "
            "encrypted (then set ATTUNE_DB_KEY or ATTUNE_DB_KEY_FILE to its key)."
        )
    where = "ATTUNE_DB_KEY_FILE" if settings.db_key_file is not None else "ATTUNE_DB_KEY"
    return StartFailure(
        f"The database {url} cannot be read with the key of {where}: the key is wrong, or the "
        "file is not encrypted with it (a plain SQLite file: see Encryption at rest in "
        "docs/operations.md to encrypt it)."
    )


def _remove_sqlite(path: Path) -> None:
    for suffix in ("", "-wal", "-shm", "-journal"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)


def migrations_head() -> str | None:
    """The schema revision of the migrations that come with Attune; :class:`StartFailure` when
    they cannot be read."""
    try:
        return migrate.head_revision()
    except Exception as exc:  # alembic's CommandError for a missing folder, or a broken script
        raise StartFailure(
            "The database migrations that come with Attune cannot be read "
            f"({one_line(exc)}); reinstall Attune."
        ) from exc


def _known_revision(url: str, revision: str) -> bool:
    from alembic.script import ScriptDirectory
    from alembic.util import CommandError

    try:
        ScriptDirectory.from_config(migrate.alembic_config(url)).get_revision(revision)
    except CommandError:
        return False
    return True


def _echo(line: str) -> None:
    typer.echo(line, err=True)  # plain: rich would wrap the line at 80 columns


def upgrade_schema(
    settings: Settings, *, report_current: bool = True, say: Callable[[str], None] = _echo
) -> None:
    """Bring the database's schema up to date (telling ``say`` what was done), or raise
    :class:`StartFailure`.

    Nothing is touched before the migrations are found and the database's folder exists; a
    SQLite file made by a failed attempt is removed again.
    """
    head = migrations_head()
    sqlite = sqlite_file(settings)
    if sqlite is not None and not sqlite.parent.is_dir():
        raise StartFailure(
            f"The SQLite database {sqlite} cannot be made: the folder "
            f"{sqlite.parent} does not exist."
        )
    made = sqlite is not None and not sqlite.exists()
    try:
        safe = Database(settings)
        url = mask_url(settings.database_url)
        try:
            before = migrate.current_revision(safe.engine)
        except Exception as exc:  # the driver's error: refused, unknown host, bad password...
            why = unreadable(settings, exc)
            if why is not None:
                raise why from None  # the driver's message is in the sentence's words
            raise StartFailure(f"Cannot reach the database {url}: {one_line(exc)}.") from exc
        finally:
            safe.dispose()
        if (
            before is not None
            and before != head
            and not _known_revision(settings.database_url, before)
        ):
            raise StartFailure(
                f"The database {url} has schema revision {before}, which this "
                f"version of Attune (schema {head}) does not know: it was made "
                "by a newer release; run that release, or restore a backup."
            )
        if before == head:
            if report_current:
                say(f"Database {url} is up to date (schema {head}).")
            return
        try:
            migrate.upgrade(settings.database_url, key=settings.database_key)
        except Exception as exc:
            raise StartFailure(
                f"Upgrading the database {url} to schema {head} failed: {one_line(exc)}."
            ) from exc
        say(f"Database {url} upgraded: schema {before or 'empty'} -> {head}.")
    except BaseException:
        if made and sqlite is not None:
            _remove_sqlite(sqlite)
        raise


@contextmanager
def open_database(settings: Settings) -> Iterator[Database]:
    """The database, its schema brought up to date first (a fresh machine has none yet)."""
    try:
        upgrade_schema(settings, report_current=False)
    except StartFailure as exc:
        fail(exc)
    database = Database(settings)
    try:
        yield database
    finally:
        database.dispose()


def tell(message: str, style: str = "") -> None:
    """One message on stderr, as it is (no markup), on one line however long."""
    from rich.text import Text

    err.print(Text(message, style=style), soft_wrap=True)
