"""Rolling a candidate learner out to a share of a fleet's people, comparing the arms while it
runs, and promoting or rolling it back (the fleet's staff, admins): :mod:`app.services.rollouts`.
"""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute
from app.api.errors import responses
from app.schemas.rollouts import RollbackIn, RolloutIn, RolloutOut, ShadowIn, ShadowOut
from app.services import rollouts, shadows
from app.services.context import ServiceContext

from ._common import FleetName

router = APIRouter(prefix="/v1/admin", tags=["rollouts"], route_class=TransactionalRoute)


@router.get("/fleets/{fleet}/rollout", response_model=RolloutOut, responses=responses(403, 404))
def get_rollout(
    fleet: FleetName, session: Session, ctx: ServiceContext, principal: CurrentPrincipal
) -> RolloutOut:
    """The fleet's newest rollout and a look at its arms: candidate minus control in mean
    return per encounter, with an interval that holds at every look, and what it says in
    words. 404 when the fleet never had one."""
    return RolloutOut.of(rollouts.rollout_view(session, ctx, principal, fleet))


@router.put(
    "/fleets/{fleet}/rollout",
    response_model=RolloutOut,
    status_code=200,
    responses={**responses(403, 409, 415), 201: {"description": "A rollout started."}},
)
def put_rollout(
    fleet: FleetName,
    body: RolloutIn,
    request: Request,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> JSONResponse:
    """Roll ``candidate`` out to ``share`` of the fleet's people (201 when it starts one), or
    change the share of the one running (200; the same candidate, else 409). Each person's arm
    is chosen by a salted stable hash of their id and stored: a lower share, a mission change or
    a restart moves no one. A person moved keeps what was learned (their history is taught to
    the learner they move to). Audit entries ``rollout.start``, ``rollout.share``, and
    ``user.learner`` per person moved."""
    found, started = rollouts.put_rollout(
        session,
        ctx,
        principal,
        fleet,
        algorithm=body.candidate.algorithm,
        params=body.candidate.params,
        share=body.share,
        mover=getattr(request.app.state, "rollout_mover", None),
    )
    out = RolloutOut.of(found).model_dump(mode="json")
    return JSONResponse(out, status_code=201 if started else 200)


@router.post(
    "/fleets/{fleet}/rollout/promote", response_model=RolloutOut, responses=responses(403, 409)
)
def promote_rollout(
    fleet: FleetName,
    request: Request,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> RolloutOut:
    """Give the running rollout's candidate to everyone it assigned (the control people move,
    keeping what was learned) and to the fleet's newcomers from now on. 409 when no rollout
    runs. Audit entry ``rollout.promote``."""
    mover = getattr(request.app.state, "rollout_mover", None)
    return RolloutOut.of(rollouts.promote(session, ctx, principal, fleet, mover=mover))


@router.post(
    "/fleets/{fleet}/rollout/rollback",
    response_model=RolloutOut,
    responses=responses(403, 409, 415),
)
def roll_back_rollout(
    fleet: FleetName,
    request: Request,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    body: RollbackIn | None = None,
) -> RolloutOut:
    """Give every candidate person back the learner they had (taught their whole history,
    what the candidate learned with them included); newcomers get the fleet's default again.
    409 when no rollout runs. Audit entry ``rollout.rollback``."""
    reason = body.reason if body is not None else None
    mover = getattr(request.app.state, "rollout_mover", None)
    return RolloutOut.of(
        rollouts.roll_back(session, ctx, principal, fleet, reason=reason, mover=mover)
    )


@router.get("/fleets/{fleet}/shadow", response_model=ShadowOut, responses=responses(403, 404))
def get_shadow(
    fleet: FleetName, session: Session, ctx: ServiceContext, principal: CurrentPrincipal
) -> ShadowOut:
    """The fleet's newest shadow: how often its candidate would have done what the robots did,
    and its off-policy estimate. 404 when the fleet never had one."""
    return ShadowOut.model_validate(shadows.shadow_view(session, ctx, principal, fleet))


@router.put(
    "/fleets/{fleet}/shadow",
    response_model=ShadowOut,
    responses={**responses(403, 409, 415), 201: {"description": "A shadow started."}},
)
def put_shadow(
    fleet: FleetName,
    body: ShadowIn,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> JSONResponse:
    """Let ``candidate`` decide beside the fleet's learners, without acting, for ``share`` of
    the fleet's people (201 when it starts one; 200 when it changes the running one's share;
    another candidate while one runs: 409). Audit entries ``shadow.start``, ``shadow.share``."""
    found, started = shadows.put_shadow(
        session,
        ctx,
        principal,
        fleet,
        algorithm=body.candidate.algorithm,
        params=body.candidate.params,
        share=body.share,
    )
    out = ShadowOut.model_validate(found).model_dump(mode="json")
    return JSONResponse(out, status_code=201 if started else 200)


@router.delete("/fleets/{fleet}/shadow", response_model=ShadowOut, responses=responses(403, 409))
def stop_shadow(
    fleet: FleetName, session: Session, ctx: ServiceContext, principal: CurrentPrincipal
) -> ShadowOut:
    """Stop the fleet's running shadow; what it decided stays. 409 when none runs. Audit entry
    ``shadow.stop``."""
    return ShadowOut.model_validate(shadows.stop_shadow(session, ctx, principal, fleet))
