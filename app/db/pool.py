"""The connection pool of a worker's engine, counting the checkouts that wait.

SQLAlchemy's pool events fire once a connection is handed out, so they cannot tell a request
that waited for one from a request that found one idle; this pool tells them apart where the
request asks (``connect``), for the metrics (``attune_db_pool_waits_total``).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from typing import Any

from sqlalchemy import Connection
from sqlalchemy.pool import QueuePool

__all__ = ["MeteredQueuePool", "invalidate_all", "is_lost_connection"]

# SQLSTATEs that say the server ended the session: an administrator or a failover ended it
# (pg_terminate_backend, a fast shutdown: 57P01), the server crashed or is starting (57P02,
# 57P03), and class 08, connection exceptions (a pooler in between says "server conn crashed?"
# with 08P01 when the server connection behind a client's transaction broke).
_ENDED = frozenset({"57P01", "57P02", "57P03"})


def is_lost_connection(exc: BaseException) -> bool:
    """Whether a driver (psycopg) error means the connection is gone, and the pool must drop
    it, beyond what SQLAlchemy's dialect recognizes by its messages: every operational or
    interface error raised by the client itself (no SQLSTATE: "server closed the connection
    unexpectedly", "consuming input failed", "the connection is closed"), the server's ending
    of the session, and connection exceptions. A statement the server refused (a lock not
    available, a constraint, a cancelled query) carries a SQLSTATE of another class: not lost.
    """
    psycopg = sys.modules.get("psycopg")  # not loaded: not its error (SQLite never loads it)
    if psycopg is None or not isinstance(exc, psycopg.OperationalError | psycopg.InterfaceError):
        return False
    sqlstate = getattr(exc, "sqlstate", None)
    return sqlstate is None or sqlstate in _ENDED or sqlstate.startswith("08")


def invalidate_all(connection: Connection, exc: BaseException) -> None:
    """Drop ``connection``, lost with ``exc``, and every connection its pool opened before it
    (they are closed as they come back, or replaced when next checked out): what SQLAlchemy
    does on a disconnect, for the statements run on the driver's cursor. A restart or failover
    breaks them all at once, so each would otherwise fail one more request."""
    connection.engine.pool._invalidate(connection.connection, exc)
    connection.invalidate(exc)


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
