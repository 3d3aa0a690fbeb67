from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Request, Response
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute
from app.api.errors import responses
from app.schemas.common import CLIENT_ID_PATTERN
from app.schemas.profile import CorrectionIn, CorrectionList, CorrectionOut, ProfileOut
from app.services import corrections
from app.services import profile as service
from app.services.context import ServiceContext

from ._common import REPLAY_HEADER, Fleet, IdRule, UserId, no_content, record_read

router = APIRouter(prefix="/v1/users/{user_id}", tags=["profile"], route_class=TransactionalRoute)

CorrectionId = Annotated[
    str, Path(pattern=CLIENT_ID_PATTERN, description="The correction_id it was made with."), IdRule
]


@router.get("/profile", response_model=ProfileOut, responses=responses(404))
def get_profile(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    request: Request,
    fleet: Fleet = None,
) -> ProfileOut:
    """What Attune believes the person wants in each context, how sure it is, what the robot
    will do there, and the staff corrections in force, in plain words (a staff or admin read
    is recorded)."""
    out = service.profile_view(session, ctx, principal, user_id, fleet=fleet)
    record_read(request, principal, user_id, fleet, "profile")
    return out


@router.post(
    "/corrections",
    status_code=201,
    response_model=CorrectionOut,
    responses={
        200: {
            "model": CorrectionOut,
            "headers": REPLAY_HEADER,
            "description": "Idempotent replay of an earlier correction_id.",
        },
        **responses(403, 404, 409, 415),
    },
)
def add_correction(
    user_id: UserId,
    body: CorrectionIn,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    fleet: Fleet = None,
) -> JSONResponse:
    """Correct what was learned about the person in one context (staff of the fleet, admin):
    they prefer a service and detail there, the robot must avoid a service (or a detail)
    there, or stay quiet there."""
    out, created = corrections.add_correction(session, ctx, principal, user_id, body, fleet=fleet)
    headers = {} if created else {"Idempotent-Replay": "true"}
    return JSONResponse(
        out.model_dump(mode="json"), status_code=201 if created else 200, headers=headers
    )


@router.get("/corrections", response_model=CorrectionList, responses=responses(404))
def list_corrections(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    request: Request,
    fleet: Fleet = None,
) -> CorrectionList:
    """The person's corrections, lifted ones too, oldest first, with author, time, note and
    status (a staff or admin read is recorded)."""
    out = corrections.list_corrections(session, ctx, principal, user_id, fleet=fleet)
    record_read(request, principal, user_id, fleet, "corrections")
    return out


@router.delete(
    "/corrections/{correction_id}",
    status_code=204,
    response_class=Response,
    responses=responses(403, 404),
)
def lift_correction(
    user_id: UserId,
    correction_id: CorrectionId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    fleet: Fleet = None,
) -> Response:
    """Lift a correction (staff of the fleet, admin); lifting a lifted one changes nothing."""
    corrections.lift_correction(session, ctx, principal, user_id, correction_id, fleet=fleet)
    return no_content()
