"""A job each worker wakes for every so often, run by one process of the deployment at a time
(a lease): the rollout guard, the shadows' pass."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from app.db.session import Database

from . import leases

__all__ = ["Periodic"]

log = logging.getLogger("attune.periodic")


class Periodic:
    """Every ``seconds``, take the lease ``name`` (unless another process holds it) and run
    ``job``; a failure is logged and tried again at the next wake. ``stopping()`` (the
    worker's drain) and :meth:`stop` end it."""

    def __init__(
        self,
        db: Database,
        name: str,
        seconds: float,
        job: Callable[[], object],
        *,
        stopping: Callable[[], bool] = lambda: False,
    ) -> None:
        self.db, self.name, self.seconds, self.job = db, name, seconds, job
        self.stopping = stopping
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name=f"attune-{self.name}", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _loop(self) -> None:
        while not self._stop.wait(self.seconds):
            if self.stopping():
                return
            try:
                with leases.held(self.db, self.name):
                    self.job()
            except leases.LeaseHeld:
                continue
            except Exception:
                log.exception(
                    "The %s job failed; it runs again in %.0f s.", self.name, self.seconds
                )
