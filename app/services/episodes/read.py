"""Read views of episodes: a whole trace, and a user's episodes a page at a time."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import episodes as repo
from app.db.repositories.episodes import EpisodeRow
from app.errors import NotFound, ValidationFailed
from app.schemas.common import position_of
from app.schemas.episodes import EpisodeList, EpisodeSummary, EpisodeTrace

from ..context import Principal, ServiceContext
from ..users import visible_user
from .render import chain_out, probabilities_out, state_name

__all__ = ["get_trace", "list_episodes"]


def _summary(
    session: Session, ctx: ServiceContext, ep: EpisodeRow, user_id: str, fleet: str
) -> dict[str, Any]:
    space = ctx.missions.get(session, fleet, ep.mission_version).space
    return {
        "episode_id": ep.id,
        "user_id": user_id,
        "fleet": fleet,
        "event_id": ep.event_id,
        "robot_id": ep.robot_id,
        "status": ep.status,
        "context": {"time_slot": ep.time_slot, "situation": ep.situation},
        "initiator": ep.initiator,
        "interaction_class": ep.interaction_class,
        "total_reward": ep.total_reward,
        "state": state_name(space, ep.state),
        "occurred_at": repo.local_time(ep.occurred_at, ep.utc_offset),
        "index": ep.seq,
        "mission_version": ep.mission_version,
    }


def get_trace(
    session: Session, ctx: ServiceContext, principal: Principal, episode_id: str
) -> EpisodeTrace:
    owner = repo.owner(session, episode_id)
    ep = repo.get(session, episode_id) if owner is not None else None
    if owner is None or ep is None or not principal.sees(owner[1]):
        raise NotFound(f"No episode {episode_id!r} in your fleet.")
    space = ctx.missions.get(session, owner[1], ep.mission_version).space
    decisions = [
        {
            "decision_id": d.id,
            "state": state_name(space, d.state),
            "action": space.actions[d.action].to_dict(),
            "probabilities": probabilities_out(space, d.state, d.probabilities),
            "chain": chain_out(space, d.chain),
            "response": d.response,
            "service": d.service,
            "detail": d.detail,
            "feedback": d.feedback,
            "reward": d.reward,
            "decided_at": d.decided_at,
            "answered_at": d.answered_at,
        }
        for d in repo.decisions(session, episode_id)
    ]
    feedback = [
        {
            "feedback_id": f.feedback_id,
            "feedback": f.feedback,
            "reward": f.reward,
            "received_at": f.received_at,
        }
        for f in repo.feedback_list(session, episode_id)
    ]
    return EpisodeTrace.model_validate(
        {
            **_summary(session, ctx, ep, owner[2], owner[1]),
            "decisions": decisions,
            "feedback": feedback,
        }
    )


def list_episodes(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    limit: int,
    cursor: str | None,
    fleet: str | None = None,
) -> EpisodeList:
    user = visible_user(session, principal, user_id, fleet=fleet)
    before: int | None = None
    if cursor is not None:
        before = position_of(cursor)
        if before is None:
            raise ValidationFailed("cursor is not one this API returned.")
    rows = repo.list_page(session, user.id, before_seq=before, limit=limit + 1)
    items = [
        EpisodeSummary.model_validate(_summary(session, ctx, ep, user_id, user.fleet))
        for ep in rows[:limit]
    ]
    more = len(rows) > limit
    return EpisodeList(items=items, next_cursor=str(rows[limit - 1].seq) if more else None)
