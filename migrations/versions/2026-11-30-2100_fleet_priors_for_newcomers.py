"""A fleet's prior for newcomers: ``users.fleet_prior`` (whether the person starts from and adds
to the fleet's prior), ``learner_models.base_origin`` and ``base_contributors`` (where a model's
base came from: a fresh learner, an imported document or the fleet's prior, and how many people
the prior averaged), and ``fleet_settings`` (a fleet's own switch for its prior).

Existing users keep taking part (``fleet_prior`` true); existing models are ``imported`` where
they have a base document and ``fresh`` otherwise. Downgrading drops all of it; it refuses while
a model grew from a fleet's prior, since the previous revision would call that base an import.

Revision ID: 8c4f1a7e2b93
Revises: 5b7d2e9a1c08
Create Date: 2026-11-30 21:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "8c4f1a7e2b93"
down_revision: str | None = "5b7d2e9a1c08"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "fleet_settings",
        sa.Column("fleet", sa.String(length=128), nullable=False),
        sa.Column("prior_enabled", sa.Boolean(), nullable=False),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("updated_by", sa.String(length=40), nullable=True),
        sa.PrimaryKeyConstraint("fleet", name=op.f("pk_fleet_settings")),
    )
    with op.batch_alter_table("users") as batch:
        batch.add_column(
            sa.Column("fleet_prior", sa.Boolean(), nullable=False, server_default=sa.true())
        )
    with op.batch_alter_table("learner_models") as batch:
        batch.add_column(
            sa.Column("base_origin", sa.String(length=16), nullable=False, server_default="fresh")
        )
        batch.add_column(sa.Column("base_contributors", sa.Integer(), nullable=True))
    op.execute("UPDATE learner_models SET base_origin = 'imported' WHERE base_state IS NOT NULL")


def downgrade() -> None:
    bind = op.get_bind()
    grown = bind.execute(
        sa.text("SELECT COUNT(*) FROM learner_models WHERE base_origin = 'fleet_prior'")
    ).scalar_one()
    if grown:
        raise RuntimeError(
            f"{grown} models started from their fleet's prior; the previous revision would take "
            "that base for an imported model. Reset those models or keep this revision."
        )
    with op.batch_alter_table("learner_models") as batch:
        batch.drop_column("base_contributors")
        batch.drop_column("base_origin")
    with op.batch_alter_table("users") as batch:
        batch.drop_column("fleet_prior")
    op.drop_table("fleet_settings")
