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


def _held_up(hold: object) -> Metrics:
    """The watchdog's figures after the loop was held up once by ``hold()``."""
    metrics = Metrics()

    async def run() -> None:
        watch = asyncio.create_task(metrics.watch_stalls(5.0))
        await asyncio.sleep(0.05)
        hold()  # type: ignore[operator]
        await asyncio.sleep(0.05)
        watch.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await watch

    asyncio.run(run())
    return metrics


def test_the_busy_part_of_a_stall_is_the_loop_s_own_cpu() -> None:
    def compute() -> None:  # 0.12 s of this thread's CPU, however busy the machine is
        began = time.thread_time()
        while time.thread_time() - began < 0.12:
            pass

    metrics = _held_up(compute)
    wall = _sample(metrics, "attune_event_loop_stall_max_seconds")
    busy = _sample(metrics, "attune_event_loop_busy_stall_max_seconds")
    assert wall >= 0.115
    assert busy >= 0.115  # the thread ran through all of it
    assert busy <= wall


def test_a_wait_on_the_loop_is_a_stall_but_not_busy() -> None:
    # A blocking call (a sleep here, a database's answer for a write inline) holds the loop up
    # without running its thread: the whole stall on the wall clock, almost none of it busy.
    metrics = _held_up(lambda: time.sleep(0.12))
    wall = _sample(metrics, "attune_event_loop_stall_max_seconds")
    busy = _sample(metrics, "attune_event_loop_busy_stall_max_seconds")
    assert wall >= 0.115
    assert busy < wall / 2
