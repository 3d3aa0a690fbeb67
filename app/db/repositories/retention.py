"""What a retention run reads and removes: the folds (``history_folds``), the fleets' windows,
the old part of a person's history, removed a batch at a time (the journal's part is
``journal.delete_folded``)."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import delete, func, or_, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from ..models import Decision, Episode, FleetSettings, HistoryFold, JournalEntry, LearnerModel, User
from ._rows import columns, conn, record, table

__all__ = [
    "FoldRow",
    "delete_episodes",
    "doc",
    "first_kept_created",
    "first_kept_version",
    "fleet_windows",
    "fold",
    "kept_from",
    "leftovers",
    "people",
    "put_fold",
    "set_window",
    "upto_seq",
    "window",
]


@dataclass(slots=True)
class FoldRow:
    user_pk: int
    upto_seq: int
    upto_version: int
    kept_from: dt.datetime
    folded_at: dt.datetime
    doc: dict[str, Any]


_folds = table(HistoryFold)
_settings = table(FleetSettings)
_users = table(User)
_episodes = table(Episode)
_decisions = table(Decision)
_journal = table(JournalEntry)
_models = table(LearnerModel)


def fold(session: Session, user_pk: int) -> FoldRow | None:
    return record(
        FoldRow,
        conn(session)
        .execute(select(*columns(_folds, FoldRow)).where(_folds.c.user_pk == user_pk))
        .first(),
    )


def doc(session: Session, user_pk: int) -> dict[str, Any] | None:
    """The profile's walk over the person's removed episodes (``None``: none removed)."""
    return (
        conn(session)
        .execute(select(_folds.c.doc).where(_folds.c.user_pk == user_pk))
        .scalar_one_or_none()
    )


def kept_from(session: Session, user_pk: int) -> dt.datetime | None:
    """From when the person's history is kept (``None``: all of it)."""
    return (
        conn(session)
        .execute(select(_folds.c.kept_from).where(_folds.c.user_pk == user_pk))
        .scalar_one_or_none()
    )


def put_fold(
    session: Session,
    user_pk: int,
    *,
    upto_seq: int,
    upto_version: int,
    kept_from: dt.datetime,
    now: dt.datetime,
    doc: dict[str, Any],
) -> None:
    c = conn(session)
    dialect = postgresql if c.dialect.name == "postgresql" else sqlite
    values = {
        "upto_seq": upto_seq,
        "upto_version": upto_version,
        "kept_from": kept_from,
        "folded_at": now,
        "doc": doc,
    }
    stmt = dialect.insert(_folds).values(user_pk=user_pk, **values)
    c.execute(stmt.on_conflict_do_update(index_elements=["user_pk"], set_=values))


def window(session: Session, fleet: str) -> int | None:
    """The fleet's retention window in days (``None``: keep everything)."""
    return (
        conn(session)
        .execute(select(_settings.c.history_days).where(_settings.c.fleet == fleet))
        .scalar_one_or_none()
    )


def fleet_windows(session: Session) -> list[tuple[str, int]]:
    """(fleet, days) of every fleet with a retention window."""
    rows = conn(session).execute(
        select(_settings.c.fleet, _settings.c.history_days)
        .where(_settings.c.history_days.is_not(None))
        .order_by(_settings.c.fleet)
    )
    return [(r[0], int(r[1])) for r in rows]


def set_window(
    session: Session, fleet: str, *, days: int | None, now: dt.datetime, actor: str | None
) -> None:
    c = conn(session)
    dialect = postgresql if c.dialect.name == "postgresql" else sqlite
    stmt = dialect.insert(_settings).values(
        fleet=fleet, prior_enabled=True, history_days=days, updated_at=now, updated_by=actor
    )
    c.execute(
        stmt.on_conflict_do_update(
            index_elements=["fleet"],
            set_={"history_days": days, "updated_at": now, "updated_by": actor},
        )
    )


def people(session: Session, fleet: str, *, after_pk: int, limit: int) -> list[tuple[int, str]]:
    """(row id, user id) of the fleet's people after ``after_pk``, in row order."""
    rows = conn(session).execute(
        select(_users.c.id, _users.c.user_id)
        .where(_users.c.fleet == fleet, _users.c.id > after_pk)
        .order_by(_users.c.id)
        .limit(limit)
    )
    return [(r[0], r[1]) for r in rows]


def upto_seq(session: Session, user_pk: int, before: dt.datetime) -> int:
    """The last episode of the longest run from the person's first episode that is closed
    and was received before ``before`` (0: none)."""
    c = conn(session)
    first_kept = c.execute(
        select(func.min(_episodes.c.seq)).where(
            _episodes.c.user_pk == user_pk,
            or_(_episodes.c.status == "open", _episodes.c.created_at >= before),
        )
    ).scalar()
    if first_kept is not None:
        return int(first_kept) - 1
    last = c.execute(
        select(func.max(_episodes.c.seq)).where(_episodes.c.user_pk == user_pk)
    ).scalar()
    return 0 if last is None else int(last)


def first_kept_version(session: Session, user_pk: int, after_seq: int) -> int | None:
    """The oldest model version a decision of an episode after ``after_seq`` was drawn from."""
    return (
        conn(session)
        .execute(
            select(func.min(_decisions.c.model_version))
            .join(_episodes, _episodes.c.id == _decisions.c.episode_id)
            .where(_episodes.c.user_pk == user_pk, _episodes.c.seq > after_seq)
        )
        .scalar()
    )


def first_kept_created(session: Session, user_pk: int, after_seq: int) -> dt.datetime | None:
    """When the oldest episode after ``after_seq`` was received (``None``: no such episode)."""
    return (
        conn(session)
        .execute(
            select(func.min(_episodes.c.created_at)).where(
                _episodes.c.user_pk == user_pk, _episodes.c.seq > after_seq
            )
        )
        .scalar()
    )


def delete_episodes(session: Session, user_pk: int, upto_seq: int, *, limit: int) -> int:
    """Remove up to ``limit`` of the person's episodes up to ``upto_seq`` (their decisions and
    feedback go with them): how many."""
    c = conn(session)
    ids = (
        select(_episodes.c.id)
        .where(_episodes.c.user_pk == user_pk, _episodes.c.seq <= upto_seq)
        .order_by(_episodes.c.seq)
        .limit(limit)
        .scalar_subquery()
    )
    return int(c.execute(delete(_episodes).where(_episodes.c.id.in_(ids))).rowcount or 0)


def leftovers(session: Session, user_pk: int) -> bool:
    """Whether the person still has episodes or journal entries a past run folded."""
    c = conn(session)
    old_episode = c.execute(
        select(_episodes.c.id)
        .join(_folds, _folds.c.user_pk == _episodes.c.user_pk)
        .where(_episodes.c.user_pk == user_pk, _episodes.c.seq <= _folds.c.upto_seq)
        .limit(1)
    ).first()
    if old_episode is not None:
        return True
    old_entry = c.execute(
        select(_journal.c.id)
        .join(_folds, _folds.c.user_pk == _journal.c.user_pk)
        .where(
            _journal.c.user_pk == user_pk,
            _journal.c.version <= _folds.c.upto_version,
            _journal.c.kind != "fold",
        )
        .limit(1)
    ).first()
    return old_entry is not None
