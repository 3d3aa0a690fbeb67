"""What a route gets besides its parameters: the caller, the request's session and the service
context.

A request costs the event loop one hop to the thread pool, for the route, whose whole
transaction runs in that one call (:class:`TransactionalRoute`): between the first statement and
the commit nothing waits for the event loop, so a writer holds a user's lock (and SQLite's write
lock) only while it works. The caller is known before that, on the event loop, from the worker's
key cache (a key is looked up in the database, in the thread pool, only when the cache does not
have it). The robots' short writes (:func:`inline`) skip the hop when they can start at once.
"""

from __future__ import annotations

import asyncio
import functools
import inspect
import json
from collections.abc import Callable, Coroutine, Iterator
from typing import Annotated, Any
from urllib.parse import parse_qsl

import orjson
from anyio import to_thread
from fastapi import Depends, Header, Request, Response, params
from fastapi.concurrency import run_in_threadpool
from fastapi.routing import APIRoute
from sqlalchemy.orm import Session

from app import logs
from app.db.session import Database, LockBusy
from app.errors import TooManyRequests, UnsupportedMediaType, ValidationFailed
from app.services.auth import authenticate, bearer_digest
from app.services.context import KeyCache, Principal, ServiceContext

from .middleware import KeyRateLimiter

__all__ = [
    "CurrentPrincipal",
    "RequestSession",
    "TransactionalRoute",
    "inline",
    "nul_fields",
    "principal_of",
    "refuse_nul",
    "writes",
]

RequestSession = Session
"""The annotation of an endpoint's ``session`` parameter (the route class gives it)."""

_WRITES = {"POST", "PUT", "PATCH", "DELETE"}
_WRITE_MARK = "__attune_writes__"
_INJECTED = ("session", "ctx")
_INLINE_MARK = "__attune_inline__"


def inline(endpoint: Callable[..., Any]) -> Callable[..., Any]:
    """Mark a short write (a robot's episode start or outcome): it runs on the event loop when
    it can start at once, else in the thread pool as every other request. On SQLite it joins
    the turn's write group (``Database.join_group``); on PostgreSQL it runs on the worker's
    inline connection and takes the user's lock only if it is free (``Database.inline``)."""
    setattr(endpoint, _INLINE_MARK, True)
    return endpoint


def writes(endpoint: Callable[..., Any]) -> Callable[..., Any]:
    """Mark a GET route that writes nonetheless (an admin action that leaves an audit entry):
    its transaction is a write transaction."""
    setattr(endpoint, _WRITE_MARK, True)
    return endpoint


NUL = "\x00"
NUL_MESSAGE = "Text must not contain the NUL character (U+0000)"
_NUL_KEY = "attune.nul_fields"  # in the request's ASGI scope: where the route found NULs


def _nul_locations(value: Any, loc: list[str]) -> Iterator[list[str]]:
    """Where in a decoded JSON value a string (or an object's key) holds U+0000."""
    if isinstance(value, str):
        if NUL in value:
            yield loc
    elif isinstance(value, dict):
        for key, item in value.items():
            if NUL in key:
                yield [*loc, key]
            yield from _nul_locations(item, [*loc, key])
    elif isinstance(value, list):
        for i, item in enumerate(value):
            yield from _nul_locations(item, [*loc, str(i)])


def _is_form(content_type: str | None) -> bool:
    kind = (content_type or "").split(";", 1)[0].strip().lower()
    return kind == "application/x-www-form-urlencoded"


