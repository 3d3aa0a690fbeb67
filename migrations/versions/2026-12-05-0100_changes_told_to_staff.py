"""Changes in what people want, told to staff: ``context_beliefs`` (each context's walk of
the profile's belief as episodes end) and ``change_events`` (the changes it decided: when,
which context, before and now, on what evidence).

Two new tables; no existing row changes. A database upgraded from the previous release starts
with no walks and no changes: each context's walk begins with the next episode that ends there
(its earlier episodes are not weighed again). Downgrading drops both tables.

Revision ID: 6e1a9d3c5b72
Revises: 3c9d4e7f2a18
Create Date: 2026-12-05 01:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "6e1a9d3c5b72"
down_revision: str | None = "3c9d4e7f2a18"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "context_beliefs",
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("time_slot", sa.String(length=64), nullable=False),
        sa.Column("situation", sa.String(length=64), nullable=False),
        sa.Column("upto_seq", sa.Integer(), nullable=False),
        sa.Column("doc", sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ["user_pk"],
            ["users.id"],
            name=op.f("fk_context_beliefs_user_pk_users"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint(
            "user_pk", "time_slot", "situation", name=op.f("pk_context_beliefs")
        ),
    )
    op.create_table(
        "change_events",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("fleet", sa.String(length=128), nullable=False),
        sa.Column("source", sa.String(length=16), nullable=False),
        sa.Column("time_slot", sa.String(length=64), nullable=False),
        sa.Column("situation", sa.String(length=64), nullable=False),
        sa.Column("seq", sa.Integer(), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("utc_offset", sa.Integer(), nullable=True),
        sa.Column("detected_seq", sa.Integer(), nullable=False),
        sa.Column("detected_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("before_service", sa.String(length=64), nullable=True),
        sa.Column("before_detail", sa.String(length=64), nullable=True),
        sa.Column("now_service", sa.String(length=64), nullable=True),
        sa.Column("now_detail", sa.String(length=64), nullable=True),
        sa.Column("evidence", sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ["user_pk"],
            ["users.id"],
            name=op.f("fk_change_events_user_pk_users"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_change_events")),
    )
    with op.batch_alter_table("change_events") as batch:
        batch.create_index("ix_change_events_user_id", ["user_pk", "id"])
        batch.create_index("ix_change_events_fleet_detected", ["fleet", "detected_at"])


def downgrade() -> None:
    with op.batch_alter_table("change_events") as batch:
        batch.drop_index("ix_change_events_fleet_detected")
        batch.drop_index("ix_change_events_user_id")
    op.drop_table("change_events")
    op.drop_table("context_beliefs")
