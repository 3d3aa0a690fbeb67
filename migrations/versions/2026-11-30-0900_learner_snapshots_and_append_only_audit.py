"""Learner snapshots (state_version) and an append-only audit log enforced by the database.

``learner_models.state_version`` is the model version the stored state document is of: the
service now stores the learner's state every few versions and replays the journal's later
samples onto it. Every stored state is current before this revision, so it starts equal to
``version``.

The audit log's entries were protected against change by the ORM only; the database now refuses
an UPDATE or DELETE of ``audit_log`` rows itself (a trigger on each engine).

Revision ID: 5b7e1c2d9a40
Revises: 0e0cf2f012cb
Create Date: 2026-11-30 09:00:00+00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "5b7e1c2d9a40"
down_revision: str | None = "0e0cf2f012cb"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_MESSAGE = "audit_log entries are append only: they are never changed or removed"


def upgrade() -> None:
    with op.batch_alter_table("learner_models") as batch:
        batch.add_column(
            sa.Column("state_version", sa.Integer(), nullable=False, server_default="0")
        )
    op.execute("UPDATE learner_models SET state_version = version")
    if op.get_bind().dialect.name == "postgresql":
        op.execute(f"""
            CREATE FUNCTION audit_log_append_only() RETURNS trigger LANGUAGE plpgsql AS $$
            BEGIN
                RAISE EXCEPTION '{_MESSAGE}';
            END $$""")
        op.execute("""
            CREATE TRIGGER audit_log_append_only BEFORE UPDATE OR DELETE ON audit_log
            FOR EACH ROW EXECUTE FUNCTION audit_log_append_only()""")
    else:
        for event in ("UPDATE", "DELETE"):
            op.execute(f"""
                CREATE TRIGGER audit_log_no_{event.lower()} BEFORE {event} ON audit_log
                BEGIN SELECT RAISE(ABORT, '{_MESSAGE}'); END""")


def downgrade() -> None:
    if op.get_bind().dialect.name == "postgresql":
        op.execute("DROP TRIGGER audit_log_append_only ON audit_log")
        op.execute("DROP FUNCTION audit_log_append_only()")
    else:
        for event in ("update", "delete"):
            op.execute(f"DROP TRIGGER audit_log_no_{event}")
    # Before this revision the stored state is the model itself: every state must be current.
    behind = (
        op.get_bind()
        .execute(sa.text("SELECT count(*) FROM learner_models WHERE state_version <> version"))
        .scalar()
    )
    if behind:
        raise RuntimeError(
            f"{behind} stored learner states are older than their models; run "
            "`attune models snapshot --all` with this version of Attune first, then downgrade."
        )
    with op.batch_alter_table("learner_models") as batch:
        batch.drop_column("state_version")
