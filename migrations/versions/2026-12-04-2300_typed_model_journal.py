"""The model's journal as typed entries: ``samples`` becomes ``journal``, where every column
means one thing for every kind of entry that has it.

In ``samples`` a staff correction's row id sat in ``action`` and the learner's episode count in
``episode``, and a move to another mission version filled the step's columns with zeros. In
``journal``:

- a transition keeps every column as it was; feedback too (its ``next_state`` and ``signal``,
  which feedback never had, are empty);
- a correction or a lift has its correction's row in ``correction_pk`` (a foreign key now) and
  the learner's episode count in ``since``; its ``context`` stays; the step's columns are empty;
- a move to another mission version keeps ``mission_version`` only;
- three new kinds mark where a model started over (``reset``, ``import``) and where a
  retention run folded the journal (``fold``), with ``detail`` saying who and how. They are
  written from now on; nothing earlier is made up.

Every row is copied (same ids, same order), so a model rebuilds from its base exactly as before.
Downgrading copies the rows back into ``samples`` in their old form (zeros where the columns are
empty now, the correction's row id in ``action``, the episode count in ``episode``); the entries
of the new kinds have no place there and are dropped (a model's base stays where they put it).

Revision ID: 3c9d4e7f2a18
Revises: 9c4e7a2b6d15
Create Date: 2026-12-04 23:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "3c9d4e7f2a18"
down_revision: str | None = "9c4e7a2b6d15"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

TAUGHT = "('transition', 'feedback')"
CORRECTIONS = "('correction', 'lift')"


def _postgresql() -> bool:
    return op.get_bind().dialect.name == "postgresql"


def _reset_sequence(table: str) -> None:
    """Explicit ids were copied: the next id of ``table`` comes after them (PostgreSQL)."""
    if _postgresql():
        op.execute(
            f"SELECT setval(pg_get_serial_sequence('{table}', 'id'), "
            f"COALESCE((SELECT MAX(id) FROM {table}), 0) + 1, false)"
        )


def upgrade() -> None:
    op.create_table(
        "journal",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("mission_version", sa.Integer(), nullable=False),
        sa.Column("episode", sa.Integer(), nullable=True),
        sa.Column("context", sa.Integer(), nullable=True),
        sa.Column("state", sa.Integer(), nullable=True),
        sa.Column("action", sa.Integer(), nullable=True),
        sa.Column("reward", sa.Float(), nullable=True),
        sa.Column("next_state", sa.Integer(), nullable=True),
        sa.Column("signal", sa.Integer(), nullable=True),
        sa.Column("correction_pk", sa.Integer(), nullable=True),
        sa.Column("since", sa.Integer(), nullable=True),
        sa.Column("detail", sa.JSON(), nullable=True),
        sa.ForeignKeyConstraint(
            ["correction_pk"],
            ["corrections.id"],
            name=op.f("fk_journal_correction_pk_corrections"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["user_pk"], ["users.id"], name=op.f("fk_journal_user_pk_users"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_journal")),
    )
    op.execute(
        f"""
        INSERT INTO journal (id, user_pk, version, kind, mission_version, episode, context,
                             state, action, reward, next_state, signal, correction_pk, since)
        SELECT id, user_pk, version, kind, mission_version,
               CASE WHEN kind IN {TAUGHT} THEN episode END,
               CASE WHEN kind IN {TAUGHT} OR kind IN {CORRECTIONS} THEN context END,
               CASE WHEN kind IN {TAUGHT} THEN state END,
               CASE WHEN kind IN {TAUGHT} THEN action END,
               CASE WHEN kind IN {TAUGHT} THEN reward END,
               CASE WHEN kind = 'transition' THEN next_state END,
               CASE WHEN kind = 'transition' THEN signal END,
               CASE WHEN kind IN {CORRECTIONS} THEN action END,
               CASE WHEN kind IN {CORRECTIONS} THEN episode END
        FROM samples
        """
    )
    _reset_sequence("journal")
    with op.batch_alter_table("journal") as batch:
        batch.create_index("ix_journal_user_version", ["user_pk", "version"])
        batch.create_index("ix_journal_user_episode", ["user_pk", "episode"])
    with op.batch_alter_table("samples") as batch:
        batch.drop_index("ix_samples_user_version")
        batch.drop_index("ix_samples_user_episode")
    op.drop_table("samples")


def downgrade() -> None:
    op.create_table(
        "samples",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("episode", sa.Integer(), nullable=False),
        sa.Column("context", sa.Integer(), nullable=False),
        sa.Column("state", sa.Integer(), nullable=False),
        sa.Column("action", sa.Integer(), nullable=False),
        sa.Column("reward", sa.Float(), nullable=False),
        sa.Column("next_state", sa.Integer(), nullable=True),
        sa.Column("signal", sa.Integer(), nullable=False),
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("mission_version", sa.Integer(), server_default="1", nullable=False),
        sa.ForeignKeyConstraint(
            ["user_pk"], ["users.id"], name=op.f("fk_samples_user_pk_users"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_samples")),
    )
    op.execute(
        f"""
        INSERT INTO samples (id, version, kind, episode, context, state, action, reward,
                             next_state, signal, user_pk, mission_version)
        SELECT id, version, kind,
               CASE WHEN kind IN {CORRECTIONS} THEN since ELSE COALESCE(episode, 0) END,
               COALESCE(context, 0),
               COALESCE(state, 0),
               CASE WHEN kind IN {CORRECTIONS} THEN correction_pk ELSE COALESCE(action, 0) END,
               COALESCE(reward, 0.0),
               next_state,
               COALESCE(signal, 0),
               user_pk, mission_version
        FROM journal
        WHERE kind NOT IN ('reset', 'import', 'fold')
        """
    )
    _reset_sequence("samples")
    with op.batch_alter_table("samples") as batch:
        batch.create_index("ix_samples_user_version", ["user_pk", "version"])
        batch.create_index("ix_samples_user_episode", ["user_pk", "episode"])
    with op.batch_alter_table("journal") as batch:
        batch.drop_index("ix_journal_user_version")
        batch.drop_index("ix_journal_user_episode")
    op.drop_table("journal")
