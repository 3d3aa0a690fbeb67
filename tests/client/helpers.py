"""What a simulated person answers, shared by the client's tests against the real service."""

from __future__ import annotations

import datetime as dt
from typing import Any

from attune_client import Decision

EVENT_TIME = "2026-11-22T15:10:00+08:00"  # afternoon, local time
FIRST_DETAIL = {"ProvideDrink": "tea", "BriefInformation": "news",
                "ArrangeSchedule": "today_agenda"}


def answer(decision: Decision, n: int = 0) -> dict[str, Any]:
    """Keyword arguments of ``report_outcome`` for a cooperative person; ``n`` varies the
    answers a little (a person who stays silent, or asks for something themselves)."""
    kind = decision.action.kind
    if kind == "pass":
        if n % 3 == 1:
            return {"response": "none"}
        return {"response": "human_request", "service": "ProvideDrink"}
    if kind == "query_type":
        return {"response": "answered", "service": "BriefInformation"}
    if kind == "query_detail":
        service = decision.action.service or "ProvideDrink"
        return {"response": "answered", "detail": FIRST_DETAIL[service]}
    if kind == "initiate" and n % 5 == 4:
        return {"response": "rejected"}
    return {"response": "accepted"}


def occurred(n: int) -> str:
    """An event time: the afternoon of a day, one minute per event."""
    base = dt.datetime.fromisoformat(EVENT_TIME)
    return (base + dt.timedelta(minutes=n)).isoformat()
