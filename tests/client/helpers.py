"""Event times of the client's tests against the real service."""

from __future__ import annotations

import datetime as dt

from tests.support.episodes import EVENT_TIME

__all__ = ["EVENT_TIME", "occurred"]


def occurred(n: int) -> str:
    """An event time: the afternoon of a day, one minute per event."""
    base = dt.datetime.fromisoformat(EVENT_TIME)
    return (base + dt.timedelta(minutes=n)).isoformat()
