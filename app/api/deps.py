"""Annotated dependencies: the request's session, the caller, the service context.

A request costs the event loop one hop to the thread pool for the caller's key (one read
statement of its own) and one for the route, whose whole transaction runs in that one thread
(:class:`TransactionalRoute`): between the first statement and the commit nothing waits for the
event loop, so a writer holds a user's lock (and SQLite's write lock) only while it works.
"""

from __future__ import annotations

import functools
import inspect
import logging
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import AbstractContextManager
from typing import Annotated, Any

from fastapi import Depends, Header, Request, Response, params
from fastapi.routing import APIRoute
from sqlalchemy.orm import Session

from app import logs
from app.db.session import Database
from app.errors import TooManyRequests, UnsupportedMediaType
from app.services.auth import authenticate
from app.services.context import Principal, ServiceContext

from .middleware import KeyRateLimiter

__all__ = ["ContextDep", "CurrentPrincipal", "SessionDep", "TransactionalRoute", "single_read",
           "writes"]

log = logging.getLogger("attune.api")

_WRITES = {"POST", "PUT", "PATCH", "DELETE"}
_WRITE_MARK = "__attune_writes__"
_DB = "attune_db"


def writes(endpoint: Callable[..., Any]) -> Callable[..., Any]:
    """Mark a GET route that writes nonetheless (an admin action that leaves an audit entry):
    its transaction is a write transaction."""
    setattr(endpoint, _WRITE_MARK, True)
    return endpoint


async def get_session(request: Request) -> AsyncIterator[Session]:
    """The request's session, not yet begun: the route's own thread runs its transaction
    (``TransactionalRoute``), committed before the response is sent, or rolled back if the
    route raises; the learner cache is refreshed only after the commit.

    Writes are write transactions (SQLite: ``BEGIN IMMEDIATE``); so is a route marked with
    :func:`writes`.
    """
    db: Database = request.app.state.db
    route = request.scope.get("route")
    write = request.method in _WRITES or getattr(getattr(route, "endpoint", None),
                                                 _WRITE_MARK, False)
    session = db.session(write=write)
    session.info[_DB] = (db, write)
    try:
        yield session
    finally:
        if session.in_transaction():  # a route outside TransactionalRoute: never commit it
            log.error("the session of %s %s was used outside its route's transaction; "
                      "rolled back", request.method, request.url.path)
        session.close()


SessionDep = Annotated[Session, Depends(get_session, scope="function")]


def _in_transaction(endpoint: Callable[..., Any]) -> Callable[..., Any]:
    if inspect.iscoroutinefunction(endpoint) or \
            "session" not in inspect.signature(endpoint).parameters:
        return endpoint

    @functools.wraps(endpoint)
    def run(*args: Any, **kwargs: Any) -> Any:
        session: Session = kwargs["session"]
        db, write = session.info[_DB]
        with db.within(session, write=write):
            return endpoint(*args, **kwargs)

    return run


def is_json(content_type: str | None) -> bool:
    """``application/json`` or ``application/<anything>+json``, parameters aside."""
    if not content_type:
        return False
    kind = content_type.split(";", 1)[0].strip().lower()
    return kind == "application/json" or (kind.startswith("application/")
                                          and kind.endswith("+json"))


class TransactionalRoute(APIRoute):
    """A route whose ``session`` parameter's transaction runs inside the route's own call (in
    the thread pool): first statement, work, commit and after-commit callbacks in one thread.

    A route that takes a JSON body refuses a non-empty body sent as anything but JSON (another
    Content-Type, or none) with 415, before reading it as JSON; an empty body is left to the
    route (422 where the body is required, the defaults where it is optional).
    """

    def __init__(self, path: str, endpoint: Callable[..., Any], **kwargs: Any) -> None:
        super().__init__(path, _in_transaction(endpoint), **kwargs)

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        body = self.body_field
        if body is None or isinstance(body.field_info, params.Form):
            return handler

        async def json_only(request: Request) -> Response:
            content_type = request.headers.get("content-type")
            if not is_json(content_type) and await request.body():
                came = (f"as {content_type.split(';', 1)[0].strip()!r}" if content_type
                        else "without a Content-Type")
                raise UnsupportedMediaType("The body must be JSON, sent with Content-Type: "
                                           f"application/json; this one came {came}.")
            return await handler(request)

        return json_only


async def get_context(request: Request) -> ServiceContext:
    ctx: ServiceContext = request.app.state.ctx
    return ctx


ContextDep = Annotated[ServiceContext, Depends(get_context)]


def single_read(request: Request) -> AbstractContextManager[Session]:
    """A session for one read statement of its own, outside any transaction (the caller's
    key, looked up before the route runs)."""
    db: Database = request.app.state.db
    return db.single_read()


def current_principal(
    request: Request,
    authorization: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> Principal:
    """The caller, once its key is known and within its rate limit (else 401 / 429).

    The key is read by a statement of its own, so the route's transaction begins only in the
    route.
    """
    with single_read(request) as session:
        principal = authenticate(session, authorization)
    ctx = logs.current()
    if ctx is not None:  # for the access line
        ctx.key_id = principal.key_id
    limiter: KeyRateLimiter = request.app.state.limiter
    wait = limiter.acquire(principal.key_id)
    if wait:
        raise TooManyRequests(f"This API key is over its rate limit ({limiter.rate:g} requests "
                              f"a second); retry in {wait} s.", retry_after=wait)
    return principal


CurrentPrincipal = Annotated[Principal, Depends(current_principal)]
