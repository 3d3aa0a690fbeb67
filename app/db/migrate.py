"""Running the Alembic migrations from the service and the command line.

The migration scripts live in ``migrations/`` at the top of a source checkout and ship inside
the installed package as ``app/migrations`` (the wheel's build maps one onto the other), so an
installed ``attune`` finds them wherever it runs from. The configuration is built here; the
repository's ``alembic.ini`` serves developers who call ``alembic`` directly.
"""

from __future__ import annotations

import functools
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from pydantic import SecretStr
from sqlalchemy import Engine, create_engine
from sqlalchemy.pool import NullPool

from . import encryption

__all__ = [
    "MigrationsMissing",
    "alembic_config",
    "current_revision",
    "head_revision",
    "is_current",
    "script_location",
    "upgrade",
]

_PACKAGE = Path(__file__).resolve().parents[1]  # app/


class MigrationsMissing(RuntimeError):
    """The migration scripts are not where an installed or checked-out Attune keeps them."""


def script_location() -> Path:
    """The folder of the migration scripts: inside the installed package, else the checkout's."""
    for folder in (_PACKAGE / "migrations", _PACKAGE.parent / "migrations"):
        if (folder / "env.py").is_file() and (folder / "versions").is_dir():
            return folder
    raise MigrationsMissing(
        f"The database migrations are missing: neither {_PACKAGE / 'migrations'} nor "
        f"{_PACKAGE.parent / 'migrations'} holds them; reinstall Attune."
    )


def alembic_config(url: str) -> Config:
    cfg = Config()
    cfg.set_main_option("script_location", str(script_location()))
    cfg.set_main_option("path_separator", "os")
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    cfg.attributes["configure_logging"] = False
    return cfg


@functools.lru_cache
def head_revision() -> str | None:
    return ScriptDirectory.from_config(alembic_config("sqlite://")).get_current_head()


def current_revision(engine: Engine) -> str | None:
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def is_current(engine: Engine) -> bool:
    return current_revision(engine) == head_revision()


def upgrade(url: str, revision: str = "head", key: SecretStr | None = None) -> None:
    """Migrate the database of ``url`` to ``revision``. ``key``: an encrypted SQLite file's;
    the migrations then run on a connection given the key (the URL never holds it)."""
    cfg = alembic_config(url)
    if key is None:
        command.upgrade(cfg, revision)
        return
    engine = create_engine(url, poolclass=NullPool, module=encryption.driver())
    encryption.apply_key(engine, key)
    try:
        with engine.connect() as connection:
            cfg.attributes["connection"] = connection
            command.upgrade(cfg, revision)
    finally:
        engine.dispose()
