"""ASGI middleware and limits: the trusted proxies' forwarded headers, request ids and the access
line, HEAD on GET routes, the request body limit (413), overload shedding (503), the per-key rate
limit (429) and Prometheus request metrics."""

from __future__ import annotations

import ipaddress
import json
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app import logs

from .lifecycle import Drain
from .metrics import Metrics, begin_round_trips, end_round_trips

__all__ = [
    "BodyLimitMiddleware",
    "BodyTooLarge",
    "HeadMiddleware",
    "InFlightLimitMiddleware",
    "KeyRateLimiter",
    "MetricsMiddleware",
    "ProxyMiddleware",
    "RequestContextMiddleware",
    "TrustedProxies",
    "error_body",
    "route_template",
]

access_log = logging.getLogger("attune.access")
log = logging.getLogger("attune.api")

# Probes and scrapes must answer while the service sheds load: they are what tells an operator
# (or an orchestrator) that it is alive but busy.
EXEMPT_PATHS = frozenset({"/livez", "/healthz", "/readyz", "/metrics"})


class BodyTooLarge(Exception):
    """Raised while a streamed body goes over the limit (FastAPI wraps it in a 400, which the
    error handler turns back into this 413)."""

    def __init__(self, limit: int) -> None:
        super().__init__(f"The request body is over the {limit}-byte limit.")
        self.limit = limit


def error_body(error: str, detail: str, **more: Any) -> dict[str, Any]:
    """The contract's error body, with the id of the request being answered."""
    body: dict[str, Any] = {"error": error, "detail": detail, **more}
    request_id = logs.current_request_id()
    if request_id is not None:
        body["request_id"] = request_id
    return body


async def _send_error(
    send: Send, status: int, error: str, detail: str, headers: tuple[tuple[bytes, bytes], ...] = ()
) -> None:
    body = json.dumps(error_body(error, detail), separators=(",", ":")).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                *headers,
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


async def _send_413(send: Send, limit: int) -> None:
    await _send_error(
        send, 413, "PayloadTooLarge", f"The request body is over the {limit}-byte limit."
    )


def route_path(scope: Scope) -> str:
    """The request's path without the root path (``ATTUNE_ROOT_PATH``) in front of it: the
    path the routes are matched on."""
    path: str = scope.get("path", "")
    root = scope.get("root_path", "")
    if root and (path == root or path.startswith(root + "/")):
        return path[len(root) :] or "/"
    return path


def route_template(scope: Scope) -> str:
    """The path template of the route that answered (``/v1/users/{user_id}``), or
    ``unmatched``: a label of bounded cardinality for metrics and logs."""
    path = getattr(scope.get("route"), "path", None)
    return path if isinstance(path, str) and path else "unmatched"


class TrustedProxies:
    """The peers whose forwarded headers are believed: IP addresses and networks
    (``ATTUNE_FORWARDED_ALLOW_IPS``), or ``*`` for every peer."""

    def __init__(self, allowed: Iterable[str]) -> None:
        allowed = list(allowed)
        self.everyone = "*" in allowed
        self.networks = [ipaddress.ip_network(a, strict=False) for a in allowed if a != "*"]

    def __contains__(self, host: object) -> bool:
        if not isinstance(host, str) or not host:
            return False
        if self.everyone:
            return True
        try:
            ip = ipaddress.ip_address(host)
        except ValueError:  # a Unix socket's peer, a name
            return False
        mapped = getattr(ip, "ipv4_mapped", None)  # ::ffff:10.0.0.5 is 10.0.0.5
        return any(ip in net or (mapped is not None and mapped in net) for net in self.networks)

    def client(self, forwarded_for: str) -> str | None:
        """The caller in an ``X-Forwarded-For`` chain: the last address that is not a trusted
        proxy (each proxy appends the peer it heard from), else the first one. A hop that is
        not an IP address ends the walk: what lies left of it was written by the caller, not
        by a proxy, and is not taken (``None``: the peer stays the client)."""
        hops = [hop.strip() for hop in forwarded_for.split(",") if hop.strip()]
        last = None
        for hop in reversed(hops):
            try:
                ipaddress.ip_address(hop)
            except ValueError:
                return last
            if hop not in self:
                return hop
            last = hop
        return last


# What only a trusted proxy may say: from any other peer these headers are dropped, so nothing
# downstream (the request id, the console's origin check, the access line) can be misled.
FORWARDED_HEADERS = frozenset(
    {
        b"forwarded",
        b"x-forwarded-for",
        b"x-forwarded-host",
        b"x-forwarded-port",
        b"x-forwarded-prefix",
        b"x-forwarded-proto",
        b"x-real-ip",
        b"x-request-id",
    }
)


