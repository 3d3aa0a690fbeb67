"""``attune serve``: the v1 API under uvicorn, with one or more worker processes.

Before anything else it binds the port (and the metrics port, if any) and brings the database's
schema up to date; a start that cannot succeed (a port in use, the database unreachable, its
schema from a newer release, the migrations missing) says why in one line and exits 1.

On SIGTERM or SIGINT every worker drains (``supervisor.DrainingServer``): ``/readyz`` answers
503 at once, the requests in flight finish, and the service exits within
``ATTUNE_DRAIN_TIMEOUT_S``.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import socket
import tempfile
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ._setup import StartFailure, fail, load_settings, one_line, upgrade_schema

if TYPE_CHECKING:
    from app.settings import Settings

__all__ = ["serve"]


def _listen(host: str, port: int, *, what: str = "--port") -> socket.socket:
    """A listening socket, bound before anything else is done (a port in use must not leave a
    database behind); uvicorn's workers share the service's."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise StartFailure(
                f"Port {port} on {host} is already in use: stop what uses it, or "
                f"pass another {what}."
            ) from None
        if exc.errno == errno.EACCES:
            raise StartFailure(
                f"Not allowed to listen on port {port} of {host}: pass a port "
                "above 1023, or run with the rights to use it."
            ) from None
        if exc.errno == errno.EADDRNOTAVAIL or isinstance(exc, socket.gaierror):
            raise StartFailure(
                f"Cannot listen on {host}: it is not an address of this "
                "machine; pass another --host."
            ) from None
        raise StartFailure(
            f"Cannot listen on {host}:{port}: {exc.strerror or one_line(exc)}."
        ) from None
    # uvicorn's own socket is made without IPPROTO_TCP, so asyncio does not turn Nagle's
    # algorithm off on the connections it accepts, and every response sent in two writes waits
    # for the client's delayed ACK (40 ms a request on Linux: 160 instead of 10,000 requests/s
    # for a bare app with 2 workers). Accepted connections inherit TCP_NODELAY from the
    # listener.
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.set_inheritable(True)
    return sock


def _metrics_server(sock: socket.socket, token: str | None) -> Any:
    """``GET /metrics`` on a port of its own (``ATTUNE_METRICS_PORT``), in the process that
    started the workers: the sum of their metrics files, behind the metrics token if one is
    set. A ``ThreadingHTTPServer`` on ``sock``; its ``serve_forever`` runs in a thread."""
    import hmac
    import http.server

    from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
    from prometheus_client.multiprocess import MultiProcessCollector

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            if self.path.split("?", 1)[0] != "/metrics":
                self._answer(404, b'{"error":"NotFound","detail":"Only /metrics is served here."}')
                return
            scheme, _, secret = self.headers.get("Authorization", "").partition(" ")
            if token is not None and not (
                scheme.lower() == "bearer"
                and hmac.compare_digest(secret.strip().encode(), token.encode())
            ):
                self._answer(
                    401,
                    b'{"error":"Unauthorized","detail":"/metrics needs the metrics token: '
                    b'Authorization: Bearer <ATTUNE_METRICS_TOKEN>."}',
                    {"WWW-Authenticate": "Bearer"},
                )
                return
            registry = CollectorRegistry()
            MultiProcessCollector(registry)  # type: ignore[no-untyped-call]
            self._answer(200, generate_latest(registry), content_type=CONTENT_TYPE_LATEST)

        def _answer(
            self,
            status: int,
            body: bytes,
            headers: dict[str, str] | None = None,
            content_type: str = "application/json",
        ) -> None:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            for name, value in (headers or {}).items():
                self.send_header(name, value)
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: Any) -> None:
            pass  # scrapes are not requests of the service: no access line

    server = http.server.ThreadingHTTPServer(
        sock.getsockname()[:2], Handler, bind_and_activate=False
    )
    server.daemon_threads = True
    server.socket.close()
    server.socket = sock  # bound by _listen, with its one-line failures
    sock.listen(16)
    return server


