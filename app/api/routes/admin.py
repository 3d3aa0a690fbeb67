from __future__ import annotations

import datetime as dt
from typing import Annotated

from fastapi import APIRouter, Path, Query, Response
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute, writes
from app.api.errors import responses
from app.schemas.admin import (
    FleetHistoryIn,
    FleetHistoryOut,
    FleetList,
    FleetPriorIn,
    FleetPriorOut,
    KeyCreated,
    KeyIn,
    KeyList,
)
from app.schemas.audit import AuditList, ViewList
from app.schemas.changes import ChangeList
from app.schemas.common import CLIENT_ID_PATTERN
from app.schemas.models import MissionChanged, MissionChangeIn, MissionVersionList
from app.services import admin, changes, missions, prior, retention, views
from app.services import audit as service
from app.services.context import ServiceContext

from ._common import REPLAY_HEADER, FleetName, IdRule, Limit, SeqCursor, no_content

KeyId = Annotated[
    str,
    Path(max_length=64, description="The key's id (key_...).", examples=["key_0123456789abcdef"]),
]

router = APIRouter(prefix="/v1/admin", tags=["admin"], route_class=TransactionalRoute)


@router.get("/audit", response_model=AuditList, responses=responses(403))
def list_audit(
    session: Session,
    principal: CurrentPrincipal,
    limit: Limit = 50,
    cursor: SeqCursor = None,
) -> AuditList:
    """The audit log, newest first: who (the key), what (user.delete, user.learner,
    user.prior, user.export, model.reset, model.export, model.import, model.rebuild, key.create,
    key.revoke, mission.set, correction.add, correction.lift, fleet.prior, fleet.history,
    fleet.retention), when.
    Admins read every fleet's entries, a fleet's staff its own."""
    return service.list_audit(session, principal, limit=limit, cursor=cursor)


@router.get("/views", response_model=ViewList, responses=responses(403, 404))
def list_views(
    session: Session,
    principal: CurrentPrincipal,
    limit: Limit = 50,
    cursor: SeqCursor = None,
    fleet: Annotated[
        str | None,
        Query(
            pattern=CLIENT_ID_PATTERN,
            description="Only this fleet's (admin keys; staff read their own fleet's, and "
            "naming another is 404).",
        ),
        IdRule,
    ] = None,
) -> ViewList:
    """Who looked at whom, newest first: every read of a person's data by a staff or admin key.
    Admins read every fleet's (or one's, ?fleet=), a fleet's staff its own."""
    return views.list_views(session, principal, limit=limit, cursor=cursor, fleet=fleet)


@router.post("/keys", status_code=201, response_model=KeyCreated, responses=responses(403, 415))
def create_key(body: KeyIn, session: Session, principal: CurrentPrincipal) -> JSONResponse:
    """Make an API key (admin); its secret is in this answer only."""
    made = admin.add_key(session, principal, body)
    return JSONResponse(
        made.model_dump(mode="json"), status_code=201, headers={"Cache-Control": "no-store"}
    )


@router.get("/keys", response_model=KeyList, responses=responses(403))
def list_keys(session: Session, principal: CurrentPrincipal) -> KeyList:
    """Every API key, without secrets (admin)."""
    return admin.keys(session, principal)


@router.delete(
    "/keys/{key_id}", status_code=204, response_class=Response, responses=responses(403, 404)
)
def revoke_key(
    key_id: KeyId, session: Session, ctx: ServiceContext, principal: CurrentPrincipal
) -> Response:
    """Revoke a key (admin): its requests get 401 from now on. Revoking a revoked key changes
    nothing (204 again)."""
    admin.remove_key(session, ctx, principal, key_id)
    return no_content()


@router.get("/fleets", response_model=FleetList, responses=responses(403))
def list_fleets(session: Session, principal: CurrentPrincipal) -> FleetList:
    """The fleets with users or live keys, with their counts of users, keys and episodes
    (admin)."""
    return admin.fleets(session, principal)


