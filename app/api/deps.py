"""Annotated dependencies: the request's session (which owns the transaction), the caller, the
service context."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Header, Request
from sqlalchemy.orm import Session

from app.db.session import Database
from app.errors import TooManyRequests
from app.services.auth import authenticate
from app.services.context import Principal, ServiceContext

from .middleware import KeyRateLimiter

__all__ = ["ContextDep", "CurrentPrincipal", "SessionDep"]

_WRITES = {"POST", "PUT", "PATCH", "DELETE"}
# GET routes that write nonetheless: an export is an admin action and leaves an audit entry.
_AUDITED_READS = {"export_model"}


def get_session(request: Request) -> Iterator[Session]:
    """One transaction per request: committed when the route returns, rolled back if it raises.

    Writes start as write transactions (SQLite: ``BEGIN IMMEDIATE``). The commit happens before
    the response is sent (``scope="function"``), so a client never sees a success that was not
    stored; the learner cache is refreshed only after the commit.
    """
    db: Database = request.app.state.db
    route = request.scope.get("route")
    write = request.method in _WRITES or getattr(route, "name", None) in _AUDITED_READS
    with db.transaction(write=write) as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session, scope="function")]


def get_context(request: Request) -> ServiceContext:
    ctx: ServiceContext = request.app.state.ctx
    return ctx


ContextDep = Annotated[ServiceContext, Depends(get_context)]


def current_principal(
    request: Request,
    session: SessionDep,
    authorization: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> Principal:
    """The caller, once its key is known and within its rate limit (else 401 / 429)."""
    principal = authenticate(session, authorization)
    limiter: KeyRateLimiter = request.app.state.limiter
    wait = limiter.acquire(principal.key_id)
    if wait:
        raise TooManyRequests(f"This API key is over its rate limit ({limiter.rate:g} requests "
                              f"a second); retry in {wait} s.", retry_after=wait)
    return principal


CurrentPrincipal = Annotated[Principal, Depends(current_principal)]
