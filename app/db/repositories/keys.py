from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import Row, Table, bindparam, select
from sqlalchemy.orm import Session

from ..models import ApiKey

__all__ = ["add_key", "get_key", "key_by_hash", "list_keys"]

_keys: Table = ApiKey.__table__  # type: ignore[assignment]
# Every request looks its key up: one prebuilt Core statement, no ORM object.
_BY_HASH = select(_keys.c.id, _keys.c.role, _keys.c.fleet, _keys.c.secret_hash,
                  _keys.c.revoked_at).where(_keys.c.secret_hash == bindparam("secret_hash"))


def add_key(session: Session, key: ApiKey) -> ApiKey:
    session.add(key)
    session.flush()
    return key


def get_key(session: Session, key_id: str) -> ApiKey | None:
    return session.get(ApiKey, key_id)


def key_by_hash(session: Session, secret_hash: str) -> Row[Any, Any, Any, Any, Any] | None:
    """(id, role, fleet, secret_hash, revoked_at) of the key with this digest."""
    return session.connection().execute(_BY_HASH, {"secret_hash": secret_hash}).first()


def list_keys(session: Session, *, fleet: str | None = None) -> Sequence[ApiKey]:
    stmt = select(ApiKey).order_by(ApiKey.created_at, ApiKey.id)
    if fleet is not None:
        stmt = stmt.where(ApiKey.fleet == fleet)
    return session.scalars(stmt).all()