@router.get("/fleets/{fleet}/missions", response_model=MissionVersionList, responses=responses(403))
def list_missions(
    fleet: FleetName, session: Session, ctx: ServiceContext, principal: CurrentPrincipal
) -> MissionVersionList:
    """Every version of a fleet's mission, newest first (the fleet's staff, admins)."""
    return MissionVersionList.model_validate(missions.list_missions(session, ctx, principal, fleet))


@router.put(
    "/fleets/{fleet}/mission",
    response_model=MissionChanged,
    responses={**responses(403, 409, 415), 200: {"headers": REPLAY_HEADER}},
)
def set_mission(
    fleet: FleetName,
    body: MissionChangeIn,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> JSONResponse:
    """Give a fleet a new mission (the fleet's staff, admins): a new version, and in the same
    transaction every user's model of the fleet carried to it by names (what exists in both
    versions keeps what was learned; ``renames`` carries it across a rename), and the fleet's
    open episodes closed as ``interrupted``. Idempotent on ``change_id``; a mission equal to
    the one in force changes nothing (``changed`` false). 422 names what is wrong with the
    mission or the renames."""
    renames = body.renames.model_dump() if body.renames is not None else None
    out, replay = missions.set_mission(
        session,
        ctx,
        principal,
        fleet,
        change_id=body.change_id,
        mission_doc=body.mission,
        renames_doc=renames,
    )
    return JSONResponse(out, headers={"Idempotent-Replay": "true"} if replay else None)


@router.get("/fleets/{fleet}/prior", response_model=FleetPriorOut, responses=responses(403))
def get_fleet_prior(
    fleet: FleetName, session: Session, ctx: ServiceContext, principal: CurrentPrincipal
) -> FleetPriorOut:
    """A fleet's prior for newcomers (the fleet's staff, admins): whether it is on, how many of
    its people can contribute per learner, and for which learners it is in force."""
    return FleetPriorOut.model_validate(prior.fleet_prior_view(session, ctx, principal, fleet))


@router.put("/fleets/{fleet}/prior", response_model=FleetPriorOut, responses=responses(403, 415))
def set_fleet_prior(
    fleet: FleetName,
    body: FleetPriorIn,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> FleetPriorOut:
    """Turn a fleet's prior on or off for its next newcomers (the fleet's staff, admins);
    models that started from it keep their start. Audit entry ``fleet.prior`` when it
    changes."""
    return FleetPriorOut.model_validate(
        prior.set_fleet_prior(session, ctx, principal, fleet, enabled=body.enabled)
    )


@router.get("/fleets/{fleet}/history", response_model=FleetHistoryOut, responses=responses(403))
def get_fleet_history(
    fleet: FleetName, session: Session, ctx: ServiceContext, principal: CurrentPrincipal
) -> FleetHistoryOut:
    """How long a fleet keeps its raw history (the fleet's staff, admins)."""
    return FleetHistoryOut.model_validate(retention.history_view(session, ctx, principal, fleet))


@router.put(
    "/fleets/{fleet}/history", response_model=FleetHistoryOut, responses=responses(403, 415, 422)
)
def set_fleet_history(
    fleet: FleetName,
    body: FleetHistoryIn,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
) -> FleetHistoryOut:
    """Set how many days of raw history a fleet keeps (null: everything; the fleet's staff,
    admins). The next retention run folds what is older into the people's models and removes
    it. Audit entry ``fleet.history`` when it changes."""
    return FleetHistoryOut.model_validate(
        retention.set_history(session, ctx, principal, fleet, days=body.history_days)
    )


@router.get("/fleets/{fleet}/changes", response_model=ChangeList, responses=responses(403, 422))
@writes  # each person it names is recorded as looked at
def list_fleet_changes(
    fleet: FleetName,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    since: Annotated[
        dt.datetime | None,
        Query(
            description="Only the changes decided at or after this time (RFC 3339, with an "
            "offset), e.g. a week ago for 'what changed this week'."
        ),
    ] = None,
    limit: Limit = 50,
    cursor: SeqCursor = None,
) -> ChangeList:
    """What changed in what the fleet's people want, newest first (the fleet's staff,
    admins)."""
    return changes.fleet_changes(
        session, ctx, principal, fleet, since=since, limit=limit, cursor=cursor
    )