class ProxyMiddleware:
    """The outermost middleware: what a trusted reverse proxy says about the request.

    From a peer in ``trusted``: ``X-Forwarded-For`` gives the caller's address (the ASGI
    ``client``: the access line's ``client``), ``X-Forwarded-Proto`` the scheme the browser used
    (``http`` or ``https``: the console's ``Secure`` cookie), ``X-Forwarded-Host`` the host it
    used (it replaces ``Host``: the console's same-origin check), and its ``X-Request-ID`` is
    kept. From any other peer, all of these (and ``Forwarded``, ``X-Real-IP``) are dropped
    before anything reads them, so the request gets an id of its own. As uvicorn's
    ``ProxyHeadersMiddleware`` does for its ``--forwarded-allow-ips``, which ``attune serve``
    leaves off."""

    def __init__(self, app: ASGIApp, trusted: TrustedProxies) -> None:
        self.app, self.trusted = app, trusted

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        client = scope.get("client")
        headers: list[tuple[bytes, bytes]] = list(scope.get("headers", []))
        if not (client and client[0] in self.trusted):
            if any(k in FORWARDED_HEADERS for k, _ in headers):  # else nothing to drop
                scope["headers"] = [(k, v) for k, v in headers if k not in FORWARDED_HEADERS]
            await self.app(scope, receive, send)
            return
        given: dict[bytes, str] = {}
        for name, value in headers:
            if name in (b"x-forwarded-for", b"x-forwarded-proto", b"x-forwarded-host"):
                text = value.decode("latin-1")
                given[name] = f"{given[name]}, {text}" if name in given else text
        proto = given.get(b"x-forwarded-proto", "").split(",")[0].strip().lower()
        if proto in ("http", "https"):
            scope["scheme"] = proto
        caller = self.trusted.client(given.get(b"x-forwarded-for", ""))
        if caller:
            scope["client"] = (caller, 0)
        host = given.get(b"x-forwarded-host", "").split(",")[0].strip()
        if host and (b"host", host.encode("latin-1")) not in headers:
            scope["headers"] = [(k, v) for k, v in headers if k != b"host"] + [
                (b"host", host.encode("latin-1"))
            ]
        await self.app(scope, receive, send)


class RequestContextMiddleware:
    """The outermost of the service's middleware: gives each request its id (the caller's valid
    ``X-Request-ID``, else a fresh one) for its log lines, its error body and its
    ``X-Request-ID`` response header; answers an unhandled error with the contract's 500 after
    logging it once, with its traceback; and writes the request's access line (``attune.access``)
    once the response is sent, whoever answered it."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        method = scope.get("method", "?")
        given = None
        for name, value in scope.get("headers", []):
            if name == b"x-request-id":
                given = value.decode("latin-1")
                break
        ctx = logs.RequestContext(logs.request_id_from(given))
        header = (b"x-request-id", ctx.request_id.encode())
        status = 500
        started = False

        async def send_with_id(message: Message) -> None:
            nonlocal status, started
            if message["type"] == "http.response.start":
                status, started = message["status"], True
                headers = [
                    (k, v) for k, v in message.get("headers", []) if k.lower() != b"x-request-id"
                ]
                message = {**message, "headers": [*headers, header]}
            await send(message)

        token = logs.bind(ctx)
        try:
            await self.app(scope, receive, send_with_id)
        except Exception:
            # Logged here, once, and not raised on: the server would log it a second time.
            log.exception("unhandled error on %s %s", method, route_template(scope))
            if not started:
                await _send_error(
                    send_with_id, 500, "InternalError", "The server failed; the error was logged."
                )
        finally:
            if access_log.isEnabledFor(logging.INFO):
                latency_ms = round((time.perf_counter() - start) * 1000, 2)
                route = route_template(scope)
                peer = scope.get("client")
                client = peer[0] if peer else None
                fields = {
                    "method": method,
                    "route": route,
                    "status": status,
                    "latency_ms": latency_ms,
                    "key_id": ctx.key_id,
                    "client": client,
                }
                access_log.info(
                    "method=%s route=%s status=%d latency_ms=%s key_id=%s client=%s",
                    method,
                    route,
                    status,
                    latency_ms,
                    ctx.key_id or "-",
                    client or "-",
                    extra={logs.FIELDS: fields},
                )
            logs.unbind(token)


HEAD_KEY = "attune.head"  # in a HEAD request's scope, run as its GET: no body is sent


class HeadMiddleware:
    """``HEAD`` on every ``GET`` route: the request runs as its ``GET`` (same status and
    headers, ``Content-Length`` included) and the body is left out. Routes do not declare
    ``HEAD`` themselves, so the OpenAPI document lists only their ``GET``."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("method") != "HEAD":
            await self.app(scope, receive, send)
            return
        body_sent = False

        async def headers_only(message: Message) -> None:
            nonlocal body_sent
            if message["type"] == "http.response.body":
                if body_sent or message.get("more_body", False):
                    return
                body_sent = True
                message = {"type": "http.response.body", "body": b"", "more_body": False}
            await send(message)

        # A copy: the server reads the method of its own scope to know that no body follows.
        as_get = {**scope, "method": "GET", HEAD_KEY: True}
        try:
            await self.app(as_get, receive, headers_only)
        finally:
            if "route" in as_get:  # for the metrics and the access line
                scope["route"] = as_get["route"]


