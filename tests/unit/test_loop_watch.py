"""The loop watchdog (``ATTUNE_LOOP_WATCH_MS``): work that holds the event loop up is counted as
a stall in ``attune_event_loop_stall_seconds`` and shown in the worst-stall gauge."""

from __future__ import annotations

import asyncio
import contextlib
import time

from prometheus_client import generate_latest

from app.api.metrics import Metrics


def _sample(metrics: Metrics, name: str, labels: dict[str, str] | None = None) -> float:
    value = metrics.registry.get_sample_value(name, labels or {})
    assert value is not None, name
    return value


def test_a_blocked_loop_is_seen_as_a_stall() -> None:
    metrics = Metrics()

    async def run() -> None:
        watch = asyncio.create_task(metrics.watch_stalls(5.0))
        await asyncio.sleep(0.05)
        time.sleep(0.12)  # holds the event loop up, as a synchronous write on it would
        await asyncio.sleep(0.05)
        watch.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await watch

    asyncio.run(run())
    # The watchdog wakes every 5 ms: it woke at least 0.12 - 0.005 s late once.
    assert _sample(metrics, "attune_event_loop_stall_max_seconds") >= 0.115
    over = _sample(metrics, "attune_event_loop_stall_seconds_count") - _sample(
        metrics, "attune_event_loop_stall_seconds_bucket", {"le": "0.1"}
    )
    assert over >= 1
    assert b"attune_event_loop_stall_seconds_bucket" in generate_latest(metrics.registry)
