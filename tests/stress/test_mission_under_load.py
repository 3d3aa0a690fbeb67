"""Two fleets with different missions served side by side by a real ``attune serve`` (SQLite with
1 worker, PostgreSQL with 2), each with its robots retrying, duplicating and resending; one fleet
changes its mission in the middle of the traffic. Then the history check of each fleet: no
acknowledged write lost or doubled, every model's versions accounted for (the move to the new
mission included), every model rebuilt identically; the other fleet is not moved."""

from __future__ import annotations

import threading
import time
from typing import Any

import httpx
import pytest

from app.learning import Mission, office_mission
from tests.support.fixtures import WorkerDatabases
from tests.support.live import LiveService, fresh_database, make_keys

from .helpers import CASES, create_users, service_env
from .history import Workload, check_history

pytestmark = [pytest.mark.stress, pytest.mark.xdist_group("stress")]

CLIENTS = 8  # per fleet
SERVED = CLIENTS * 10 + 1  # writes each fleet has acknowledged by the end (of 30 * CLIENTS)


def _office_with(service: str | None = None, detail: str | None = None) -> dict[str, Any]:
    """The office mission (so the robots' events fit both fleets) with one more service, or
    one more detail under ProvideDrink."""
    doc = office_mission().to_dict()
    if detail is not None:
        doc["services"] = [
            {
                "name": s["name"],
                "details": [*s["details"], detail] if s["name"] == "ProvideDrink" else s["details"],
            }
            for s in doc["services"]
        ]
    if service is not None:
        doc["services"] = [*doc["services"], {"name": service, "details": ["chat", "walk"]}]
    return doc


def office_with_cocoa() -> Mission:
    """The default fleet's mission after its change (its robots' people answer under it)."""
    return Mission.from_dict(_office_with(detail="cocoa"))


@pytest.mark.parametrize(("engine", "workers"), CASES)
def test_a_mission_change_under_load_loses_nothing(
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
            # The second fleet has its own mission from the start.
            r = api.put(
                "/v1/admin/fleets/care/mission",
                json={"change_id": "care-menu", "mission": _office_with(service="Companionship")},
            )
            assert r.status_code == 200, r.text
            care = Mission.from_dict(_office_with(service="Companionship"))
            homes = {
                fleet: Workload(
                    service.url,
                    make_keys(url, CLIENTS, fleet=fleet),
                    episodes_per_client=30,
                    seed=seed,
                    mission=mission,
                )
                for fleet, seed, mission in (("default", 7, office_with_cocoa()), ("care", 8, care))
            }
            initial = {
                fleet: create_users(api, w.all_users, fleet=fleet) for fleet, w in homes.items()
            }
            care_before = {
                u: api.get(f"/v1/users/{u}/model", params={"fleet": "care"}).json()[
                    "mission_version"
                ]
                for u in homes["care"].all_users
            }

            changed: dict[str, Any] = {}

            def change_midway() -> None:
                """The default fleet's staff add cocoa once CLIENTS * 5 of its writes are in;
                the robots go on (at most 30 episodes each) until as many more are in after
                it and the care fleet has SERVED, so the change meets the traffic however fast
                the service answers."""
                deadline = time.monotonic() + 120

                def wait_for(acks: int, care: int = 0) -> None:
                    while (
                        len(homes["default"].history.acks) < acks
                        or len(homes["care"].history.acks) < care
                    ) and time.monotonic() < deadline:
                        time.sleep(0.05)

                try:
                    wait_for(CLIENTS * 5)
                    with httpx.Client(
                        base_url=service.url,
                        timeout=120,
                        headers={"Authorization": f"Bearer {staff_key}"},
                    ) as staff:
                        r = staff.put(
                            "/v1/admin/fleets/default/mission",
                            json={
                                "change_id": "add-cocoa",
                                "mission": _office_with(detail="cocoa"),
                            },
                        )
                        changed.update(
                            status=r.status_code,
                            body=r.json(),
                            during=any(t.is_alive() for t in threads),
                        )
                    # ... and the other fleet is served too, however the two share the workers
                    wait_for(len(homes["default"].history.acks) + CLIENTS * 5, care=SERVED)
                finally:
                    for w in homes.values():
                        w.stopping.set()

            began = time.monotonic()
            for w in homes.values():
                w.start()
            threads = [t for w in homes.values() for t in w._threads]
            changer = threading.Thread(target=change_midway)
            changer.start()
            for w in homes.values():
                w.join()
            changer.join(timeout=180)
            driven = time.monotonic() - began

            findings = []
            for fleet, w in homes.items():
                findings += [
                    f"{fleet}: {f}"
                    for f in check_history(
                        w.history,
                        api,
                        url,
                        w.all_users,
                        initial[fleet],
                        rebuild=True,
                        fleet=fleet,
                    )
                ]
            default_models = {
                u: api.get(f"/v1/users/{u}/model").json() for u in homes["default"].all_users
            }
            care_after = {
                u: api.get(f"/v1/users/{u}/model", params={"fleet": "care"}).json()[
                    "mission_version"
                ]
                for u in homes["care"].all_users
            }
            missions = {
                fleet: api.get("/v1/mission", params={"fleet": fleet}).json() for fleet in homes
            }
    acks = {fleet: len(w.history.acks) for fleet, w in homes.items()}
    interrupted = len(homes["default"].history.interrupted)
    print(
        f"\n{engine}/{workers}w: {acks} acknowledgements in {driven:.1f} s; the change moved "
        f"{changed.get('body', {}).get('users_moved')} models and interrupted "
        f"{changed.get('body', {}).get('episodes_interrupted')} episodes "
        f"({interrupted} outcomes refused as interrupted)"
    )
    assert changed["status"] == 200, changed
    assert changed["during"], "the change came after the traffic"
    assert (changed["body"]["version"], changed["body"]["users_moved"]) == (2, 3)
    assert findings == [], "\n".join(findings)
    assert interrupted <= changed["body"]["episodes_interrupted"]
    for view in default_models.values():
        assert view["mission_version"] == 2
        drinks = [
            a["action"].get("detail")
            for c in view["contexts"][:1]
            for st in c["states"]
            for a in st["actions"]
            if a["action"].get("service") == "ProvideDrink"
        ]
        assert "cocoa" in drinks
    assert care_after == care_before  # the other fleet's models did not move
    assert [m["version"] for m in missions.values()] == [2, 2]
    assert missions["default"]["fingerprint"] != missions["care"]["fingerprint"]
    assert all(n >= SERVED for n in acks.values())  # both fleets were served throughout