async def nul_fields(request: Request) -> list[list[str]]:
    """Where the request's texts hold the NUL character U+0000: every path parameter, query
    parameter and body field (of a JSON body at any depth, keys too, or of a console form),
    as the ``loc`` of a 422. A JSON body can hold it only as the escape ``\\u0000``, a form
    only as ``%00``: a body without those bytes is not parsed again (every robot request
    passes here; the common case costs a few lookups and byte searches)."""
    scope = request.scope
    found: list[list[str]] = []
    for name, value in scope.get("path_params", {}).items():
        if isinstance(value, str) and NUL in value:
            found.append(["path", name])
    if b"%00" in scope.get("query_string", b""):
        found += [
            ["query", name]
            for name, value in request.query_params.multi_items()
            if NUL in name or NUL in value
        ]
    if scope["method"] not in ("GET", "HEAD"):
        raw = await request.body()  # the route reads it anyway; Starlette keeps it
        if b"\\u0000" in raw and is_json(request.headers.get("content-type")):
            try:
                doc = json.loads(raw)
            except ValueError:  # not JSON: the route's own handling refuses it
                doc = None
            found += list(_nul_locations(doc, ["body"]))
        elif b"%00" in raw and _is_form(request.headers.get("content-type")):
            try:
                pairs = parse_qsl(raw.decode("utf-8"), keep_blank_values=True)
            except (UnicodeDecodeError, ValueError):
                pairs = []
            found += [["form", name] for name, value in pairs if NUL in name or NUL in value]
    return found


def refuse_nul(request: Request) -> None:
    """422 naming every place of the request whose text holds U+0000 (found by
    :func:`nul_fields` when the route received the request). PostgreSQL cannot store it in a
    text and SQLite would: one rule at the edge, applied by every route's transaction wrapper
    after the key and the request's shape were checked and before the endpoint's first SQL
    statement, answers the same on both engines."""
    found: list[list[str]] | None = request.scope.get(_NUL_KEY)
    if found:
        raise ValidationFailed(
            f"{'.'.join(found[0])}: {NUL_MESSAGE}.",
            fields=[{"loc": loc, "msg": NUL_MESSAGE, "type": "string_nul"} for loc in found],
        )


def _in_transaction(
    endpoint: Callable[..., Any], *, write: bool, inline: bool
) -> Callable[..., Any]:
    """``endpoint`` with its ``session`` and ``ctx`` parameters filled in by the route: the
    request's session, whose transaction is the endpoint's whole call (committed at the end,
    rolled back if it raises; the after-commit callbacks run once it committed), and the
    service context. FastAPI sees the endpoint's other parameters, plus the request. The
    endpoint's call starts by refusing NUL characters in the request's texts
    (:func:`refuse_nul`): after the key and the request's shape, before any SQL of it."""
    if inspect.iscoroutinefunction(endpoint):
        return endpoint
    signature = inspect.signature(endpoint)
    injected = [name for name in _INJECTED if name in signature.parameters]
    if not injected:
        return endpoint
    params = [p for p in signature.parameters.values() if p.name not in _INJECTED]
    own_request = any(p.name == "request" for p in params)
    if not own_request:
        params.append(
            inspect.Parameter("request", inspect.Parameter.KEYWORD_ONLY, annotation=Request)
        )

    def arguments(kwargs: dict[str, Any]) -> tuple[dict[str, Any], Request]:
        """The endpoint's arguments from the route's (the request kept only if the endpoint
        takes it, the context filled in; the session is the caller's), and the request."""
        call = dict(kwargs)
        request: Request = call["request"] if own_request else call.pop("request")
        if "ctx" in injected:
            call["ctx"] = request.app.state.ctx
        return call, request

    @functools.wraps(endpoint)
    async def run_here_or_in_thread(**kwargs: Any) -> Any:
        call, request = arguments(kwargs)
        refuse_nul(request)
        db: Database = request.app.state.db
        group = db.join_group(asyncio.get_running_loop())
        if group is None:
            if db.writes_inline:
                try:
                    with db.inline() as session:
                        return endpoint(**call, session=session)
                except LockBusy:  # the user's lock is taken: wait for it in the thread pool
                    pass
            elif not db.is_sqlite:  # the round trip is too long to wait for on the loop
                db.pooled += 1
            return await run_in_threadpool(run, **kwargs)
        failure: Exception | None = None
        try:
            with group.member() as session:
                result = endpoint(**call, session=session)
        except Exception as exc:  # answered once the group committed: it saw the group's writes
            failure = exc
        await group.committed()
        if failure is not None:
            raise failure
        return result

    @functools.wraps(endpoint)
    def run(**kwargs: Any) -> Any:
        call, request = arguments(kwargs)
        refuse_nul(request)
        if "session" not in injected:
            return endpoint(**call)
        db: Database = request.app.state.db
        with db.transaction(write=write) as session:
            return endpoint(**call, session=session)

    run.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
    if not (write and inline):
        return run
    run_here_or_in_thread.__signature__ = run.__signature__  # type: ignore[attr-defined]
    return run_here_or_in_thread


