"""Staff correct a person's model while the fleet's robots serve them, on a real ``attune serve``
(SQLite with 1 worker, PostgreSQL with 2): the robots retry, duplicate and resend; the staff
send each correction twice (a retry) and lift some. Then: the history check (no acknowledged
write lost or doubled, every model version accounted for, the corrections' included), every
model rebuilt identically, and each correction stored once with the state the staff left it
in."""

from __future__ import annotations

import random
import threading
import time
from typing import Any

import httpx
import pytest

from tests.support.fixtures import WorkerDatabases
from tests.support.live import LiveService, fresh_database, make_keys

from .helpers import CASES, create_users, service_env
from .history import Workload, check_history

pytestmark = [pytest.mark.stress, pytest.mark.xdist_group("stress")]

CLIENTS = 6
EPISODES = 60
KINDS = [
    ("prefers", "ProvideDrink", "tea"),
    ("avoid", "BriefInformation", None),
    ("quiet", None, None),
]
SLOTS = ["morning", "noon", "afternoon", "evening"]
SITUATIONS = ["arriving", "working", "stretching", "busy"]


@pytest.mark.parametrize(("engine", "workers"), CASES)
def test_corrections_under_load_lose_nothing(
    engine: str, workers: int, worker_databases: WorkerDatabases
) -> None:
    with (
        fresh_database(engine) as url,
        LiveService(
            url, workers=workers, env=service_env(engine, url, worker_databases)
        ) as service,
    ):
        admin_key = make_keys(url, 1, role="admin")[0]
        staff_key = make_keys(url, 1, role="staff")[0]
        with httpx.Client(
            base_url=service.url, timeout=120, headers={"Authorization": f"Bearer {admin_key}"}
        ) as api:
            # The robots go on until the staff are done (at most EPISODES each), so that the
            # corrections meet the traffic however fast the service answers the robots.
            work = Workload(
                service.url, make_keys(url, CLIENTS), episodes_per_client=EPISODES, seed=11
            )
            initial = create_users(api, work.all_users)
            made: dict[tuple[str, str], bool] = {}  # (user, correction id) -> lifted
            problems: list[str] = []
            during: list[int] = []  # the corrections sent while the robots were writing

            def staff() -> None:
                rng = random.Random(5)
                with httpx.Client(
                    base_url=service.url,
                    timeout=120,
                    headers={"Authorization": f"Bearer {staff_key}"},
                ) as http:
                    try:
                        for n in range(12):
                            if any(t.is_alive() for t in work._threads):
                                during.append(n)
                            user = rng.choice(work.all_users)
                            kind, service_, detail = rng.choice(KINDS)
                            body: dict[str, Any] = {
                                "correction_id": f"c{n}",
                                "kind": kind,
                                "time_slot": rng.choice(SLOTS),
                                "situation": rng.choice(SITUATIONS),
                                "service": service_,
                                "detail": detail,
                            }
                            codes = [
                                http.post(f"/v1/users/{user}/corrections", json=body).status_code
                                for _ in range(2)
                            ]
                            if codes != [201, 200]:
                                problems.append(f"c{n} for {user}: {codes}")
                            made[(user, f"c{n}")] = False
                            if rng.random() < 0.4:
                                r = http.delete(f"/v1/users/{user}/corrections/c{n}")
                                if r.status_code != 204:
                                    problems.append(f"lift c{n}: {r.status_code}")
                                made[(user, f"c{n}")] = True
                            time.sleep(0.02)
                    finally:
                        work.stopping.set()

            work.start()
            staffer = threading.Thread(target=staff)
            staffer.start()
            work.join()
            staffer.join(timeout=180)
            findings = check_history(work.history, api, url, work.all_users, initial, rebuild=True)
            stored = {
                u: api.get(f"/v1/users/{u}/corrections").json()["items"] for u in work.all_users
            }
    assert problems == []
    assert findings == [], "\n".join(findings)
    assert len(during) >= 3, "the corrections came after the traffic"
    for (user, cid), lifted in made.items():
        [item] = [c for c in stored[user] if c["correction_id"] == cid]
        assert (item["status"] == "lifted") == lifted, item
    assert sum(len(v) for v in stored.values()) == len(made)
