"""Erasing a person: the audit log's entries about them keep who did what and when, and lose
what they said of the person; a user's number is never given to anyone else.

The audit log stays append only, with one exception the database itself checks: an entry's
``detail`` may be replaced by ``{"erased": true}``, every other column unchanged, once no user
of the entry's fleet has the entry's target as their id (the person was erased in the same
transaction, just before). Every other UPDATE, and every DELETE, is refused as before.

SQLite: ``users`` is rebuilt with ``AUTOINCREMENT``, so that the number of an erased user (the
key of their learner in each worker's cache, and of every row that was theirs) is never taken
by the next user made; before, SQLite gave the highest number again once its user was deleted.
PostgreSQL's sequence never did.

Downgrading restores the strict triggers (entries already redacted stay redacted) and, on
SQLite, the table without ``AUTOINCREMENT``.

Revision ID: 3e9d41c7a5b2
Revises: 8c4f1a7e2b93
Create Date: 2026-12-02 17:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = "3e9d41c7a5b2"
down_revision: str | None = "8c4f1a7e2b93"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_MESSAGE = "audit_log entries are append only: they are never changed or removed"
_UNCHANGED = ("id", "at", "actor_key_id", "actor_role", "actor_fleet", "action", "target", "fleet")


def _postgresql() -> bool:
    return op.get_bind().dialect.name == "postgresql"


def _refuse_with_foreign_keys_on() -> None:
    """SQLite rebuilds ``users`` by dropping it: with foreign keys enforced, the drop would
    delete every row that refers to a user. The migrations' own connections do not enforce
    them; a connection handed in that does is refused before anything changes."""
    if op.get_bind().exec_driver_sql("PRAGMA foreign_keys").scalar():
        raise RuntimeError(
            "This migration rebuilds the users table: run it on a SQLite connection without "
            "PRAGMA foreign_keys=ON (attune db upgrade does)."
        )


def upgrade() -> None:
    if _postgresql():
        same = " AND ".join(f"NEW.{c} IS NOT DISTINCT FROM OLD.{c}" for c in _UNCHANGED)
        op.execute(f"""
            CREATE OR REPLACE FUNCTION audit_log_append_only() RETURNS trigger
            LANGUAGE plpgsql AS $$
            BEGIN
                IF TG_OP = 'UPDATE'
                   AND NEW.detail IS NOT NULL
                   AND NEW.detail::jsonb = '{{"erased": true}}'::jsonb
                   AND {same}
                   AND NOT EXISTS (
                       SELECT 1 FROM users
                       WHERE users.fleet = OLD.fleet AND users.user_id = OLD.target)
                THEN
                    RETURN NEW;
                END IF;
                RAISE EXCEPTION '{_MESSAGE}';
            END $$""")
        return
    _refuse_with_foreign_keys_on()
    # The new trigger reads users: made once the table is rebuilt (a rename checks triggers).
    op.execute("DROP TRIGGER audit_log_no_update")
    with op.batch_alter_table(
        "users", recreate="always", table_kwargs={"sqlite_autoincrement": True}
    ):
        pass
    same = " AND ".join(f"NEW.{c} IS OLD.{c}" for c in _UNCHANGED)
    op.execute(f"""
        CREATE TRIGGER audit_log_no_update BEFORE UPDATE ON audit_log
        WHEN NOT (
            json(NEW.detail) IS json('{{"erased": true}}')
            AND {same}
            AND NOT EXISTS (
                SELECT 1 FROM users
                WHERE users.fleet = OLD.fleet AND users.user_id = OLD.target))
        BEGIN SELECT RAISE(ABORT, '{_MESSAGE}'); END""")


def downgrade() -> None:
    if _postgresql():
        op.execute(f"""
            CREATE OR REPLACE FUNCTION audit_log_append_only() RETURNS trigger
            LANGUAGE plpgsql AS $$
            BEGIN
                RAISE EXCEPTION '{_MESSAGE}';
            END $$""")
        return
    _refuse_with_foreign_keys_on()
    op.execute("DROP TRIGGER audit_log_no_update")
    with op.batch_alter_table(
        "users", recreate="always", table_kwargs={"sqlite_autoincrement": False}
    ) as batch:
        # The key gets its name back (AUTOINCREMENT's key is the column's own, unnamed): the
        # earlier revisions' downgrades find it by name.
        batch.create_primary_key("pk_users", ["id"])
    op.execute(f"""
        CREATE TRIGGER audit_log_no_update BEFORE UPDATE ON audit_log
        BEGIN SELECT RAISE(ABORT, '{_MESSAGE}'); END""")
