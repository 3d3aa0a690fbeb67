"""``attune serve``: the v1 API under uvicorn, with one or more worker processes.

Before anything else it binds the port and brings the database's schema up to date; a start that
cannot succeed (the port in use, the database unreachable, its schema from a newer release, the
migrations missing) says why in one line and exits 1.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import tempfile
from typing import Annotated

import typer

from ._setup import StartFailure, fail, load_settings, one_line, upgrade_schema

__all__ = ["serve"]


def _listen(host: str, port: int) -> socket.socket:
    """The service's listening socket, bound before anything else is done (a port in use must
    not leave a database behind); uvicorn's workers share it."""
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
                "pass another --port."
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


def serve(
    host: Annotated[str, typer.Option(help="Interface to listen on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=1, max=65535, help="TCP port.")] = 8000,
    workers: Annotated[
        int,
        typer.Option(
            min=1, help="Worker processes (each with its own connection pool and learner cache)."
        ),
    ] = 1,
) -> None:
    """Apply pending migrations, then serve the v1 API (docs at /docs).

    A start that cannot succeed (the port in use, the database unreachable, its schema from a
    newer release, the migrations missing) says why in one line and exits 1, leaving no new
    database file behind.
    """
    import logging.config

    import uvicorn

    from app import logs

    settings = load_settings()
    log_config = logs.logging_config(settings.log_level, settings.log_format)
    logging.config.dictConfig(log_config)
    try:
        sock = _listen(host, port)
    except StartFailure as exc:
        fail(exc)
    say = logging.getLogger("attune.serve").info  # a log line: JSON with ATTUNE_LOG_FORMAT=json
    try:
        try:
            upgrade_schema(settings, say=say)
        except StartFailure as exc:
            fail(exc)
        if workers > 1 and not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
            # Every worker writes its metrics here and /metrics adds them up.
            os.environ["PROMETHEUS_MULTIPROC_DIR"] = tempfile.mkdtemp(prefix="attune-metrics-")
        say(
            f"Attune on http://{host}:{port} (docs: http://{host}:{port}/docs), "
            f"{workers} worker(s)."
        )
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
            proxy_headers=False,
        )
        if workers == 1:
            with contextlib.suppress(KeyboardInterrupt):  # Ctrl+C: as uvicorn.run does
                uvicorn.Server(config).run(sockets=[sock])
            return
        from .supervisor import Supervisor

        Supervisor(config, sockets=[sock]).run()
    finally:
        sock.close()
