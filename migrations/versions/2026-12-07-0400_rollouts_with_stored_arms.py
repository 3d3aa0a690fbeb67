"""Rollouts of a candidate learner to a share of a fleet's people (``rollouts``), and each
person's arm, stored when assigned (``rollout_arms``).

Two new tables; no existing row changes. A database upgraded from the previous release has no
rollout: every person keeps the learner they have. Downgrading drops both tables (the people
keep the learner they have then).

Revision ID: 2d7c5a9e4f13
Revises: 8b4f2e6a1c90
Create Date: 2026-12-07 04:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "2d7c5a9e4f13"
down_revision: str | None = "8b4f2e6a1c90"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

RUNNING = sa.text("status = 'running'")


def upgrade() -> None:
    op.create_table(
        "rollouts",
        sa.Column("id", sa.String(length=40), nullable=False),
        sa.Column("fleet", sa.String(length=128), nullable=False),
        sa.Column("algorithm", sa.String(length=32), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("share", sa.Float(), nullable=False),
        sa.Column("salt", sa.String(length=32), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("started_by", sa.String(length=40), nullable=False),
        sa.Column("ended_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("ended_by", sa.String(length=40), nullable=True),
        sa.Column("end_reason", sa.String(length=500), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_rollouts")),
    )
    with op.batch_alter_table("rollouts") as batch:
        batch.create_index("ix_rollouts_fleet_started", ["fleet", "started_at"])
        batch.create_index(
            "ux_rollouts_running",
            ["fleet"],
            unique=True,
            sqlite_where=RUNNING,
            postgresql_where=RUNNING,
        )
    op.create_table(
        "rollout_arms",
        sa.Column("rollout_id", sa.String(length=40), nullable=False),
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("arm", sa.String(length=16), nullable=False),
        sa.Column("assigned_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("previous_algorithm", sa.String(length=32), nullable=False),
        sa.Column("previous_params", sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ["rollout_id"],
            ["rollouts.id"],
            name=op.f("fk_rollout_arms_rollout_id_rollouts"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["user_pk"],
            ["users.id"],
            name=op.f("fk_rollout_arms_user_pk_users"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("rollout_id", "user_pk", name=op.f("pk_rollout_arms")),
    )
    with op.batch_alter_table("rollout_arms") as batch:
        batch.create_index("ix_rollout_arms_user", ["user_pk"])


def downgrade() -> None:
    with op.batch_alter_table("rollout_arms") as batch:
        batch.drop_index("ix_rollout_arms_user")
    op.drop_table("rollout_arms")
    with op.batch_alter_table("rollouts") as batch:
        batch.drop_index("ux_rollouts_running")
        batch.drop_index("ix_rollouts_fleet_started")
    op.drop_table("rollouts")
