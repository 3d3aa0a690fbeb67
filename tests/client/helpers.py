"""What a simulated person answers, shared by the client's tests against the real service."""

from __future__ import annotations

import datetime as dt
import random
from typing import Any

from attune_client import Decision

from tests.support import people

EVENT_TIME = "2026-11-22T15:10:00+08:00"  # afternoon, local time


def answer(decision: Decision, n: int = 0) -> dict[str, Any]:
    """Keyword arguments of ``report_outcome`` for a cooperative person; ``n`` varies the
    answers a little (a person who says no, stays silent, or asks for something themselves),
    always the same for the same ``n``."""
    return people.answer(decision.action, picky=False, rng=random.Random(n), yes=0.8, asks=0.7)


def occurred(n: int) -> str:
    """An event time: the afternoon of a day, one minute per event."""
    base = dt.datetime.fromisoformat(EVENT_TIME)
    return (base + dt.timedelta(minutes=n)).isoformat()
