"""The ASGI application: ``create_app(settings)`` wires the database, routes and handlers."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from anyio import to_thread
from fastapi import FastAPI
from fastapi.routing import APIRoute

from app.api.docs import install_docs
from app.api.errors import install_error_handlers
from app.api.lifecycle import STATE_KEY, Drain
from app.api.metrics import Metrics
from app.api.middleware import (
    BodyLimitMiddleware,
    HeadMiddleware,
    InFlightLimitMiddleware,
    KeyRateLimiter,
    MetricsMiddleware,
    ProxyMiddleware,
    RequestContextMiddleware,
    TrustedProxies,
)
from app.api.routes import (
    admin,
    episodes,
    evaluations,
    meta,
    models,
    profile,
    rollouts,
    users,
)
from app.console import mount_console
from app.db.session import Database
from app.services import rollouts as rollout_service
from app.services import shadows as shadow_service
from app.services.context import ServiceContext
from app.services.evaluation_jobs import EvaluationRunner
from app.services.periodic import Periodic
from app.services.retention_runs import DailyRetention
from app.settings import Settings, get_settings, mask_url

__all__ = ["app", "create_app", "package_version"]

DESCRIPTION = """
Attune learns what each person a robot fleet serves wants, and when, from their feedback, and
tells any robot what to do next for that person.

A robot reports an **event** near a person (`POST /v1/users/{user_id}/episodes`) and gets a
**decision**; it carries the action out and reports what the person did
(`POST /v1/episodes/{episode_id}/outcomes`), getting the next decision, until the episode ends.
Writes are idempotent: repeat them with the same ids after a network failure.

Every request but `/livez`, `/healthz`, `/readyz` and `/metrics` needs `Authorization: Bearer
<api key>`; keys are made with `attune keys create` (`/metrics` may need the deployment's metrics
token instead).

