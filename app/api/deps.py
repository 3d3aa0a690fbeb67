"""Annotated dependencies: the request's session (which owns the transaction), the caller, the
service context."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Header, Request
from sqlalchemy.orm import Session

from app.db.session import Database
from app.services.auth import authenticate
from app.services.context import Principal, ServiceContext

__all__ = ["ContextDep", "CurrentPrincipal", "SessionDep"]

_WRITES = {"POST", "PUT", "PATCH", "DELETE"}


def get_session(request: Request) -> Iterator[Session]:
    """One transaction per request: committed when the route returns, rolled back if it raises.

    Writes start as write transactions (SQLite: ``BEGIN IMMEDIATE``). The commit happens before
    the response is sent (``scope="function"``), so a client never sees a success that was not
    stored; the learner cache is refreshed only after the commit.
    """
    db: Database = request.app.state.db
    with db.transaction(write=request.method in _WRITES) as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session, scope="function")]


def get_context(request: Request) -> ServiceContext:
    ctx: ServiceContext = request.app.state.ctx
    return ctx


ContextDep = Annotated[ServiceContext, Depends(get_context)]


def current_principal(
    session: SessionDep,
    authorization: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> Principal:
    return authenticate(session, authorization)


CurrentPrincipal = Annotated[Principal, Depends(current_principal)]
