"""A worker's shutdown, as its probes and metrics see it.

``attune serve`` runs each worker under a server that, on SIGTERM or SIGINT, calls
:meth:`Drain.begin` on the app's drain (handed to the server in the lifespan's state under
:data:`STATE_KEY`), then goes on serving until no request is in flight or
``ATTUNE_DRAIN_TIMEOUT_S`` has passed. From the signal on, ``/readyz`` answers 503, so that a
load balancer or Kubernetes sends no more traffic, while ``/livez`` still answers 200: the worker
is alive, only leaving.
"""

from __future__ import annotations

import time

__all__ = ["STATE_KEY", "Drain"]

STATE_KEY = "attune.drain"
"""The lifespan state's key of the app's :class:`Drain` (read by the server of ``attune serve``)."""


class Drain:
    """Whether this worker is shutting down, and since when (``time.monotonic()``)."""

    def __init__(self) -> None:
        self.since: float | None = None

    @property
    def draining(self) -> bool:
        return self.since is not None

    def begin(self) -> None:
        """The worker was told to stop: from now on it is not ready (idempotent)."""
        if self.since is None:
            self.since = time.monotonic()  # the server logs it (attune.serve)
