"""Reads the admin console needs beyond the v1 API's: users found by text, a page at a time, with
their recent activity; and the latest episode of a user in one context (the decision to explain).

The metrics follow docs/method.md §10, as ``models.stats`` does: the recent success rate is
``stats(last=RECENT_EPISODES).success_rate``, computed in SQL for a whole page of users at once.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from sqlalchemy.orm import Session

from app.db.repositories import console as repo
from app.db.repositories import keys as keys_repo
from app.db.repositories import missions as missions_repo
from app.db.repositories import models as models_repo
from app.db.repositories import retention as retention_repo
from app.db.repositories import users as users_repo
from app.db.repositories.users import UserRow
from app.errors import ValidationFailed
from app.learning import Mission
from app.schemas.changes import ChangeEventOut
from app.schemas.episodes import EpisodeTrace
from app.schemas.users import UserOut

from .context import Principal, ServiceContext
from .episodes import get_trace
from .users import user_out, visible_user

__all__ = [
    "evidence_episodes",
    "RECENT_EPISODES",
    "UserActivity",
    "UserPage",
    "episode_offsets",
    "find_users",
    "history_from",
    "key_names",
    "latest_trace_in_context",
    "mission_version",
    "open_episodes",
    "time_zones",
    "user_mission",
]

RECENT_EPISODES = 100  # "recent": the last 100 episodes, the paper's block size (Table II)


@dataclass(frozen=True, slots=True)
class UserActivity:
    """A user with its recent success rate (None: no mission yet) and last activity."""

    user: UserOut
    recent_episodes: int
    recent_missions: int
    recent_success_rate: float | None
    last_activity: dt.datetime | None
    utc_offset: int | None = None  # minutes east of UTC of the latest episode


@dataclass(frozen=True, slots=True)
class UserPage:
    items: list[UserActivity]
    total: int
    page: int  # 1-based
    per_page: int

    @property
    def pages(self) -> int:
        return max(1, math.ceil(self.total / self.per_page))


def find_users(
    session: Session,
    principal: Principal,
    *,
    text: str | None,
    page: int,
    per_page: int,
    window: int = RECENT_EPISODES,
) -> UserPage:
    """Users whose id or display name contains ``text`` (any case), by user id, one page.

    Like ``GET /v1/users``, a robot key sees its own fleet and an admin key every fleet.
    """
    if page < 1 or not 1 <= per_page <= 500:
        raise ValidationFailed("page must be 1 or more, per_page between 1 and 500.")
    text = (text or "").strip() or None
    if text is not None and len(text) > 200:
        raise ValidationFailed("search text must be at most 200 characters.")
    fleet = None if principal.is_admin else principal.fleet
    total = repo.count_users(session, fleet=fleet, text=text)
    users = repo.search_users(
        session, fleet=fleet, text=text, offset=(page - 1) * per_page, limit=per_page
    )
    activity = repo.recent_activity(session, [u.id for u in users], window=window)
    items = []
    for user in users:
        a = activity[user.id]
        items.append(
            UserActivity(
                user=user_out(user),
                recent_episodes=a.episodes,
                recent_missions=a.missions,
                recent_success_rate=a.successes / a.missions if a.missions else None,
                last_activity=a.last_at,
                utc_offset=a.utc_offset,
            )
        )
    return UserPage(items=items, total=total, page=page, per_page=per_page)


def evidence_episodes(
    session: Session, fleet: str, changes: Sequence[ChangeEventOut]
) -> dict[tuple[str, int], str]:
    """(user id, episode index) -> episode id, for the episodes the changes name as evidence
    that are still stored (a retention run may have removed older ones)."""
    wanted: dict[str, set[int]] = {}
    for c in changes:
        wanted.setdefault(c.user_id, set()).update(e.episode for e in c.evidence)
    out: dict[tuple[str, int], str] = {}
    for user_id, seqs in wanted.items():
        found = users_repo.get(session, fleet, user_id)
        if found is None:
            continue
        for seq, episode_id in repo.episode_ids_by_seq(session, found.id, sorted(seqs)).items():
            out[(user_id, seq)] = episode_id
    return out


def _pk(session: Session, user: UserOut | UserRow) -> int:
    if isinstance(user, UserRow):
        return user.id
    found = users_repo.get(session, user.fleet, user.user_id)
    assert found is not None  # the caller found the user
    return found.id


def open_episodes(session: Session, user: UserOut | UserRow) -> int:
    """How many of the user's episodes are still open (counted in ``user.episodes`` too)."""
    return repo.open_episodes(session, _pk(session, user))


def history_from(session: Session, user: UserOut | UserRow) -> dt.datetime | None:
    """From when the person's history is kept, since a retention run removed what was older
    (``None``: all of it is kept), as ``GET /v1/users/{id}/stats`` says ``history_from``."""
    return retention_repo.kept_from(session, _pk(session, user))


def episode_offsets(session: Session, episode_ids: list[str]) -> dict[str, int | None]:
    """Minutes east of UTC each episode's time came with: the person's local time then
    (None: sent before offsets were kept)."""
    return repo.episode_offsets(session, episode_ids)


def mission_version(session: Session, user: UserOut | UserRow) -> int:
    """The fleet's mission version the user's model follows."""
    model = models_repo.head(session, _pk(session, user))
    if model is None:  # every person is created with a model; only a broken database lacks it
        raise RuntimeError(f"user {user.fleet}/{user.user_id} has no model row")
    return model.mission_version


def user_mission(session: Session, ctx: ServiceContext, user: UserOut | UserRow) -> Mission:
    """The mission version a user's model is laid out for (the fleet's in force)."""
    return ctx.missions.display(session, user.fleet, mission_version(session, user))


def latest_trace_in_context(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    time_slot: str,
    situation: str,
    fleet: str | None = None,
) -> EpisodeTrace | None:
    """The trace of the user's most recent episode in (time slot, situation), if any."""
    user = visible_user(session, principal, user_id, fleet=fleet)
    try:
        user_mission(session, ctx, user).context_index(time_slot, situation)
    except ValueError as exc:
        raise ValidationFailed(str(exc)) from None
    episode_id = repo.latest_episode_in_context(session, user.id, time_slot, situation)
    return None if episode_id is None else get_trace(session, ctx, principal, episode_id)


def key_names(session: Session, key_ids: Sequence[str]) -> dict[str, str]:
    """The names of the keys given by id (a key without a name, or gone, is left out)."""
    out = {}
    for key_id in dict.fromkeys(key_ids):
        key = keys_repo.get(session, key_id)
        if key is not None and key.name:
            out[key_id] = key.name
    return out


def time_zones(session: Session, ctx: ServiceContext, fleets: Iterable[str]) -> dict[str, str]:
    """Each fleet's time zone (its mission in force's ``time_zone``)."""
    out = {}
    for fleet in fleets:
        version = missions_repo.latest_version(session, fleet) or 1
        out[fleet] = ctx.missions.display(session, fleet, version).time_zone
    return out