def is_json(content_type: str | None) -> bool:
    """``application/json`` or ``application/<anything>+json``, parameters aside."""
    if not content_type:
        return False
    kind = content_type.split(";", 1)[0].strip().lower()
    return kind == "application/json" or (
        kind.startswith("application/") and kind.endswith("+json")
    )


class TransactionalRoute(APIRoute):
    """A route whose endpoint takes ``session: Session`` and/or ``ctx: ServiceContext``, given
    by the route (not by dependencies): the session's transaction is the endpoint's whole call,
    in the thread pool. Routes of POST, PUT, PATCH and DELETE, and GET routes marked with
    :func:`writes`, run write transactions (SQLite: ``BEGIN IMMEDIATE``); the others read.

    A route that takes a JSON body refuses a non-empty body sent as anything but JSON (another
    Content-Type, or none) with 415, before reading it as JSON; an empty body is left to the
    route (422 where the body is required, the defaults where it is optional). Every route
    looks for NUL characters in the request's texts as it receives it (:func:`nul_fields`),
    and the endpoint refuses them (:func:`refuse_nul`).
    """

    def __init__(self, path: str, endpoint: Callable[..., Any], **kwargs: Any) -> None:
        methods = {m.upper() for m in kwargs.get("methods") or ("GET",)}
        write = bool(methods & _WRITES) or getattr(endpoint, _WRITE_MARK, False)
        inline = getattr(endpoint, _INLINE_MARK, False)
        super().__init__(path, _in_transaction(endpoint, write=write, inline=inline), **kwargs)

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = self._json_handler()

        async def looked_at(request: Request) -> Response:
            # Where its texts hold NUL characters; refused once the key and the request's
            # shape are checked, just before the endpoint (refuse_nul).
            request.scope[_NUL_KEY] = await nul_fields(request)
            return await handler(request)

        return looked_at

    def _json_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        body = self.body_field
        if body is None or isinstance(body.field_info, params.Form):
            return handler

        async def json_only(request: Request) -> Response:
            content_type = request.headers.get("content-type")
            if not is_json(content_type) and await request.body():
                came = (
                    f"as {content_type.split(';', 1)[0].strip()!r}"
                    if content_type
                    else "without a Content-Type"
                )
                raise UnsupportedMediaType(
                    "The body must be JSON, sent with Content-Type: "
                    f"application/json; this one came {came}."
                )
            return await handler(request)

        if getattr(self.endpoint, _INLINE_MARK, False):
            return _lean_handler(self, json_only) or json_only
        return json_only


