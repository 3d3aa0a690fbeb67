from __future__ import annotations

import hmac
import logging
from typing import Annotated

from fastapi import APIRouter, Header, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute
from app.api.errors import ERROR_RESPONSES, responses
from app.api.lifecycle import Drain
from app.api.metrics import Metrics
from app.api.middleware import error_body
from app.db import migrate
from app.db.session import Database
from app.errors import NotFound, Unauthorized
from app.schemas.common import ErrorOut
from app.schemas.models import FleetMissionOut
from app.services import missions
from app.services.context import ServiceContext
from app.settings import Settings

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
    "/livez", responses={200: {"content": {"application/json": {"example": {"status": "ok"}}}}}
)
def livez() -> dict[str, str]:
    """200 while the process answers, also while it shuts down: for liveness probes."""
    return {"status": "ok"}


@router.get(
    "/healthz", responses={200: {"content": {"application/json": {"example": {"status": "ok"}}}}}
)
def healthz() -> dict[str, str]:
    """200 while the process runs (as /livez)."""
    return {"status": "ok"}


@router.get(
    "/readyz",
    responses={503: {"description": "Shutting down, database down, or schema behind."}},
)
def readyz(request: Request) -> JSONResponse:
    """200 when the database answers, the schema is at the latest migration and the service is
    not shutting down, else 503."""
    drain: Drain = request.app.state.drain
    if drain.draining:
        return JSONResponse(
            error_body(
                "ServiceUnavailable",
                "The service is shutting down: it finishes the requests in flight, then stops.",
            ),
            status_code=503,
        )
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
        200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "Prometheus text format."},
        401: {
            "model": ErrorOut,
            "description": "ATTUNE_METRICS_TOKEN is set and the request did not send it.",
            "headers": ERROR_RESPONSES[401]["headers"],
        },
        404: {
            "model": ErrorOut,
            "description": "ATTUNE_METRICS_PORT is set: /metrics is served on that port.",
        },
    },
)
def metrics(
    request: Request, authorization: Annotated[str | None, Header(include_in_schema=False)] = None
) -> Response:
    """The service's metrics: requests, latencies and round trips per route, the worker
    processes, the database pool, the learner cache, the event loop, and the learning's health
    per fleet."""
    settings: Settings = request.app.state.settings
    if settings.metrics_port is not None:
        raise NotFound(
            "Metrics are served on their own port (ATTUNE_METRICS_PORT), not on this one."
        )
    if not metrics_token_matches(settings, authorization):
        raise MetricsUnauthorized(
            "/metrics needs the metrics token: Authorization: Bearer <ATTUNE_METRICS_TOKEN>."
        )
    served: Metrics = request.app.state.metrics
    served.sample()
    return Response(served.render(), media_type=CONTENT_TYPE_LATEST)


class MetricsUnauthorized(Unauthorized):
    def headers(self) -> dict[str, str]:
        return {"WWW-Authenticate": "Bearer"}


def metrics_token_matches(settings: Settings, authorization: str | None) -> bool:
    """True when no token is set, or when ``authorization`` is ``Bearer <the token>``."""
    if settings.metrics_token is None:
        return True
    scheme, _, given = (authorization or "").partition(" ")
    expected = settings.metrics_token.get_secret_value()
    return scheme.lower() == "bearer" and hmac.compare_digest(
        given.strip().encode(), expected.encode()
    )
