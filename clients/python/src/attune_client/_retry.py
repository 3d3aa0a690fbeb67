"""When to retry a request, and how long to wait first.

A request is retried after a transport failure (no connection, a timeout, a dropped
connection) and after the statuses of ``RETRY_STATUSES``; never after another 4xx, which the
same request would only get again. Every retry sends the very same request, body included, so
the ids in it (``event_id``, ``decision_id``, ``feedback_id``) are the same: the service answers
a repeat as a replay, and a retry can never count a report twice.
"""

from __future__ import annotations

import datetime as dt
import email.utils
import time
from collections.abc import Callable
from dataclasses import dataclass

import httpx

from ._constants import INITIAL_RETRY_DELAY, MAX_RETRY_AFTER, MAX_RETRY_DELAY, RETRY_STATUSES

__all__ = ["Backoff", "parse_retry_after", "should_retry_status"]


def should_retry_status(status_code: int) -> bool:
    """True for 408, 429, 500, 502, 503 and 504."""
    return status_code in RETRY_STATUSES


def parse_retry_after(value: str | None, *, now: float | None = None) -> float | None:
    """Seconds to wait from a ``Retry-After`` header (delay-seconds or an HTTP-date), or None
    when the header is absent or unreadable. A date in the past gives 0."""
    if value is None:
        return None
    value = value.strip()
    try:
        seconds = float(value)
    except ValueError:
        try:
            when = email.utils.parsedate_to_datetime(value)
        except (TypeError, ValueError, IndexError):
            return None
        if when.tzinfo is None:  # RFC 9110 dates are GMT
            when = when.replace(tzinfo=dt.UTC)
        seconds = when.timestamp() - (time.time() if now is None else now)
    if seconds != seconds or seconds in (float("inf"), float("-inf")):  # NaN, infinities
        return None
    return max(seconds, 0.0)


@dataclass(frozen=True, slots=True)
class Backoff:
    """Exponential backoff with jitter: ``initial * 2**attempt`` capped at ``maximum``, then
    shortened by up to a quarter at random (so a fleet that lost the service at the same moment
    does not come back in lockstep). A ``Retry-After`` header wins, capped at ``max_retry_after``.
    """

    initial: float = INITIAL_RETRY_DELAY
    maximum: float = MAX_RETRY_DELAY
    max_retry_after: float = MAX_RETRY_AFTER

    def delay(
        self, attempt: int, response: httpx.Response | None, random: Callable[[], float]
    ) -> float:
        """Seconds to wait before retry number ``attempt + 1`` (``attempt`` counts from 0).

        ``random`` returns a float in [0, 1) (``random.random``); the delay lies in
        ``[0.75 * base, base]`` where ``base = min(initial * 2**attempt, maximum)``.
        """
        if response is not None:
            retry_after = parse_retry_after(response.headers.get("retry-after"))
            if retry_after is not None:
                return min(retry_after, self.max_retry_after)
        base = min(self.initial * 2.0**attempt, self.maximum)
        return base * (1.0 - 0.25 * random())
