from __future__ import annotations

import logging

from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute
from app.api.errors import responses
from app.api.middleware import error_body
from app.db import migrate
from app.db.session import Database
from app.schemas.models import FleetMissionOut
from app.services import missions
from app.services.context import ServiceContext

from ._common import MissionFleet

router = APIRouter(tags=["service"], route_class=TransactionalRoute)
log = logging.getLogger("attune.api")


@router.get("/v1/mission", response_model=FleetMissionOut, responses=responses(403))
def get_mission(
    session: Session, ctx: ServiceContext, principal: CurrentPrincipal, fleet: MissionFleet = None
) -> FleetMissionOut:
    """Your fleet's mission in force (situations, time slots, services, rewards), with its
    version: what robots negotiate about and what the learners' tables are laid out for."""
    return FleetMissionOut.model_validate(missions.fleet_mission(session, ctx, principal, fleet))


@router.get(
    "/healthz", responses={200: {"content": {"application/json": {"example": {"status": "ok"}}}}}
)
def healthz() -> dict[str, str]:
    """200 while the process runs."""
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "Database down or schema behind."}})
def readyz(request: Request) -> JSONResponse:
    """200 when the database answers and the schema is at the latest migration, else 503."""
    db: Database = request.app.state.db
    try:
        current = migrate.current_revision(db.engine)
    except Exception as exc:  # any failure to reach the database means "not ready"
        log.warning("readiness: database unreachable: %s", exc)
        return JSONResponse(
            error_body("ServiceUnavailable", "The database does not answer."), status_code=503
        )
    head = migrate.head_revision()
    if current != head:
        where = "has no schema yet" if current is None else f"is at schema {current}"
        return JSONResponse(
            error_body(
                "ServiceUnavailable", f"The database {where}, not {head}; run `attune db upgrade`."
            ),
            status_code=503,
        )
    return JSONResponse({"status": "ready", "schema": current})


@router.get(
    "/metrics",
    response_class=Response,
    responses={
        200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "Prometheus text format."}
    },
)
def metrics(request: Request) -> Response:
    """Request counts and latencies per route; decisions and outcomes per action kind."""
    return Response(request.app.state.metrics.render(), media_type=CONTENT_TYPE_LATEST)
