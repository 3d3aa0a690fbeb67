"""The connection pool of a worker's engine, counting the checkouts that wait.

SQLAlchemy's pool events fire once a connection is handed out, so they cannot tell a request
that waited for one from a request that found one idle; this pool tells them apart where the
request asks (``connect``), for the metrics (``attune_db_pool_waits_total``).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from sqlalchemy.pool import QueuePool

__all__ = ["MeteredQueuePool"]


class MeteredQueuePool(QueuePool):
    """A ``QueuePool`` that counts the checkouts made while every connection it may open was
    in use (``waits``), and the seconds they waited (``wait_seconds``).

    The counts are plain numbers, read by the metrics every second; a checkout that finds a
    connection pays one comparison.
    """

    def __init__(
        self, creator: Any, pool_size: int = 5, max_overflow: int = 10, **kwargs: Any
    ) -> None:
        super().__init__(creator, pool_size=pool_size, max_overflow=max_overflow, **kwargs)
        self.capacity = pool_size + max_overflow if max_overflow >= 0 else None
        self.waits = 0
        self.wait_seconds = 0.0
        self._counting = threading.Lock()

    def connect(self) -> Any:
        capacity = self.capacity
        if capacity is None or self.checkedout() < capacity:
            return super().connect()
        start = time.perf_counter()
        try:
            return super().connect()
        finally:
            waited = time.perf_counter() - start
            with self._counting:  # only on this path: a checkout that waited
                self.waits += 1
                self.wait_seconds += waited


# SQLAlchemy logs a pool's life (disposed, recreated) at INFO, under the pool class's own name;
# as for its own pools (it sets "sqlalchemy" to WARNING unless configured), warnings only.
_pool_log = logging.getLogger(f"{MeteredQueuePool.__module__}.{MeteredQueuePool.__name__}")
if _pool_log.level == logging.NOTSET:
    _pool_log.setLevel(logging.WARNING)
