from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Query, Request, Response
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute, writes
from app.api.errors import responses
from app.schemas.models import ModelOut, StatsOut
from app.services import models as service
from app.services import views
from app.services.context import ServiceContext
from app.services.users import fleet_of

from ._common import Fleet, Last, UserId, no_content, record_read

router = APIRouter(prefix="/v1/users/{user_id}", tags=["models"], route_class=TransactionalRoute)


@router.get("/model", response_model=ModelOut, responses=responses(404))
def get_model(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    request: Request,
    time_slot: Annotated[str | None, Query(max_length=64)] = None,
    situation: Annotated[str | None, Query(max_length=64)] = None,
    fleet: Fleet = None,
) -> ModelOut:
    """What the learner believes now, per context, state and action (a staff or admin read
    is recorded)."""
    out = service.model_view(
        session, ctx, principal, user_id, time_slot=time_slot, situation=situation, fleet=fleet
    )
    record_read(request, principal, user_id, fleet, "model")
    return out


@router.get("/stats", response_model=StatsOut, responses=responses(404))
def get_stats(
    user_id: UserId,
    session: Session,
    principal: CurrentPrincipal,
    request: Request,
    last: Last = None,
    fleet: Fleet = None,
) -> StatsOut:
    """The paper's metrics over the user's last N episodes (all by default; a staff or admin
    read is recorded)."""
    out = service.stats(session, principal, user_id, last=last, fleet=fleet)
    record_read(request, principal, user_id, fleet, "stats")
    return out


@router.delete("/model", status_code=204, response_class=Response, responses=responses(403, 404))
def reset_model(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    fleet: Fleet = None,
    corrections: Annotated[
        Literal["keep", "drop"],
        Query(
            description="The staff corrections in force: kept by default, or dropped too.",
        ),
    ] = "keep",
) -> Response:
    """Forget what was learned, keep the history and, unless asked, the staff corrections
    (staff of the fleet, admin)."""
    service.reset_model(
        session, ctx, principal, user_id, fleet=fleet, drop_corrections=corrections == "drop"
    )
    return no_content()


@router.get("/model/export", responses=responses(403, 404))
@writes  # an export leaves an audit entry
def export_model(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    fleet: Fleet = None,
) -> dict[str, Any]:
    """The model as a self-describing document that PUT /model accepts back (staff of the
    fleet, admin; audited, and recorded as a read)."""
    out = service.export_model(session, ctx, principal, user_id, fleet=fleet)
    views.add(
        session,
        ctx.settings,
        principal,
        fleet=fleet_of(principal, fleet, user_id),
        user_id=user_id,
        what="export",
    )
    return out


@router.put("/model", response_model=ModelOut, responses=responses(403, 404, 415))
def import_model(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    doc: Annotated[
        dict[str, Any],
        Body(
            description="A document from GET /model/export.",
            examples=[
                {
                    "format": "attune.learner-state",
                    "format_version": 1,
                    "algorithm": "hri",
                    "params": {"tau": 0.01},
                    "mission": {"name": "office", "fingerprint": "sha256:..."},
                    "version": 412,
                    "episodes": 87,
                    "arrays": {
                        "visits": {
                            "dtype": "<i8",
                            "shape": [16, 30],
                            "encoding": "zlib+base64",
                            "data": "...",
                        }
                    },
                    "pending": [],
                }
            ],
        ),
    ],
    fleet: Fleet = None,
) -> ModelOut:
    """Replace the model with an exported document (staff of the fleet, admin); 422 for
    another format or mission."""
    return service.import_model(session, ctx, principal, user_id, doc, fleet=fleet)
