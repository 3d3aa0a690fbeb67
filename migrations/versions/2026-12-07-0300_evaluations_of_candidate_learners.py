"""Evaluations of candidate learners as background jobs (``evaluations``): what was asked, by
whom, how far it got, and its result.

One new table; no existing row changes. A database upgraded from the previous release has no
evaluation yet. Downgrading drops the table (the results with it: they can be run again from the
logs, which stay).

Revision ID: 8b4f2e6a1c90
Revises: 6e1a9d3c5b72
Create Date: 2026-12-07 03:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "8b4f2e6a1c90"
down_revision: str | None = "6e1a9d3c5b72"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

ACTIVE = sa.text("status IN ('queued', 'running')")


def upgrade() -> None:
    op.create_table(
        "evaluations",
        sa.Column("id", sa.String(length=40), nullable=False),
        sa.Column("fleet", sa.String(length=128), nullable=False),
        sa.Column("request_id", sa.String(length=128), nullable=False),
        sa.Column("request_hash", sa.String(length=64), nullable=False),
        sa.Column("request", sa.JSON(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("actor_key_id", sa.String(length=40), nullable=False),
        sa.Column("actor_role", sa.String(length=16), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("holder", sa.String(length=200), nullable=True),
        sa.Column("done_people", sa.Integer(), nullable=False),
        sa.Column("total_people", sa.Integer(), nullable=True),
        sa.Column("cancel_requested", sa.Boolean(), nullable=False),
        sa.Column("error", sa.String(length=2000), nullable=True),
        sa.Column("result", sa.JSON(), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_evaluations")),
        sa.UniqueConstraint("fleet", "request_id", name="uq_evaluations_fleet_request"),
    )
    with op.batch_alter_table("evaluations") as batch:
        batch.create_index("ix_evaluations_fleet_created", ["fleet", "created_at"])
        batch.create_index(
            "ux_evaluations_active",
            ["fleet"],
            unique=True,
            sqlite_where=ACTIVE,
            postgresql_where=ACTIVE,
        )


def downgrade() -> None:
    with op.batch_alter_table("evaluations") as batch:
        batch.drop_index("ux_evaluations_active")
        batch.drop_index("ix_evaluations_fleet_created")
    op.drop_table("evaluations")