class BodyLimitMiddleware:
    """Refuse bodies over ``limit`` bytes, by Content-Length or while streaming."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app, self.limit = app, limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", []):
            if name == b"content-length":
                try:
                    too_big = int(value) > self.limit
                except ValueError:
                    too_big = False
                if too_big:
                    await _send_413(send, self.limit)
                    return
        seen = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    raise BodyTooLarge(self.limit)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except BodyTooLarge:
            if not started:
                await _send_413(send, self.limit)


class MetricsMiddleware:
    """Count requests, time them and count their round trips to PostgreSQL, per route template
    (``/v1/users/{user_id}``).

    While the worker shuts down (``drain``), every response also closes its connection
    (``Connection: close``): a client's next request opens a new one, which the load balancer
    sends to another instance, so the requests in flight here run out.
    """

    def __init__(self, app: ASGIApp, metrics: Metrics, drain: Drain) -> None:
        self.app, self.metrics, self.drain = app, metrics, drain

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status: dict[str, Any] = {"code": 500}
        drain = self.drain

        async def tracking_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                status["code"] = message["status"]
                if drain.since is not None:
                    headers = [
                        (k, v) for k, v in message.get("headers", []) if k.lower() != b"connection"
                    ]
                    message = {**message, "headers": [*headers, (b"connection", b"close")]}
            await send(message)

        trips, token = begin_round_trips()
        try:
            await self.app(scope, receive, tracking_send)
        finally:
            end_round_trips(token)
            self.metrics.observe_request(
                scope.get("method", "?"),
                route_template(scope),
                status["code"],
                time.perf_counter() - start,
                trips[0],
            )


class InFlightLimitMiddleware:
    """Shed load: past ``limit`` requests in progress in this worker, answer 503 at once.

    The sync routes run in a bounded thread pool; without a cap, requests beyond it wait in
    an unbounded queue and every robot times out together. Refusing early with ``Retry-After``
    keeps the latency of the admitted requests bounded and tells clients when to come back.
    The counter lives on the event loop's thread (ASGI calls run there), so it needs no lock.
    """

    def __init__(self, app: ASGIApp, limit: int, retry_after: int = 1) -> None:
        self.app, self.limit, self.retry_after = app, limit, retry_after
        self.in_flight = 0
        self.shed = 0
        self._detail = f"The service is at capacity; retry in {retry_after} s."
        self._retry_after = ((b"retry-after", str(retry_after).encode()),)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or route_path(scope) in EXEMPT_PATHS:
            await self.app(scope, receive, send)
            return
        if self.in_flight >= self.limit:
            self.shed += 1
            await _send_error(send, 503, "ServiceUnavailable", self._detail, self._retry_after)
            return
        self.in_flight += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.in_flight -= 1


class KeyRateLimiter:
    """A token bucket per API key id: ``rate`` tokens a second, at most ``burst`` saved up.

    One limiter per worker process (``attune serve --workers N`` lets a key make N times the
    rate in all). Buckets of keys idle long enough to be full again are dropped, so memory is
    bounded by the keys active in the last ``burst / rate`` seconds. Thread-safe: it is called
    from the route thread pool.
    """

    def __init__(
        self, rate: float, burst: int, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.rate, self.burst, self.clock = rate, float(burst), clock
        self._buckets: dict[str, tuple[float, float]] = {}  # key id -> (tokens, at)
        self._lock = threading.Lock()
        self._swept = 0.0

    @property
    def enabled(self) -> bool:
        return self.rate > 0

    def acquire(self, key_id: str) -> int:
        """Take one token; 0 when granted, else the whole seconds to wait before retrying."""
        if not self.enabled:
            return 0
        now = self.clock()
        with self._lock:
            tokens, at = self._buckets.get(key_id, (self.burst, now))
            tokens = min(self.burst, tokens + (now - at) * self.rate)
            if tokens >= 1.0:
                self._buckets[key_id] = (tokens - 1.0, now)
                self._sweep(now)
                return 0
            self._buckets[key_id] = (tokens, now)
            return max(1, math.ceil((1.0 - tokens) / self.rate))

    def _sweep(self, now: float) -> None:
        full_after = self.burst / self.rate
        if now - self._swept < full_after:
            return
        self._swept = now
        for key_id, (tokens, at) in list(self._buckets.items()):
            if tokens + (now - at) * self.rate >= self.burst:
                del self._buckets[key_id]
