"""Leases: ``leases``, one row per job that one process of the deployment runs at a time (the
retention run, started by the service at ``ATTUNE_RETENTION_AT`` or by ``attune retention
run``): who holds it, since when and until when.

A new table only: no existing row changes. Downgrading drops it; a run in progress then holds
nothing, so only downgrade with the service and the retention runs stopped.

Revision ID: 9c4e7a2b6d15
Revises: 5b8e2f4a9c17
Create Date: 2026-12-03 09:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "9c4e7a2b6d15"
down_revision: str | None = "5b8e2f4a9c17"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "leases",
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("holder", sa.String(length=200), nullable=False),
        sa.Column("acquired_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("expires_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("name", name=op.f("pk_leases")),
    )


def downgrade() -> None:
    op.drop_table("leases")
