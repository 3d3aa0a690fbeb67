"""``attune db upgrade`` and ``attune db current``: the database's schema."""

from __future__ import annotations

from typing import TYPE_CHECKING

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
    upgrade_schema,
)

if TYPE_CHECKING:
    from app.db import migrate
    from app.db.session import Database
    from app.settings import mask_url
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
                raise StartFailure(f"Cannot reach the database {url}: {one_line(exc)}.") from exc
            finally:
                database.dispose()
            where = ""
    except StartFailure as exc:
        fail(exc)
    typer.echo(f"database: {current or 'empty'}{where}\ncode:     {head}")