def _lean_handler(
    route: APIRoute, handler: Callable[[Request], Coroutine[Any, Any, Response]]
) -> Callable[[Request], Coroutine[Any, Any, Response]] | None:
    """The robots' writes without FastAPI's general request handling, for a well-formed
    request: a JSON object body sent as ``application/json`` with a Content-Length, valid path
    parameters and no query string are validated with the route's own fields (as FastAPI
    validates them), the caller comes from :func:`current_principal`, and the endpoint is called
    with them. Any other request (another Content-Type or none, a chunked body, a body that is
    not a JSON object orjson reads, a path parameter or body the fields refuse, a query string)
    goes to ``handler``, the route's usual one, which answers it as before: the same errors, in
    the same order. ``None`` if the route takes something this does not resolve."""
    dependant = route.dependant
    body = route.body_field
    principal = [d for d in dependant.dependencies if d.call is current_principal]
    if (
        body is None
        or len(principal) != 1
        or len(dependant.dependencies) != 1
        or dependant.header_params
        or dependant.cookie_params
        or any(q.field_info.is_required() for q in dependant.query_params)
        or dependant.response_param_name
        or dependant.background_tasks_param_name
        or dependant.http_connection_param_name
        or dependant.websocket_param_name
        or dependant.security_scopes_param_name
    ):
        return None
    paths = [(f.alias, f.name, f) for f in dependant.path_params]
    defaults = {q.name: q.default for q in dependant.query_params}
    body_name, principal_name = body.name, principal[0].name
    request_name = dependant.request_param_name
    endpoint = dependant.call
    if not inspect.iscoroutinefunction(endpoint) or principal_name is None:
        return None
    body_loc = ("body",)

    async def lean(request: Request) -> Response:
        headers = request.headers
        content_type = headers.get("content-type")
        if (
            request.scope.get("query_string")
            or "content-length" not in headers
            or content_type is None
            or content_type.split(";", 1)[0].strip().lower() != "application/json"
        ):
            return await handler(request)
        raw = await request.body()  # within the body limit: its Content-Length was checked
        try:
            doc = orjson.loads(raw)
        except orjson.JSONDecodeError:
            return await handler(request)
        if not isinstance(doc, dict):
            return await handler(request)
        values: dict[str, Any] = dict(defaults)
        given = request.path_params
        for alias, name, field in paths:
            value, errors = field.validate(given.get(alias), values, loc=("path", alias))
            if errors:
                return await handler(request)
            values[name] = value
        value, errors = body.validate(doc, values, loc=body_loc)
        if errors:
            return await handler(request)
        values[body_name] = value
        values[principal_name] = await current_principal(
            request, request.headers.get("authorization")
        )
        if request_name is not None:
            values[request_name] = request
        response = await endpoint(**values)
        if not isinstance(response, Response):  # the robots' writes answer with written()
            raise TypeError(f"{route.name} must return a Response")
        return response

    return lean


def _lookup(db: Database, authorization: str | None) -> Principal:
    with db.single_read() as session:
        return authenticate(session, authorization)


async def principal_of(
    request: Request, authorization: str | None, *, cached: bool = True
) -> Principal:
    """Who holds the key of an ``Authorization`` header (401 if nobody).

    A key the worker saw in the last ``ATTUNE_KEY_CACHE_SECONDS`` comes from its cache, on the
    event loop (unless not ``cached``); otherwise it is read by a statement of its own in the
    thread pool.
    """
    ctx: ServiceContext = request.app.state.ctx
    keys: KeyCache = ctx.keys
    digest = bearer_digest(authorization)
    principal = keys.get(digest) if cached else None
    if principal is None:
        principal = await to_thread.run_sync(_lookup, request.app.state.db, authorization)
        keys.put(digest, principal)
    context = logs.current()
    if context is not None:  # for the access line
        context.key_id = principal.key_id
    return principal


async def current_principal(
    request: Request,
    authorization: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> Principal:
    """The caller, once its key is known and within its rate limit (else 401 / 429)."""
    principal = await principal_of(request, authorization)
    limiter: KeyRateLimiter = request.app.state.limiter
    wait = limiter.acquire(principal.key_id)
    if wait:
        raise TooManyRequests(
            f"This API key is over its rate limit ({limiter.rate:g} requests "
            f"a second); retry in {wait} s.",
            retry_after=wait,
        )
    return principal


CurrentPrincipal = Annotated[Principal, Depends(current_principal)]
