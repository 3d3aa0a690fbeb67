from __future__ import annotations

from fastapi import APIRouter, Request, Response
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute, inline
from app.api.errors import responses
from app.api.links import EPISODE_LINKS, OUTCOME_LINKS
from app.api.metrics import Metrics
from app.schemas.episodes import (
    EpisodeCreated,
    EpisodeIn,
    EpisodeList,
    EpisodeTrace,
    FeedbackIn,
    FeedbackOut,
    OutcomeIn,
    OutcomeOut,
)
from app.services import episodes as service
from app.services.context import ServiceContext

from ._common import (
    REPLAY_HEADER,
    EpisodeId,
    Fleet,
    Limit,
    SeqCursor,
    UserId,
    record_read,
    written,
)

router = APIRouter(tags=["episodes"], route_class=TransactionalRoute)


def _count(request: Request, result: service.Written) -> None:
    if result.replay or not result.body:
        return
    metrics: Metrics = request.app.state.metrics
    decision = result.body.get("decision")
    if isinstance(decision, dict):
        metrics.decision_sent(result.fleet or "", decision["action"]["kind"])


@router.post(
    "/v1/users/{user_id}/episodes",
    status_code=201,
    response_model=EpisodeCreated,
    responses={
        200: {
            "model": EpisodeCreated,
            "description": "Idempotent replay of an earlier event_id.",
            "headers": REPLAY_HEADER,
            "links": EPISODE_LINKS,
        },
        201: {"links": EPISODE_LINKS},
        **responses(404, 409, 415),
    },
)
@inline
def start_episode(
    user_id: UserId,
    body: EpisodeIn,
    request: Request,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    fleet: Fleet = None,
) -> Response:
    """An event happened near this user: open an episode and get the robot's first action."""
    result = service.start_episode(session, ctx, principal, user_id, body, fleet=fleet)
    _count(request, result)
    return written(result)


@router.post(
    "/v1/episodes/{episode_id}/outcomes",
    response_model=OutcomeOut,
    responses={
        200: {
            "headers": REPLAY_HEADER,
            "description": "The reward, the episode, and "
            "the next decision (null when the episode ended).",
            "links": OUTCOME_LINKS,
        },
        **responses(404, 409, 415),
    },
)
@inline
def report_outcome(
    episode_id: EpisodeId,
    body: OutcomeIn,
    request: Request,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> Response:
    """What the person did after the robot's action; answers with the next decision."""
    result = service.report_outcome(session, ctx, principal, episode_id, body)
    if not result.replay and result.kind is not None:
        metrics: Metrics = request.app.state.metrics
        metrics.outcome_reported(
            result.fleet or "", result.kind, body.response, result.body.get("episode")
        )
    _count(request, result)
    return written(result)


@router.post(
    "/v1/episodes/{episode_id}/feedback",
    response_model=FeedbackOut,
    responses={200: {"headers": REPLAY_HEADER}, **responses(404, 409, 415)},
)
def add_feedback(
    episode_id: EpisodeId,
    body: FeedbackIn,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> Response:
    """Explicit feedback on an episode, during or after it (idempotent on feedback_id)."""
    return written(service.add_feedback(session, ctx, principal, episode_id, body))


@router.get("/v1/episodes/{episode_id}", response_model=EpisodeTrace, responses=responses(404))
def get_episode(
    episode_id: EpisodeId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    request: Request,
) -> EpisodeTrace:
    """The whole trace of an episode: every decision, response, reward and feedback (a staff
    or admin read is recorded)."""
    out = service.get_trace(session, ctx, principal, episode_id)
    record_read(request, principal, out.user_id, out.fleet, "episode")
    return out


@router.get("/v1/users/{user_id}/episodes", response_model=EpisodeList, responses=responses(404))
def list_episodes(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    request: Request,
    limit: Limit = 50,
    cursor: SeqCursor = None,
    fleet: Fleet = None,
) -> EpisodeList:
    """A user's episodes, newest first, without traces (a staff or admin read is recorded)."""
    out = service.list_episodes(
        session, ctx, principal, user_id, limit=limit, cursor=cursor, fleet=fleet
    )
    record_read(request, principal, user_id, fleet, "episodes")
    return out
