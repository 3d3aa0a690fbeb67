"""Reading a user's stored rows in tests: users are (fleet, user id), the tables of a user
point at its deployment number (``users.id``)."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.models import User


def user_pk(session: Session, user_id: str, fleet: str = "default") -> int:
    """The deployment number of ``user_id`` of ``fleet``; fails when there is none."""
    pk = session.scalar(select(User.id).where(User.fleet == fleet, User.user_id == user_id))
    assert pk is not None, f"no user {fleet}/{user_id}"
    return pk
