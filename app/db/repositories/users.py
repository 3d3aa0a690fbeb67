from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from ..models import LearnerModel, User
from ..types import utcnow

__all__ = ["delete_user", "get_model", "get_user", "insert_user_if_absent", "list_users"]


def get_user(session: Session, user_id: str, *, for_update: bool = False) -> User | None:
    stmt = select(User).where(User.user_id == user_id)
    if for_update:
        # PostgreSQL: the per-user lock. SQLite ignores it; its write transactions are
        # BEGIN IMMEDIATE, which already holds the database's single write lock.
        stmt = stmt.with_for_update()
    return session.scalars(stmt.execution_options(populate_existing=True)).first()


def insert_user_if_absent(
    session: Session, *, user_id: str, fleet: str, algorithm: str, params: dict[str, Any],
    display_name: str | None, state: dict[str, Any],
) -> bool:
    """Insert the user and its fresh model unless the id exists; True when inserted.

    ``ON CONFLICT DO NOTHING`` makes two robots creating the same user at once safe: one wins,
    the other sees the winner's row when it locks it.
    """
    values = {
        "user_id": user_id, "fleet": fleet, "algorithm": algorithm, "params": params,
        "display_name": display_name, "created_at": utcnow(), "episode_count": 0, "draws": 0,
    }
    dialect = session.get_bind().dialect.name
    insert = postgresql.insert if dialect == "postgresql" else sqlite.insert
    stmt = (
        insert(User).values(**values).on_conflict_do_nothing(index_elements=["user_id"])
        .returning(User.user_id)
    )
    inserted = session.execute(stmt).first() is not None
    if inserted:
        session.add(LearnerModel(user_id=user_id, version=0, state=state, base_state=None,
                                 base_version=0, episode_offset=0, updated_at=utcnow()))
        session.flush()
    return inserted


def list_users(
    session: Session, *, fleet: str | None, after: str | None, limit: int
) -> Sequence[User]:
    stmt = select(User).order_by(User.user_id).limit(limit)
    if fleet is not None:
        stmt = stmt.where(User.fleet == fleet)
    if after is not None:
        stmt = stmt.where(User.user_id > after)
    return session.scalars(stmt).all()


def delete_user(session: Session, user_id: str) -> None:
    session.execute(delete(User).where(User.user_id == user_id))


def get_model(session: Session, user_id: str) -> LearnerModel | None:
    stmt = select(LearnerModel).where(LearnerModel.user_id == user_id)
    return session.scalars(stmt.execution_options(populate_existing=True)).first()
