"""API keys: the SHA-256 of each secret, with the key's role and fleet."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

from sqlalchemy import bindparam, func, insert, select, update
from sqlalchemy.orm import Session

from ..models import ApiKey
from ._rows import columns, conn, names, record, table, values

__all__ = ["KeyRow", "add", "by_hash", "get", "list_all", "live_counts", "revoke"]


@dataclass(slots=True)
class KeyRow:
    id: str
    prefix: str
    secret_hash: str
    role: str
    fleet: str
    name: str | None
    created_at: dt.datetime
    revoked_at: dt.datetime | None


_keys = table(ApiKey)
_COLS = columns(_keys, KeyRow)
# Every request looks its key up (unless the worker's key cache has it): one prebuilt statement.
_BY_HASH = select(*_COLS).where(_keys.c.secret_hash == bindparam("secret_hash"))
_GET = select(*_COLS).where(_keys.c.id == bindparam("key_id"))


def add(session: Session, key: KeyRow) -> None:
    conn(session).execute(insert(_keys), [values(key, names(KeyRow))])


def get(session: Session, key_id: str) -> KeyRow | None:
    return record(KeyRow, conn(session).execute(_GET, {"key_id": key_id}).first())


def by_hash(session: Session, secret_hash: str) -> KeyRow | None:
    return record(KeyRow, conn(session).execute(_BY_HASH, {"secret_hash": secret_hash}).first())


def list_all(session: Session, *, fleet: str | None = None) -> list[KeyRow]:
    stmt = select(*_COLS).order_by(_keys.c.created_at, _keys.c.id)
    if fleet is not None:
        stmt = stmt.where(_keys.c.fleet == fleet)
    return [KeyRow(*row) for row in conn(session).execute(stmt)]


def live_counts(session: Session) -> dict[str, int]:
    """Keys not revoked, per fleet."""
    stmt = (
        select(_keys.c.fleet, func.count())
        .where(_keys.c.revoked_at.is_(None))
        .group_by(_keys.c.fleet)
    )
    return {fleet: int(n) for fleet, n in conn(session).execute(stmt)}


def revoke(session: Session, key_id: str, at: dt.datetime) -> None:
    conn(session).execute(update(_keys).where(_keys.c.id == key_id).values(revoked_at=at))
