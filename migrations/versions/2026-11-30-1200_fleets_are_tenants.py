"""Fleets are tenants: a user is (fleet, user id), and the deployment numbers its users.

Before, ``users.user_id`` was the key of the whole deployment. Now two fleets may both have a
``lin``: ``users`` gets an integer ``id`` (its primary key) and a unique (``fleet``,
``user_id``), and the tables that belong to a user (``learner_models``, ``episodes``,
``samples``) point at ``users.id`` (``user_pk``) instead of the user id.

Every existing user keeps its decision seeds: ``users.seed_key`` (what a user's decisions are
seeded by, beside the deployment seed and the decision's position) is set to the user id, which
is what seeded them so far; users made from now on get ``fleet/user_id``.

Downgrading works while user ids are still unique across fleets (it says which are not).

Revision ID: 9c1f4e7a2b65
Revises: 5b7e1c2d9a40
Create Date: 2026-11-30 12:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "9c1f4e7a2b65"
down_revision: str | None = "5b7e1c2d9a40"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

CHILDREN = ("learner_models", "episodes", "samples")


def _postgresql() -> bool:
    return op.get_bind().dialect.name == "postgresql"


def upgrade() -> None:
    # 1. Number the users; the seeds of the users there are stay their user ids.
    with op.batch_alter_table("users") as batch:
        batch.add_column(sa.Column("id", sa.Integer(), nullable=True))
        batch.add_column(sa.Column("seed_key", sa.String(length=257), nullable=True))
    if _postgresql():
        op.execute("""
            UPDATE users SET id = numbered.n FROM (
                SELECT user_id, row_number() OVER (ORDER BY user_id) AS n FROM users) AS numbered
            WHERE users.user_id = numbered.user_id""")
    else:
        op.execute("UPDATE users SET id = rowid")  # distinct integers, in one pass
    op.execute("UPDATE users SET seed_key = user_id")

    # 2. Each user's rows point at its number.
    for table in CHILDREN:
        with op.batch_alter_table(table) as batch:
            batch.add_column(sa.Column("user_pk", sa.Integer(), nullable=True))
        op.execute(
            f"UPDATE {table} SET user_pk = "
            f"(SELECT users.id FROM users WHERE users.user_id = {table}.user_id)"
        )

    # 3. Let go of the old key: the children's foreign keys, keys and indexes on user_id.
    with op.batch_alter_table("learner_models") as batch:
        batch.drop_constraint("fk_learner_models_user_id_users", type_="foreignkey")
        batch.drop_constraint("pk_learner_models", type_="primary")
    with op.batch_alter_table("episodes") as batch:
        batch.drop_constraint("fk_episodes_user_id_users", type_="foreignkey")
        batch.drop_constraint("uq_episodes_user_id_event_id", type_="unique")
        batch.drop_constraint("uq_episodes_user_id_seq", type_="unique")
    with op.batch_alter_table("samples") as batch:
        batch.drop_constraint("fk_samples_user_id_users", type_="foreignkey")
        batch.drop_index("ix_samples_user_version")
        batch.drop_index("ix_samples_user_episode")

    # 4. The users' new key: id; a user id is unique within its fleet.
    with op.batch_alter_table("users") as batch:
        batch.drop_index("ix_users_fleet")
        batch.drop_constraint("pk_users", type_="primary")
        batch.alter_column("id", existing_type=sa.Integer(), nullable=False)
        batch.alter_column("seed_key", existing_type=sa.String(length=257), nullable=False)
        batch.create_primary_key("pk_users", ["id"])
        batch.create_unique_constraint("uq_users_fleet_user_id", ["fleet", "user_id"])
    if _postgresql():  # new users are numbered by a sequence, after the ones there are
        op.execute("CREATE SEQUENCE users_id_seq OWNED BY users.id")
        op.execute("ALTER TABLE users ALTER COLUMN id SET DEFAULT nextval('users_id_seq')")
        op.execute(
            "SELECT setval('users_id_seq', COALESCE((SELECT max(id) FROM users), 0) + 1, false)"
        )

    # 5. The children on the new key.
    with op.batch_alter_table("learner_models") as batch:
        batch.alter_column("user_pk", existing_type=sa.Integer(), nullable=False)
        batch.drop_column("user_id")
        batch.create_primary_key("pk_learner_models", ["user_pk"])
        batch.create_foreign_key(
            "fk_learner_models_user_pk_users", "users", ["user_pk"], ["id"], ondelete="CASCADE"
        )
    with op.batch_alter_table("episodes") as batch:
        batch.alter_column("user_pk", existing_type=sa.Integer(), nullable=False)
        batch.drop_column("user_id")
        batch.create_foreign_key(
            "fk_episodes_user_pk_users", "users", ["user_pk"], ["id"], ondelete="CASCADE"
        )
        batch.create_unique_constraint("uq_episodes_user_pk_event_id", ["user_pk", "event_id"])
        batch.create_unique_constraint("uq_episodes_user_pk_seq", ["user_pk", "seq"])
    with op.batch_alter_table("samples") as batch:
        batch.alter_column("user_pk", existing_type=sa.Integer(), nullable=False)
        batch.drop_column("user_id")
        batch.create_foreign_key(
            "fk_samples_user_pk_users", "users", ["user_pk"], ["id"], ondelete="CASCADE"
        )
        batch.create_index("ix_samples_user_version", ["user_pk", "version"])
        batch.create_index("ix_samples_user_episode", ["user_pk", "episode"])


def downgrade() -> None:
    shared = (
        op.get_bind()
        .execute(
            sa.text(
                "SELECT user_id FROM users GROUP BY user_id HAVING count(*) > 1 ORDER BY user_id"
            )
        )
        .scalars()
        .all()
    )
    if shared:
        raise RuntimeError(
            f"{len(shared)} user ids are in more than one fleet ({', '.join(shared[:5])}"
            f"{', ...' if len(shared) > 5 else ''}); before this revision a user id named one "
            "user in the whole deployment. Rename or delete them, then downgrade."
        )
    for table in CHILDREN:
        with op.batch_alter_table(table) as batch:
            batch.add_column(sa.Column("user_id", sa.String(length=128), nullable=True))
        op.execute(
            f"UPDATE {table} SET user_id = "
            f"(SELECT users.user_id FROM users WHERE users.id = {table}.user_pk)"
        )
    with op.batch_alter_table("learner_models") as batch:
        batch.drop_constraint("fk_learner_models_user_pk_users", type_="foreignkey")
        batch.drop_constraint("pk_learner_models", type_="primary")
    with op.batch_alter_table("episodes") as batch:
        batch.drop_constraint("fk_episodes_user_pk_users", type_="foreignkey")
        batch.drop_constraint("uq_episodes_user_pk_event_id", type_="unique")
        batch.drop_constraint("uq_episodes_user_pk_seq", type_="unique")
    with op.batch_alter_table("samples") as batch:
        batch.drop_constraint("fk_samples_user_pk_users", type_="foreignkey")
        batch.drop_index("ix_samples_user_version")
        batch.drop_index("ix_samples_user_episode")
    if _postgresql():
        op.execute("ALTER TABLE users ALTER COLUMN id DROP DEFAULT")
        op.execute("DROP SEQUENCE users_id_seq")
    with op.batch_alter_table("users") as batch:
        batch.drop_constraint("uq_users_fleet_user_id", type_="unique")
        batch.drop_constraint("pk_users", type_="primary")
        batch.create_primary_key("pk_users", ["user_id"])
        batch.create_index("ix_users_fleet", ["fleet"])
        batch.drop_column("seed_key")
        batch.drop_column("id")
    with op.batch_alter_table("learner_models") as batch:
        batch.alter_column("user_id", existing_type=sa.String(length=128), nullable=False)
        batch.drop_column("user_pk")
        batch.create_primary_key("pk_learner_models", ["user_id"])
        batch.create_foreign_key(
            "fk_learner_models_user_id_users", "users", ["user_id"], ["user_id"], ondelete="CASCADE"
        )
    with op.batch_alter_table("episodes") as batch:
        batch.alter_column("user_id", existing_type=sa.String(length=128), nullable=False)
        batch.drop_column("user_pk")
        batch.create_foreign_key(
            "fk_episodes_user_id_users", "users", ["user_id"], ["user_id"], ondelete="CASCADE"
        )
        batch.create_unique_constraint("uq_episodes_user_id_event_id", ["user_id", "event_id"])
        batch.create_unique_constraint("uq_episodes_user_id_seq", ["user_id", "seq"])
    with op.batch_alter_table("samples") as batch:
        batch.alter_column("user_id", existing_type=sa.String(length=128), nullable=False)
        batch.drop_column("user_pk")
        batch.create_foreign_key(
            "fk_samples_user_id_users", "users", ["user_id"], ["user_id"], ondelete="CASCADE"
        )
        batch.create_index("ix_samples_user_version", ["user_id", "version"])
        batch.create_index("ix_samples_user_episode", ["user_id", "episode"])
