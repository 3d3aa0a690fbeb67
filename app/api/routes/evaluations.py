"""Evaluations of candidate learners on a fleet's logs, as background jobs (the fleet's staff,
admins): :mod:`app.services.evaluation_jobs`."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute, writes
from app.api.errors import responses
from app.schemas.evaluations import EvaluationIn, EvaluationList, EvaluationOut
from app.services import evaluation_jobs as jobs
from app.services.context import ServiceContext

from ._common import REPLAY_HEADER, FleetName, Limit, QueryBool

EvaluationId = Annotated[
    str,
    Path(
        max_length=40,
        description="The evaluation's id (ev_...).",
        examples=["ev_0123456789abcdef0123456789abcdef"],
    ),
]
Cursor = Annotated[
    str | None,
    Query(
        pattern=r"^ev_[0-9a-f]{32}$",
        description="The `next_cursor` of the previous page, passed back unchanged; treat it as "
        "opaque. A value that is not of the shape this API returns (the pattern) is refused "
        "with 422, and so is one that names no evaluation of the fleet.",
    ),
]

router = APIRouter(prefix="/v1/admin", tags=["evaluations"], route_class=TransactionalRoute)


def _body(found: dict[str, Any]) -> dict[str, Any]:
    return EvaluationOut.model_validate(found).model_dump(mode="json")


def _location(request: Request, fleet: str, evaluation_id: str) -> str:
    root = request.scope.get("root_path", "")
    return f"{root}/v1/admin/fleets/{fleet}/evaluations/{evaluation_id}"


@router.post(
    "/fleets/{fleet}/evaluations",
    status_code=202,
    response_model=EvaluationOut,
    responses={**responses(403, 404, 409, 415), 200: {"headers": REPLAY_HEADER}},
)
def start_evaluation(
    fleet: FleetName,
    body: EvaluationIn,
    request: Request,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> JSONResponse:
    """Start an evaluation of candidate learners on the fleet's logged decisions (the fleet's
    staff, admins): a background job, queued now (202, ``Location`` of the job) and run by the
    service; read it with ``GET``. One evaluation of a fleet at a time: 409 names the one in
    the way. Idempotent on ``request_id`` (200 and ``Idempotent-Replay: true``). Audit entry
    ``evaluation.start``. 404: no person of the fleet yet."""
    wanted = jobs.asked(
        body.request_id,
        [c.model_dump() for c in body.candidates],
        since=body.since,
        until=body.until,
        estimator=body.estimator,
    )
    found, replay = jobs.start(
        session,
        ctx,
        principal,
        fleet,
        wanted,
        runner=getattr(request.app.state, "evaluations", None),
    )
    headers = {"Location": _location(request, fleet, found["evaluation_id"])}
    if replay:
        headers["Idempotent-Replay"] = "true"
    return JSONResponse(_body(found), status_code=200 if replay else 202, headers=headers)


@router.get(
    "/fleets/{fleet}/evaluations", response_model=EvaluationList, responses=responses(403, 422)
)
def list_evaluations(
    fleet: FleetName,
    session: Session,
    principal: CurrentPrincipal,
    limit: Limit = 20,
    cursor: Cursor = None,
) -> EvaluationList:
    """The fleet's evaluations, newest first, with their results but without per-person rows
    (the fleet's staff, admins)."""
    return EvaluationList.model_validate(
        jobs.list_for_fleet(session, principal, fleet, limit=limit, cursor=cursor)
    )


@router.get(
    "/fleets/{fleet}/evaluations/{evaluation_id}",
    response_model=EvaluationOut,
    responses=responses(403, 404),
)
@writes  # each person its result names is recorded as looked at
def get_evaluation(
    fleet: FleetName,
    evaluation_id: EvaluationId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    persons: QueryBool = True,
) -> EvaluationOut:
    """An evaluation: its status and progress, and once done its result: per candidate the
    estimate, its interval, the effective sample size and the difference with what the robots
    earn now, in words; what the robots earn now; and per person (``persons=false`` leaves
    them out, and records no look at anyone). The fleet's staff, admins."""
    return EvaluationOut.model_validate(
        jobs.get(session, ctx, principal, fleet, evaluation_id, persons=persons)
    )


@router.post(
    "/fleets/{fleet}/evaluations/{evaluation_id}/cancel",
    response_model=EvaluationOut,
    responses=responses(403, 404),
)
def cancel_evaluation(
    fleet: FleetName,
    evaluation_id: EvaluationId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> EvaluationOut:
    """Cancel an evaluation (the fleet's staff, admins): a queued one at once, a running one
    after the person in hand (``cancel_requested`` true until then). An evaluation already
    finished stays as it is. Audit entry ``evaluation.cancel``."""
    return EvaluationOut.model_validate(jobs.cancel(session, ctx, principal, fleet, evaluation_id))
