"""Safe rollout of a candidate learner: shadows that decide beside a fleet's learners without
acting (``shadows``, and their decisions, ``shadow_decisions``), rollouts to a share of a
fleet's people (``rollouts``), and each person's arm, stored when assigned (``rollout_arms``).

Four new tables, and an index of the episodes by the time they closed (what the shadows' pass
looks for); no existing row changes. A database upgraded from the previous release has no
shadow and no rollout: every person keeps the learner they have. Downgrading drops the four
tables (the people keep the learner they have then).

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
        sa.Column("pending", sa.Boolean(), nullable=False),
        sa.Column("served_since", sa.DateTime(timezone=True), nullable=True),
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
        batch.create_index("ix_rollout_arms_pending", ["pending"])
    op.create_table(
        "shadows",
        sa.Column("id", sa.String(length=40), nullable=False),
        sa.Column("fleet", sa.String(length=128), nullable=False),
        sa.Column("algorithm", sa.String(length=32), nullable=False),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("share", sa.Float(), nullable=False),
        sa.Column("salt", sa.String(length=32), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("started_by", sa.String(length=40), nullable=False),
        sa.Column("stopped_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("stopped_by", sa.String(length=40), nullable=True),
        sa.Column("checked_until", sa.DateTime(timezone=True), nullable=False),
        sa.Column("estimate", sa.JSON(), nullable=True),
        sa.Column("estimated_at", sa.DateTime(timezone=True), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_shadows")),
    )
    with op.batch_alter_table("shadows") as batch:
        batch.create_index("ix_shadows_fleet_started", ["fleet", "started_at"])
        batch.create_index(
            "ux_shadows_running",
            ["fleet"],
            unique=True,
            sqlite_where=RUNNING,
            postgresql_where=RUNNING,
        )
    op.create_table(
        "shadow_decisions",
        sa.Column("decision_id", sa.String(length=40), nullable=False),
        sa.Column("shadow_id", sa.String(length=40), nullable=False),
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("decided_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("state", sa.Integer(), nullable=False),
        sa.Column("action", sa.Integer(), nullable=False),
        sa.Column("probabilities", sa.JSON(), nullable=False),
        sa.Column("logged_action", sa.Integer(), nullable=False),
        sa.Column("logged_probability", sa.Float(), nullable=False),
        sa.Column("agrees", sa.Boolean(), nullable=False),
        sa.ForeignKeyConstraint(
            ["decision_id"],
            ["decisions.id"],
            name=op.f("fk_shadow_decisions_decision_id_decisions"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["shadow_id"],
            ["shadows.id"],
            name=op.f("fk_shadow_decisions_shadow_id_shadows"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["user_pk"],
            ["users.id"],
            name=op.f("fk_shadow_decisions_user_pk_users"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("decision_id", "shadow_id", name=op.f("pk_shadow_decisions")),
    )
    with op.batch_alter_table("shadow_decisions") as batch:
        batch.create_index("ix_shadow_decisions_shadow_at", ["shadow_id", "decided_at"])
    # The shadows' pass finds the people with an episode closed since its last pass by it.
    op.create_index("ix_episodes_closed_at", "episodes", ["closed_at"])


def downgrade() -> None:
    op.drop_index("ix_episodes_closed_at", table_name="episodes")
    with op.batch_alter_table("shadow_decisions") as batch:
        batch.drop_index("ix_shadow_decisions_shadow_at")
    op.drop_table("shadow_decisions")
    with op.batch_alter_table("shadows") as batch:
        batch.drop_index("ux_shadows_running")
        batch.drop_index("ix_shadows_fleet_started")
    op.drop_table("shadows")
    with op.batch_alter_table("rollout_arms") as batch:
        batch.drop_index("ix_rollout_arms_pending")
        batch.drop_index("ix_rollout_arms_user")
    op.drop_table("rollout_arms")
    with op.batch_alter_table("rollouts") as batch:
        batch.drop_index("ux_rollouts_running")
        batch.drop_index("ix_rollouts_fleet_started")
    op.drop_table("rollouts")
