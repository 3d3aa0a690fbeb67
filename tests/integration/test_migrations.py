"""The migrations build the schema the models describe, on both engines, and go down again."""

from __future__ import annotations

from alembic import command
from sqlalchemy import create_engine, inspect

from app.db import migrate
from app.db.base import Base
from app.db.session import Database
from app.settings import Settings


def _tables(url: str) -> set[str]:
    engine = create_engine(url)
    try:
        return set(inspect(engine).get_table_names()) - {"alembic_version"}
    finally:
        engine.dispose()


def test_upgrade_check_downgrade_upgrade(database_url: str, empty_tables: None) -> None:
    cfg = migrate.alembic_config(database_url)
    command.check(cfg)  # raises if the models and the migrated schema differ
    assert _tables(database_url) == set(Base.metadata.tables)
    command.downgrade(cfg, "base")
    assert _tables(database_url) == set()
    database = Database(Settings(database_url=database_url, _env_file=None))  # type: ignore[call-arg]
    try:
        assert not migrate.is_current(database.engine)
    finally:
        database.dispose()
    migrate.upgrade(database_url)
    assert _tables(database_url) == set(Base.metadata.tables)
    engine = create_engine(database_url)
    try:
        assert migrate.current_revision(engine) == migrate.head_revision()
    finally:
        engine.dispose()
