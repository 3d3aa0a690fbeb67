"""Reads for the admin console: users found by text, a page at a time, with recent activity."""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from sqlalchemy import Select, case, func, or_, select
from sqlalchemy.orm import Session

from ..models import Episode, User
from ._rows import columns, conn, table
from .users import UserRow

__all__ = [
    "Activity",
    "count_users",
    "episode_offsets",
    "latest_episode_in_context",
    "open_episodes",
    "recent_activity",
    "search_users",
]

_S = TypeVar("_S", bound=Select[Any])


@dataclass(frozen=True, slots=True)
class Activity:
    """A user's last ``window`` episodes: how many, missions, successes; and the latest one."""

    episodes: int
    missions: int
    successes: int
    last_at: dt.datetime | None
    utc_offset: int | None = None  # of the latest episode: the person's local time


def _matching(stmt: _S, *, fleet: str | None, text: str | None) -> _S:
    if fleet is not None:
        stmt = stmt.where(User.fleet == fleet)
    if text:
        stmt = stmt.where(
            or_(
                User.user_id.icontains(text, autoescape=True),
                User.display_name.icontains(text, autoescape=True),
            )
        )
    return stmt


def search_users(
    session: Session, *, fleet: str | None, text: str | None, offset: int, limit: int
) -> list[UserRow]:
    stmt = (
        select(*columns(table(User), UserRow))
        .order_by(User.fleet, User.user_id)
        .offset(offset)
        .limit(limit)
    )
    return [UserRow(*row) for row in conn(session).execute(_matching(stmt, fleet=fleet, text=text))]


def count_users(session: Session, *, fleet: str | None, text: str | None) -> int:
    stmt = select(func.count()).select_from(User)
    return int(conn(session).execute(_matching(stmt, fleet=fleet, text=text)).scalar() or 0)


def recent_activity(
    session: Session, user_pks: Sequence[int], *, window: int
) -> dict[int, Activity]:
    """Per user (by its number): counts over the episodes with ``seq`` in the last ``window``
    (the user's own 1-based index, so the unique (user_pk, seq) index serves the range), and
    the time of the latest episode's last change (opened or closed)."""
    if not user_pks:
        return {}
    mission = Episode.interaction_class != "none"
    counts = (
        conn(session)
        .execute(
            select(
                Episode.user_pk,
                func.count(),
                func.sum(case((mission, 1), else_=0)),
                func.sum(case((Episode.success, 1), else_=0)),
            )
            .join(User, User.id == Episode.user_pk)
            .where(Episode.user_pk.in_(user_pks), Episode.seq > User.episode_count - window)
            .group_by(Episode.user_pk)
        )
        .all()
    )
    latest = (
        conn(session)
        .execute(
            select(Episode.user_pk, Episode.created_at, Episode.closed_at, Episode.utc_offset)
            .join(User, User.id == Episode.user_pk)
            .where(Episode.user_pk.in_(user_pks), Episode.seq == User.episode_count)
        )
        .all()
    )
    last_at = {
        uid: max(t for t in (created, closed) if t is not None)
        for uid, created, closed, _ in latest
    }
    offsets = {uid: offset for uid, _, _, offset in latest}
    out = {
        uid: Activity(int(n), int(m or 0), int(s or 0), last_at.get(uid), offsets.get(uid))
        for uid, n, m, s in counts
    }
    return {uid: out.get(uid, Activity(0, 0, 0, None)) for uid in user_pks}


def latest_episode_in_context(
    session: Session, user_pk: int, time_slot: str, situation: str
) -> str | None:
    """Id of the user's most recent episode in (``time_slot``, ``situation``), if any (by
    names: the context's number may differ between mission versions)."""
    stmt = (
        select(Episode.id)
        .where(
            Episode.user_pk == user_pk,
            Episode.time_slot == time_slot,
            Episode.situation == situation,
        )
        .order_by(Episode.seq.desc())
        .limit(1)
    )
    found: str | None = conn(session).execute(stmt).scalar()
    return found


def open_episodes(session: Session, user_pk: int) -> int:
    """How many of the user's episodes are still open (a robot waiting for an answer)."""
    stmt = (
        select(func.count())
        .select_from(Episode)
        .where(Episode.user_pk == user_pk, Episode.status == "open")
    )
    return int(conn(session).execute(stmt).scalar() or 0)


def episode_offsets(session: Session, episode_ids: Sequence[str]) -> dict[str, int | None]:
    """Per episode id: minutes east of UTC its time came with (None: not known)."""
    if not episode_ids:
        return {}
    rows = (
        conn(session)
        .execute(select(Episode.id, Episode.utc_offset).where(Episode.id.in_(list(episode_ids))))
        .all()
    )
    return {episode_id: offset for episode_id, offset in rows}


def episode_ids_by_seq(session: Session, user_pk: int, seqs: Sequence[int]) -> dict[int, str]:
    """Per episode index of the person: its episode's id (the ones still stored)."""
    if not seqs:
        return {}
    rows = conn(session).execute(
        select(Episode.seq, Episode.id).where(
            Episode.user_pk == user_pk, Episode.seq.in_(sorted(set(seqs)))
        )
    )
    return {int(seq): episode_id for seq, episode_id in rows}
