"""Retention: a fleet's window for raw history (``fleet_settings.history_days``, empty: keep
everything) and ``history_folds``, what a retention run keeps of the episodes it removes (the
profile's walk over them; the model's base moves to the learner at that point).

A new nullable column and a new table: no existing row changes (every fleet keeps everything
until its staff set a window). Downgrading drops both, and with them what runs folded: the
removed episodes stay removed, the models keep their moved bases (a rebuild still replays from
them), but the profiles then speak from the kept episodes only.

Revision ID: 5b8e2f4a9c17
Revises: 7a2c5e8d1f36
Create Date: 2026-12-02 20:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "5b8e2f4a9c17"
down_revision: str | None = "7a2c5e8d1f36"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("fleet_settings") as batch:
        batch.add_column(sa.Column("history_days", sa.Integer(), nullable=True))
    op.create_table(
        "history_folds",
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("upto_seq", sa.Integer(), nullable=False),
        sa.Column("upto_version", sa.Integer(), nullable=False),
        sa.Column("kept_from", sa.DateTime(timezone=True), nullable=False),
        sa.Column("folded_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("doc", sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ["user_pk"],
            ["users.id"],
            name=op.f("fk_history_folds_user_pk_users"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("user_pk", name=op.f("pk_history_folds")),
    )


def downgrade() -> None:
    op.drop_table("history_folds")
    with op.batch_alter_table("fleet_settings") as batch:
        batch.drop_column("history_days")
