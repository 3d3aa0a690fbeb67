"""Defaults of the client, in one place (and exported, so callers can build on them)."""

from __future__ import annotations

import httpx

__all__ = [
    "DEFAULT_MAX_RETRIES",
    "DEFAULT_TIMEOUT",
    "INITIAL_RETRY_DELAY",
    "MAX_RETRY_AFTER",
    "MAX_RETRY_DELAY",
    "RETRY_STATUSES",
]

DEFAULT_TIMEOUT = httpx.Timeout(10.0, connect=3.0)
"""10 s to read, write or wait for a pooled connection; 3 s to connect (a robot on a bad network
learns quickly that the service is out of reach)."""

DEFAULT_MAX_RETRIES = 3
"""Retries after the first attempt, so at most four requests per call."""

INITIAL_RETRY_DELAY = 0.5
"""Seconds before the first retry; the delay doubles with every retry."""

MAX_RETRY_DELAY = 8.0
"""The backoff never waits longer than this (before jitter)."""

MAX_RETRY_AFTER = 60.0
"""A server's ``Retry-After`` is honoured up to this many seconds."""

RETRY_STATUSES = frozenset({408, 429, 500, 502, 503, 504})
"""Statuses worth retrying: a timeout, a rate limit, a server or gateway failure."""
