"""Staff corrections and local times: a ``corrections`` table (the staff's corrections of what
was learned about a user, part of the user's history), and ``episodes.utc_offset``, the offset
each event's time came with, so that times are shown in the person's local time.

Episodes stored before this revision keep ``utc_offset`` NULL (shown in UTC). Downgrading drops
both; it refuses while corrections exist, since their journal entries would no longer replay.

Revision ID: 5b7d2e9a1c08
Revises: 3e8a6d0c4f17
Create Date: 2026-11-30 18:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "5b7d2e9a1c08"
down_revision: str | None = "3e8a6d0c4f17"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "corrections",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("user_pk", sa.Integer(), nullable=False),
        sa.Column("correction_id", sa.String(length=128), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("time_slot", sa.String(length=64), nullable=False),
        sa.Column("situation", sa.String(length=64), nullable=False),
        sa.Column("service", sa.String(length=64), nullable=True),
        sa.Column("detail", sa.String(length=64), nullable=True),
        sa.Column("note", sa.String(length=500), nullable=True),
        sa.Column("actor_key_id", sa.String(length=40), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("model_version", sa.Integer(), nullable=False),
        sa.Column("lifted_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("lifted_by", sa.String(length=40), nullable=True),
        sa.Column("request_hash", sa.String(length=64), nullable=False),
        sa.Column("response", sa.JSON(), nullable=False),
        sa.ForeignKeyConstraint(
            ["user_pk"], ["users.id"], name=op.f("fk_corrections_user_pk_users"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_corrections")),
        sa.UniqueConstraint(
            "user_pk", "correction_id", name=op.f("uq_corrections_user_pk_correction_id")
        ),
    )
    with op.batch_alter_table("episodes") as batch:
        batch.add_column(sa.Column("utc_offset", sa.Integer(), nullable=True))


def downgrade() -> None:
    bind = op.get_bind()
    made = bind.execute(sa.text("SELECT COUNT(*) FROM corrections")).scalar_one()
    if made:
        raise RuntimeError(
            f"{made} staff corrections are stored; the previous revision cannot replay them. "
            "Export the models you need, delete the corrections' users or keep this revision."
        )
    with op.batch_alter_table("episodes") as batch:
        batch.drop_column("utc_offset")
    op.drop_table("corrections")
