"""Crash recovery: ``attune serve`` is killed with SIGKILL in the middle of the robots' load and
started again. Everything acknowledged before the kill is stored exactly once, nothing is half
written (each model matches its history and rebuilds identically), and the writes that were in
flight, retried by their robots after the restart, are stored exactly once too."""

from __future__ import annotations

import time

import httpx
import pytest

from tests.support.live import LiveService, fresh_database, make_keys

from .helpers import create_users, rebuild
from .history import History, Workload, check_history

pytestmark = [pytest.mark.stress, pytest.mark.xdist_group("stress")]

CLIENTS = 32
KILL_AFTER = 150  # acknowledged writes before the SIGKILL


@pytest.mark.parametrize(("engine", "workers"), [("sqlite", 1), ("postgresql", 2)])
def test_sigkill_mid_load_loses_nothing_acknowledged(engine: str, workers: int) -> None:
    with fresh_database(engine) as url:
        service = LiveService(url, workers=workers)
        service.start()
        try:
            keys = make_keys(url, CLIENTS)
            admin_key = make_keys(url, 1, role="admin")[0]
            with httpx.Client(base_url=service.url, timeout=60,
                              headers={"Authorization": f"Bearer {admin_key}"}) as api:
                workload = Workload(service.url, keys, episodes_per_client=8,
                                    lost_response_rate=0.05)
                initial = create_users(api, workload.all_users)
                workload.start()
                deadline = time.monotonic() + 120
                while len(workload.history.acks) < KILL_AFTER and time.monotonic() < deadline:
                    time.sleep(0.01)
                workload.pause()  # robots hold their next request; those in flight are cut
                service.kill()
                killed_after = len(workload.history.acks)
                service.start()
                with workload.history.lock:
                    before = History(acks=list(workload.history.acks),
                                     unknown=dict(workload.history.unknown),
                                     anomalies=list(workload.history.anomalies),
                                     sent=set(workload.history.sent))
                at_restart = check_history(before, api, url, workload.all_users, initial,
                                           rebuild=rebuild(url))
                workload.resume()  # robots retry what was in flight, then finish their work
                workload.join()
                at_end = check_history(workload.history, api, url, workload.all_users,
                                       initial, rebuild=rebuild(url))
        finally:
            service.stop()
    print(f"\n{engine}/{workers}w: killed after {killed_after} acknowledgements with "
          f"{len(before.unknown)} writes in flight; {len(workload.history.acks)} in all")
    assert killed_after >= KILL_AFTER
    assert before.unknown, "no write was in flight at the kill"
    assert at_restart == [], "\n".join(at_restart)
    assert at_end == [], "\n".join(at_end)
    assert not workload.history.unknown
