"""Who looked at a person: ``data_views``, one row per read of a person's data by staff or an
admin (the API's reads of the person, their model, statistics, profile, corrections, episodes
and export, and the console's pages of them), erased with the person.

A new table only: no existing row changes. Downgrading drops it, and what it recorded.

Revision ID: 7a2c5e8d1f36
Revises: 3e9d41c7a5b2
Create Date: 2026-12-02 18:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "7a2c5e8d1f36"
down_revision: str | None = "3e9d41c7a5b2"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "data_views",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("fleet", sa.String(length=128), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("actor_key_id", sa.String(length=40), nullable=False),
        sa.Column("actor_role", sa.String(length=16), nullable=False),
        sa.Column("actor_fleet", sa.String(length=128), nullable=False),
        sa.Column("what", sa.String(length=32), nullable=False),
        sa.Column("via", sa.String(length=8), nullable=False),
        sa.ForeignKeyConstraint(
            ["user_pk"],
            ["users.id"],
            name=op.f("fk_data_views_user_pk_users"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_data_views")),
    )
    op.create_index("ix_data_views_user_id", "data_views", ["user_pk", "id"])
    op.create_index("ix_data_views_fleet_id", "data_views", ["fleet", "id"])
    op.create_index("ix_data_views_fleet_at", "data_views", ["fleet", "at"])


def downgrade() -> None:
    op.drop_index("ix_data_views_fleet_at", table_name="data_views")
    op.drop_index("ix_data_views_fleet_id", table_name="data_views")
    op.drop_index("ix_data_views_user_id", table_name="data_views")
    op.drop_table("data_views")
