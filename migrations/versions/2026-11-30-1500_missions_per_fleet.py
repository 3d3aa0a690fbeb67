"""Missions per fleet: each fleet's mission is stored, versioned, and every model, episode and
journal entry records the mission version it belongs to.

Until now a deployment had one mission (``ATTUNE_MISSION_PATH``, or the built-in office
mission), read at start. This revision stores that mission as version 1 of every fleet that
has users, so that nothing changes for them; every model, episode and sample is marked as
belonging to version 1. It first checks that every stored model was learned for that mission
(the deployment must run this upgrade with the ``ATTUNE_MISSION_PATH`` it serves with) and
says which fleets' models were not.

Downgrading works while no fleet has changed its mission (it names those that have).

Revision ID: 3e8a6d0c4f17
Revises: 9c1f4e7a2b65
Create Date: 2026-11-30 15:00:00+00:00
"""

from __future__ import annotations

import datetime as dt
import os
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

from app.db.types import LearnerStateType
from app.learning import load_mission, office_mission

revision: str = "3e8a6d0c4f17"
down_revision: str | None = "9c1f4e7a2b65"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

VERSIONED = ("learner_models", "episodes", "samples")


def upgrade() -> None:
    path = os.environ.get("ATTUNE_MISSION_PATH")
    mission = load_mission(path) if path else office_mission()
    bind = op.get_bind()

    # Every stored model must have been learned for the deployment's mission.
    models = sa.table(
        "learner_models", sa.column("user_pk", sa.Integer()), sa.column("state", LearnerStateType())
    )
    users = sa.table("users", sa.column("id", sa.Integer()), sa.column("fleet", sa.String()))
    wrong: dict[str, int] = {}
    for fleet, state in bind.execute(
        sa.select(users.c.fleet, models.c.state).join(models, models.c.user_pk == users.c.id)
    ):
        meta = state.get("mission") if isinstance(state, dict) else None
        if not isinstance(meta, dict) or meta.get("fingerprint") != mission.fingerprint:
            wrong[fleet] = wrong.get(fleet, 0) + 1
    if wrong:
        listed = ", ".join(f"{fleet} ({n})" for fleet, n in sorted(wrong.items())[:5])
        raise RuntimeError(
            f"{sum(wrong.values())} models were learned for another mission than "
            f"{mission.name!r} ({'ATTUNE_MISSION_PATH=' + path if path else 'the built-in'}): "
            f"{listed}. Run the upgrade with the ATTUNE_MISSION_PATH the service runs with."
        )

    table = op.create_table(
        "fleet_missions",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("fleet", sa.String(length=128), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("fingerprint", sa.String(length=80), nullable=False),
        sa.Column("document", sa.JSON(), nullable=False),
        sa.Column("renames", sa.JSON(), nullable=True),
        sa.Column("change_id", sa.String(length=128), nullable=True),
        sa.Column("request_hash", sa.String(length=64), nullable=True),
        sa.Column("response", sa.JSON(), nullable=True),
        sa.Column("actor_key_id", sa.String(length=40), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_fleet_missions")),
        sa.UniqueConstraint("fleet", "version", name=op.f("uq_fleet_missions_fleet_version")),
        sa.UniqueConstraint("fleet", "change_id", name=op.f("uq_fleet_missions_fleet_change_id")),
    )
    fleets = bind.execute(sa.text("SELECT DISTINCT fleet FROM users ORDER BY fleet")).scalars()
    now = dt.datetime.now(dt.UTC)
    op.bulk_insert(
        table,
        [
            {
                "fleet": fleet,
                "version": 1,
                "name": mission.name,
                "fingerprint": mission.fingerprint,
                "document": mission.to_dict(),
                "renames": None,
                "change_id": None,
                "request_hash": None,
                "response": None,
                "actor_key_id": None,
                "created_at": now,
            }
            for fleet in fleets
        ],
    )

    for name in VERSIONED:
        with op.batch_alter_table(name) as batch:
            batch.add_column(
                sa.Column("mission_version", sa.Integer(), nullable=False, server_default="1")
            )
    with op.batch_alter_table("learner_models") as batch:
        batch.add_column(
            sa.Column("base_mission_version", sa.Integer(), nullable=False, server_default="1")
        )


def downgrade() -> None:
    changed = (
        op.get_bind()
        .execute(
            sa.text("SELECT DISTINCT fleet FROM fleet_missions WHERE version > 1 ORDER BY fleet")
        )
        .scalars()
        .all()
    )
    if changed:
        raise RuntimeError(
            f"{len(changed)} fleets changed their missions ({', '.join(changed[:5])}"
            f"{', ...' if len(changed) > 5 else ''}); before this revision a deployment had one "
            "mission. Downgrading would lose which version each model and episode belongs to."
        )
    with op.batch_alter_table("learner_models") as batch:
        batch.drop_column("base_mission_version")
    for name in VERSIONED:
        with op.batch_alter_table(name) as batch:
            batch.drop_column("mission_version")
    op.drop_table("fleet_missions")