def serve(
    host: Annotated[str, typer.Option(help="Interface to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=1, max=65535, help="TCP port.")] = 8000,
    workers: Annotated[
        int,
        typer.Option(
            min=1, help="Worker processes (each with its own connection pool and learner cache)."
        ),
    ] = 1,
    migrate: Annotated[
        bool,
        typer.Option(
            help="Apply pending migrations before serving. With --no-migrate the schema is left "
            "to `attune db upgrade` (one migration job for many instances), and /readyz answers "
            "503 while it is behind."
        ),
    ] = True,
    root_path: Annotated[
        str | None,
        typer.Option(
            help="The path prefix a reverse proxy serves the service under (/attune), which it "
            "strips from each request; links, redirects, cookies and /docs carry it. Default: "
            "ATTUNE_ROOT_PATH, else none."
        ),
    ] = None,
    forwarded_allow_ips: Annotated[
        str | None,
        typer.Option(
            help="The reverse proxies to trust, comma-separated IP addresses or CIDR networks "
            "(* for any): their X-Forwarded-For/-Proto/-Host and X-Request-ID are used, others' "
            "dropped. Default: ATTUNE_FORWARDED_ALLOW_IPS, else 127.0.0.1,::1."
        ),
    ] = None,
) -> None:
    """Apply pending migrations, then serve the v1 API (docs at /docs).

    A start that cannot succeed (the port in use, the database unreachable, its schema from a
    newer release, the migrations missing) says why in one line and exits 1, leaving no new
    database file behind. SIGTERM or SIGINT drains: /readyz answers 503, the requests in flight
    finish, and it exits within ATTUNE_DRAIN_TIMEOUT_S.
    """
    import logging.config

    from app import logs

    # Through the environment: each worker process reads its settings from it.
    if root_path is not None:
        os.environ["ATTUNE_ROOT_PATH"] = root_path
    if forwarded_allow_ips is not None:
        os.environ["ATTUNE_FORWARDED_ALLOW_IPS"] = forwarded_allow_ips
    settings = load_settings()
    log_config = logs.logging_config(settings.log_level, settings.log_format)
    logging.config.dictConfig(log_config)
    sockets: list[socket.socket] = []
    made_metrics_dir: str | None = None
    try:
        try:
            sockets.append(_listen(host, port))
            if settings.metrics_port is not None:
                sockets.append(_listen(host, settings.metrics_port, what="ATTUNE_METRICS_PORT"))
        except StartFailure as exc:
            fail(exc)
        multiprocess = workers > 1 or settings.metrics_port is not None
        if multiprocess and not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
            # Every worker writes its metrics here and /metrics adds them up (set before
            # prometheus_client is first imported: it reads the variable then).
            made_metrics_dir = tempfile.mkdtemp(prefix="attune-metrics-")
            os.environ["PROMETHEUS_MULTIPROC_DIR"] = made_metrics_dir
        say = logging.getLogger("attune.serve").info  # a log line: JSON with ATTUNE_LOG_FORMAT=json
        if migrate:
            try:
                upgrade_schema(settings, say=say)
            except StartFailure as exc:
                fail(exc)
        else:
            say(
                "Not applying migrations (--no-migrate): /readyz answers 503 while the "
                "database's schema is behind."
            )
        _run(host, port, workers, settings, log_config, sockets, say)
    finally:
        for sock in sockets:
            sock.close()
        if made_metrics_dir is not None:
            shutil.rmtree(made_metrics_dir, ignore_errors=True)


def _run(
    host: str,
    port: int,
    workers: int,
    settings: Settings,
    log_config: dict[str, Any],
    sockets: list[socket.socket],
    say: Callable[[str], None],
) -> None:
    import uvicorn

    from .supervisor import DrainingServer, Supervisor

    where = f"http://{host}:{port}"
    metrics = (
        f", metrics on http://{host}:{settings.metrics_port}/metrics"
        if settings.metrics_port is not None
        else ""
    )
    if settings.root_path:
        say(
            f"Attune on {where}, served by a proxy under {settings.root_path} (docs: "
            f"{settings.root_path}/docs){metrics}, {workers} worker(s)."
        )
    else:
        say(f"Attune on {where} (docs: {where}/docs){metrics}, {workers} worker(s).")
    scrapes: Any = None
    if settings.metrics_port is not None:
        token = settings.metrics_token
        scrapes = _metrics_server(sockets[1], token.get_secret_value() if token else None)
        threading.Thread(target=scrapes.serve_forever, daemon=True, name="attune-metrics").start()
    # uvicorn's access log is off: the service writes one access line per request itself
    # (logger attune.access), with the route, the key id and the request id.
    config = uvicorn.Config(
        "app.main:app",
        factory=True,
        host=host,
        port=port,
        workers=workers,
        log_config=log_config,
        log_level=settings.log_level,
        access_log=False,
        # The service's own ProxyMiddleware reads the forwarded headers (of trusted proxies
        # only, ATTUNE_FORWARDED_ALLOW_IPS) and drops the others'; uvicorn's is off.
        proxy_headers=False,
        # The ASGI root_path: uvicorn puts it in front of each request's path, as a proxy that
        # strips the prefix expects; routing ignores it, URLs the service builds carry it.
        root_path=settings.root_path,
    )
    try:
        if workers == 1:
            with contextlib.suppress(KeyboardInterrupt):  # Ctrl+C: as uvicorn.run does
                DrainingServer(config, settings.drain_timeout_s).run(sockets=sockets[:1])
            return
        Supervisor(config, sockets=sockets[:1], drain_timeout=settings.drain_timeout_s).run()
    finally:
        if scrapes is not None:
            scrapes.shutdown()
