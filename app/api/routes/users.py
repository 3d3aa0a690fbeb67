from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from fastapi.responses import JSONResponse, StreamingResponse
from sqlalchemy.orm import Session

from app.api.deps import CurrentPrincipal, TransactionalRoute, writes
from app.api.errors import responses
from app.api.links import USER_LINKS
from app.schemas.audit import ViewList
from app.schemas.changes import ChangeList
from app.schemas.common import CLIENT_ID_PATTERN
from app.schemas.users import UserIn, UserList, UserOut
from app.services import changes, subject, views
from app.services import users as service
from app.services.context import ServiceContext

from ._common import (
    Fleet,
    IdRule,
    Limit,
    QueryBool,
    SeqCursor,
    UserCursor,
    UserId,
    export_response,
    no_content,
    record_read,
)

router = APIRouter(prefix="/v1/users", tags=["users"], route_class=TransactionalRoute)


@router.put(
    "/{user_id}",
    response_model=UserOut,
    status_code=200,
    responses={
        200: {"links": USER_LINKS},
        201: {"model": UserOut, "description": "Created.", "links": USER_LINKS},
        **responses(403, 404, 409, 415),
    },
)
def put_user(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    body: UserIn | None = None,
    reset_model: Annotated[
        QueryBool,
        Query(
            description="Allow changing the learner of a user with history (forgets what was "
            "learned): true or false, spelled so (staff and admins)."
        ),
    ] = False,
    fleet: Fleet = None,
) -> JSONResponse:
    """Create or update a user of your fleet (idempotent): 201 when created, 200 when
    updated. A robot key may create a user with any field; changing an existing user's fields,
    and reset_model, are for the fleet's staff and admins (403)."""
    out, created = service.put_user(
        session, ctx, principal, user_id, body or UserIn(), reset_model=reset_model, fleet=fleet
    )
    return JSONResponse(out.model_dump(mode="json"), status_code=201 if created else 200)


@router.get("/{user_id}", response_model=UserOut, responses=responses(404))
def get_user(
    user_id: UserId,
    session: Session,
    principal: CurrentPrincipal,
    request: Request,
    fleet: Fleet = None,
) -> UserOut:
    """One user (a staff or admin read is recorded: GET .../views)."""
    out = service.get_user(session, principal, user_id, fleet=fleet)
    record_read(request, principal, user_id, fleet, "user")
    return out


@router.get("", response_model=UserList, responses=responses(404))
def list_users(
    session: Session,
    principal: CurrentPrincipal,
    limit: Limit = 50,
    cursor: UserCursor = None,
    fleet: Annotated[
        str | None,
        Query(
            pattern=CLIENT_ID_PATTERN,
            description="Only this fleet's users (admin keys; other keys list their own fleet, "
            "and naming another is 404).",
        ),
        IdRule,
    ] = None,
) -> UserList:
    """Users of your fleet by user id (admins: of every fleet, by fleet then user id), a page at
    a time."""
    return service.list_users(session, principal, limit=limit, cursor=cursor, fleet=fleet)


@router.delete(
    "/{user_id}", status_code=204, response_class=Response, responses=responses(403, 404)
)
def delete_user(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    fleet: Fleet = None,
) -> Response:
    """Erase a person: their user, history, model, journal, feedback and corrections; the
    audit entries about them keep who did what and when, and nothing of them (staff of the
    fleet, admin)."""
    service.delete_user(session, ctx, principal, user_id, fleet=fleet)
    return no_content()


@router.get("/{user_id}/views", response_model=ViewList, responses=responses(403, 404))
def list_user_views(
    user_id: UserId,
    session: Session,
    principal: CurrentPrincipal,
    limit: Limit = 50,
    cursor: SeqCursor = None,
    fleet: Fleet = None,
) -> ViewList:
    """Who looked at the person's data, newest first: each read by a staff or admin key, of
    the API or the console (staff of the fleet, admin). Robots' reads are not recorded, nor is
    reading this list."""
    return views.list_views(
        session, principal, limit=limit, cursor=cursor, user_id=user_id, fleet=fleet
    )


@router.get("/{user_id}/changes", response_model=ChangeList, responses=responses(403, 404, 422))
def list_person_changes(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    request: Request,
    limit: Limit = 50,
    cursor: SeqCursor = None,
    fleet: Fleet = None,
) -> ChangeList:
    """What changed in what the person wants, newest first: when, in which context, what
    they wanted before and what now, on what evidence, in words (staff of the fleet, admin)."""
    out = changes.person_changes(
        session, ctx, principal, user_id, limit=limit, cursor=cursor, fleet=fleet
    )
    record_read(request, principal, user_id, fleet, "changes")
    return out


@router.get(
    "/{user_id}/export",
    response_class=StreamingResponse,
    responses={
        200: {
            "content": {"application/json": {}},
            "description": "The person's export (docs/api.md, \"A person's export\"), streamed.",
        },
        **responses(403, 404),
    },
)
@writes  # the export leaves an audit entry, and is recorded as a read
def export_person(
    user_id: UserId,
    session: Session,
    ctx: ServiceContext,
    principal: CurrentPrincipal,
    request: Request,
    fleet: Fleet = None,
) -> StreamingResponse:
    """Everything stored about the person, in one JSON document (staff of the fleet, admin):
    who they are, their part in the fleet's prior, the model and what it says in plain words,
    corrections, the audit entries about them, who looked, and every episode with its
    decisions, answers and feedback (streamed, newest first)."""
    started = subject.begin_export(session, ctx, principal, user_id, fleet=fleet)
    return export_response(request, started, ctx)