Errors are `{"error": "...", "detail": "...", "request_id": "..."}` (plus `fields` on a 422).
Every response carries an `X-Request-ID` header: the caller's own when it sent a valid one
(1 to 128 letters, digits and `. _ : -`) from an address the deployment trusts
(`ATTUNE_FORWARDED_ALLOW_IPS`: by default the service's own machine, where a reverse proxy
passes the caller's id on), else one the service made (32 hexadecimal characters). The same
id is in the error body and in the service's log lines of that request.

Request bodies are JSON: a body sent with another `Content-Type` (`text/plain`, a form,
multipart) or with none is refused with 415 `UnsupportedMediaType`; a request whose body is
optional may send no body at all. Every `GET` also answers `HEAD` (same status and headers, no
body), and a 405 lists the path's methods in its `Allow` header. Integer query parameters are
bounded (`limit` 1 to 500, `last` 1 to 1000000); outside the range, 422 names the parameter and
its range.
"""


def package_version() -> str:
    """The installed ``attune`` distribution's version, as ``attune --version`` prints it
    (``unknown`` when the code runs from a folder that was never installed): the OpenAPI
    schema's ``info.version``."""
    try:
        return version("attune")
    except PackageNotFoundError:
        return "unknown"


def _operation_id(route: APIRoute) -> str:
    """Stable client method names: the route function's name (``start_episode``)."""
    return route.name


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()
    db = Database(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[dict[str, Any]]:
        # An admitted request may hold a pool thread while it waits for a user's lock or a
        # connection; with more threads than admitted requests (InFlightLimitMiddleware), the
        # holder of the lock always finds a thread to finish on. The 8 spare threads serve the
        # probes and /metrics, which are not counted.
        to_thread.current_default_thread_limiter().total_tokens = settings.max_in_flight + 8
        logging.getLogger("attune").info("serving with database %s", mask_url(db.url))
        # The worker's own figures (CPU, memory, pool, cache, event loop), sampled every second.
        tasks = [asyncio.create_task(app.state.metrics.watch(), name="attune-metrics")]
        if settings.loop_watch_ms > 0:  # how long the event loop is held up, at a fine grain
            watchdog = app.state.metrics.watch_stalls(settings.loop_watch_ms)
            tasks.append(asyncio.create_task(watchdog, name="attune-loop-watch"))
        if db.probes_round_trip:
            # Where the robots' writes run (ATTUNE_PG_INLINE_WRITES=auto): measured before the
            # first request, then every few seconds.
            await asyncio.to_thread(db.probe_round_trip)
            tasks.append(asyncio.create_task(db.watch_round_trip(), name="attune-round-trip"))
        runner = app.state.evaluations  # started by the first evaluation it is given
        mover = app.state.rollout_mover
        mover.kick()  # the moves a stopped process left, if any
        guard = None
        if settings.rollout_guard_minutes > 0:
            # Every running rollout looked at, and rolled back when its candidate is worse.
            guard = Periodic(
                db,
                rollout_service.LEASE,
                settings.rollout_guard_minutes * 60.0,
                lambda: rollout_service.check_guard(db, app.state.ctx),
                stopping=lambda: app.state.drain.draining,
            )
            guard.start()
        shadows = None
        if settings.shadow_seconds > 0:
            # The shadows' candidates decide at the decisions of the episodes that ended.
            # In a process of its own, started while a shadow runs: its replays do not
            # share this worker's interpreter with the robots' requests.
            shadows = shadow_service.PassProcess(
                db, settings, stopping=lambda: app.state.drain.draining
            )
            shadows.start()
        daily = None
        if settings.retention_at is not None:
            # The retention run at the set time, in a thread of its own (ATTUNE_RETENTION_AT):
            # each worker wakes then, the one that takes the lease runs it. The drain stops it.
            daily = DailyRetention(
                db,
                app.state.ctx,
                settings.retention_at,
                stopping=lambda: app.state.drain.draining,
            )
            daily.start()
        try:
            # The server of `attune serve` finds the drain here and starts it on SIGTERM.
            yield {STATE_KEY: app.state.drain}
        finally:
            if daily is not None:
                await asyncio.to_thread(daily.stop)
            await asyncio.to_thread(runner.stop)
            await asyncio.to_thread(mover.join)
            if guard is not None:
                await asyncio.to_thread(guard.stop)
            if shadows is not None:
                await asyncio.to_thread(shadows.stop)
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            db.dispose()

    app = FastAPI(
        title="Attune",
        version=package_version(),
        description=DESCRIPTION,
        lifespan=lifespan,
        generate_unique_id_function=_operation_id,
        docs_url=None,
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.db = db
    app.state.ctx = ServiceContext.from_settings(settings)
    app.state.metrics = Metrics()
    app.state.drain = Drain()
    # Evaluations of candidate learners that this worker runs, one at a time, in a thread.
    app.state.evaluations = EvaluationRunner(
        db, app.state.ctx, stopping=lambda: app.state.drain.draining
    )
    # The moves a rollout owes, a person at a time, in a thread (kicked after each change).
    app.state.rollout_mover = rollout_service.Mover(
        db, app.state.ctx, stopping=lambda: app.state.drain.draining
    )
    app.state.metrics.attach(db=db, cache=app.state.ctx.cache, drain=app.state.drain)
    app.state.limiter = KeyRateLimiter(settings.rate_limit_per_s, settings.rate_limit_burst)
    install_error_handlers(app)
    for module in (users, episodes, models, profile, meta):
        app.include_router(module.router)
    app.include_router(admin.router)
    app.include_router(evaluations.router)
    app.include_router(rollouts.router)
    install_docs(app)
    mount_console(app)
    # The last added is the outermost: every response, whoever answers it, gets its request id
    # and its access line, after the forwarded headers of untrusted peers are dropped.
    app.add_middleware(HeadMiddleware)
    app.add_middleware(BodyLimitMiddleware, limit=settings.max_body_bytes)
    app.add_middleware(InFlightLimitMiddleware, limit=settings.max_in_flight)
    app.add_middleware(MetricsMiddleware, metrics=app.state.metrics, drain=app.state.drain)
    app.add_middleware(RequestContextMiddleware)
    app.add_middleware(ProxyMiddleware, trusted=TrustedProxies(settings.forwarded_allow_ips))
    return app


def app() -> FastAPI:
    """Factory for ``uvicorn --factory app.main:app``: settings from the environment."""
    return create_app()
