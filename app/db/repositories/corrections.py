"""The staff corrections of a user: made once (idempotent on ``correction_id``), lifted once,
never changed otherwise."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import insert, select, update
from sqlalchemy.orm import Session

from ..models import Correction
from ._rows import conn, names, table

__all__ = ["CorrectionRow", "add", "by_id", "by_ids", "for_user", "lift"]


@dataclass(slots=True)
class CorrectionRow:
    id: int | None
    user_pk: int
    correction_id: str
    kind: str
    time_slot: str
    situation: str
    service: str | None
    detail: str | None
    note: str | None
    actor_key_id: str
    created_at: dt.datetime
    model_version: int
    lifted_at: dt.datetime | None
    lifted_by: str | None
    request_hash: str
    response: dict[str, Any]


_corrections = table(Correction)
_NAMES = names(CorrectionRow)
_COLS = [_corrections.c[name] for name in _NAMES]


def add(session: Session, row: CorrectionRow) -> int:
    """Store a new correction; its row id."""
    values = {name: getattr(row, name) for name in _NAMES if name != "id"}
    new_id: int = (
        conn(session)
        .execute(insert(_corrections).values(**values).returning(_corrections.c.id))
        .scalar_one()
    )
    row.id = new_id
    return new_id


def by_id(session: Session, user_pk: int, correction_id: str) -> CorrectionRow | None:
    found = (
        conn(session)
        .execute(
            select(*_COLS).where(
                _corrections.c.user_pk == user_pk, _corrections.c.correction_id == correction_id
            )
        )
        .first()
    )
    return None if found is None else CorrectionRow(*found)


def by_ids(session: Session, user_pk: int, ids: list[int]) -> dict[int, CorrectionRow]:
    """The user's corrections of these row ids (a rebuild's journal names them)."""
    if not ids:
        return {}
    rows = conn(session).execute(
        select(*_COLS).where(_corrections.c.user_pk == user_pk, _corrections.c.id.in_(ids))
    )
    return {row.id: CorrectionRow(*row) for row in rows}


def for_user(session: Session, user_pk: int) -> list[CorrectionRow]:
    """Every correction of the user, lifted ones too, in the order they were made."""
    rows = conn(session).execute(
        select(*_COLS).where(_corrections.c.user_pk == user_pk).order_by(_corrections.c.id)
    )
    return [CorrectionRow(*row) for row in rows]


def lift(session: Session, row_id: int, *, at: dt.datetime | None, by: str | None) -> None:
    """Mark the correction lifted (``at`` None: in force again, after an import that brought
    it back)."""
    conn(session).execute(
        update(_corrections).where(_corrections.c.id == row_id).values(lifted_at=at, lifted_by=by)
    )
