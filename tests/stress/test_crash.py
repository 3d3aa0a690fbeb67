"""Crash recovery: ``attune serve`` is killed with SIGKILL in the middle of the robots' load and
started again. Everything acknowledged before the kill is stored exactly once, nothing is half
written (each model matches its history and rebuilds identically), and the writes that were in
flight, retried by their robots after the restart, are stored exactly once too.

The robots belong to two fleets that use the same user ids and the same event ids at once: each
fleet's history is checked against that fleet's users only."""

from __future__ import annotations

import time

import httpx
import pytest

from tests.support.fixtures import WorkerDatabases
from tests.support.live import LiveService, fresh_database, make_keys

from .helpers import CASES, create_users, service_env
from .history import History, Workload, check_history

pytestmark = [pytest.mark.stress, pytest.mark.xdist_group("stress")]

FLEETS = ("default", "east")
CLIENTS = 32  # split between the fleets
KILL_AFTER = 150  # acknowledged writes before the SIGKILL (both fleets together)


def _copy(history: History) -> History:
    with history.lock:
        return History(
            acks=list(history.acks),
            unknown=dict(history.unknown),
            anomalies=list(history.anomalies),
            sent=set(history.sent),
        )


@pytest.mark.parametrize(("engine", "workers"), CASES)
def test_sigkill_mid_load_loses_nothing_acknowledged(
    engine: str, workers: int, worker_databases: WorkerDatabases
) -> None:
    per_fleet = CLIENTS // len(FLEETS)
    with fresh_database(engine) as url:
        service = LiveService(url, workers=workers, env=service_env(engine, url, worker_databases))
        service.start()
        try:
            admin_key = make_keys(url, 1, role="admin")[0]
            with httpx.Client(
                base_url=service.url, timeout=60, headers={"Authorization": f"Bearer {admin_key}"}
            ) as api:
                workloads = {
                    fleet: Workload(
                        service.url,
                        make_keys(url, per_fleet, fleet=fleet),
                        episodes_per_client=8,
                        lost_response_rate=0.05,
                        seed=7 + n,
                    )
                    for n, fleet in enumerate(FLEETS)
                }
                initial = {
                    fleet: create_users(api, w.all_users, fleet) for fleet, w in workloads.items()
                }
                for w in workloads.values():
                    w.start()
                deadline = time.monotonic() + 120
                while (
                    sum(len(w.history.acks) for w in workloads.values()) < KILL_AFTER
                    and time.monotonic() < deadline
                ):
                    time.sleep(0.01)
                for w in workloads.values():
                    w.pause()  # robots hold their next request; those in flight are cut
                service.kill()
                killed_after = sum(len(w.history.acks) for w in workloads.values())
                service.start()
                before = {fleet: _copy(w.history) for fleet, w in workloads.items()}
                at_restart = [
                    f"{fleet}: {finding}"
                    for fleet, w in workloads.items()
                    for finding in check_history(
                        before[fleet],
                        api,
                        url,
                        w.all_users,
                        initial[fleet],
                        fleet=fleet,
                        rebuild=True,
                    )
                ]
                for w in workloads.values():
                    w.resume()  # robots retry what was in flight, then finish their work
                for w in workloads.values():
                    w.join()
                at_end = [
                    f"{fleet}: {finding}"
                    for fleet, w in workloads.items()
                    for finding in check_history(
                        w.history,
                        api,
                        url,
                        w.all_users,
                        initial[fleet],
                        fleet=fleet,
                        rebuild=True,
                    )
                ]
        finally:
            service.stop()
    in_flight = sum(len(h.unknown) for h in before.values())
    print(
        f"\n{engine}/{workers}w: killed after {killed_after} acknowledgements with "
        f"{in_flight} writes in flight; "
        f"{sum(len(w.history.acks) for w in workloads.values())} in all"
    )
    assert killed_after >= KILL_AFTER
    assert in_flight, "no write was in flight at the kill"
    assert all(len(w.history.acks) > 0 for w in workloads.values())
    assert at_restart == [], "\n".join(at_restart)
    assert at_end == [], "\n".join(at_end)
    assert not any(w.history.unknown for w in workloads.values())
