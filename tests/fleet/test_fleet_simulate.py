"""Acceptance: ``attune fleet simulate`` against a live ``attune serve`` (4 robots, 6 people).

The command runs as a robot operator would run it, in its own process, over the network. It must
finish without error, and the metrics it prints (as tables, or as JSON with ``--json``) must equal
what the service's stats endpoint says for each user; overall figures must pool the users'
episodes. Its output is a pipe, not a terminal: the tables must come whole (user ids, headings).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from app.commands.fleet import _differences, _fmt
from app.fleet import make_people, overall_stats
from app.fleet.simulate import METRICS, occurred_at
from app.learning import office_mission
from tests.support.live import ATTUNE, LiveService, fresh_database

MISSION = office_mission()
ROBOTS, USERS, EVENTS, CHANGE_AT = 4, 6, 24, 12


def simulate(
    service: LiveService, key: str, out: Path, *extra: str, as_json: bool = True
) -> subprocess.CompletedProcess[str]:
    args = [
        ATTUNE,
        "fleet",
        "simulate",
        "--url",
        service.url,
        "--key",
        key,
        "--robots",
        str(ROBOTS),
        "--users",
        str(USERS),
        "--events",
        str(EVENTS),
        "--change-at",
        str(CHANGE_AT),
        "--seed",
        "5",
        "--prefix",
        "fleet-t",
        "--plot",
        str(out / "reward.png"),
        "--no-progress",
        "--deadline",
        "240",
        *(["--json"] if as_json else []),
        *extra,
    ]
    env = {**os.environ, "COLUMNS": "40", "ATTUNE_KEY": ""}  # narrow: nothing may be cut
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=300, check=False)


def stats_of(
    service: LiveService, key: str, user_id: str, last: int | None = None
) -> dict[str, Any]:
    params = {"last": last} if last else None
    r = httpx.get(
        f"{service.url}/v1/users/{user_id}/stats",
        params=params,
        headers={"Authorization": f"Bearer {key}"},
        timeout=30,
    )
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


@pytest.mark.live
@pytest.mark.parametrize(("engine", "workers"), [("sqlite", 1), ("postgresql", 2)])
def test_fleet_against_a_live_service(engine: str, workers: int, tmp_path: Path) -> None:
    with fresh_database(engine) as url, LiveService(url, workers=workers) as service:
        key = service.create_key("robot", name="fleet")
        done = simulate(service, key, tmp_path)
        assert done.returncode == 0, done.stdout + done.stderr
        assert "equal the robots' own tally for every user" in done.stderr
        printed = json.loads(done.stdout)  # stdout holds the JSON document and nothing else
        assert (tmp_path / "reward.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

        user_ids = [f"fleet-t-u{i}" for i in range(1, USERS + 1)]
        assert sorted(printed["users"]) == sorted(user_ids)
        for user_id in user_ids:
            got = stats_of(service, key, user_id)
            assert got["episodes"] == EVENTS
            assert printed["users"][user_id] == got  # every field, cumulative curve included
            late = stats_of(service, key, user_id, last=EVENTS - CHANGE_AT)
            assert printed["since_change"]["users"][user_id] == late
        assert printed["overall"] == pytest.approx(
            overall_stats([stats_of(service, key, u) for u in user_ids])
        )
        assert printed["overall"]["episodes"] == USERS * EVENTS

        # Without --json, the same figures as tables, whole although COLUMNS is narrow.
        table_run = simulate(
            service,
            key,
            tmp_path,
            "--prefix",
            "fleet-table-check-with-a-long-prefix",
            "--users",
            "2",
            "--events",
            "4",
            "--change-at",
            "2",
            as_json=False,
        )
        assert table_run.returncode == 0, table_run.stderr
        table = table_run.stdout.splitlines()
        headers = [line for line in table if "interaction" in line]
        assert len(headers) == 2  # all episodes, and since the change
        for header in headers:
            assert [cell.strip() for cell in header.split("┃")[1:-1]] == [
                "user",
                "episodes",
                "missions",
                "interaction",
                "success",
                "queries/mission",
                "cum. reward",
            ]
        for user_id in (
            "fleet-table-check-with-a-long-prefix-u1",
            "fleet-table-check-with-a-long-prefix-u2",
        ):
            got = stats_of(service, key, user_id)
            row = next(line for line in table if line.startswith(f"│ {user_id} "))
            for name in METRICS:
                assert _fmt(name, got[name]) in row, (name, row)

        # Every episode was played by a fleet robot and closed; the robots shared the people.
        robots_seen: set[str] = set()
        auth = {"Authorization": f"Bearer {key}"}
        r = httpx.get(
            f"{service.url}/v1/users/{user_ids[0]}/episodes",
            params={"limit": 100},
            headers=auth,
            timeout=30,
        )
        items = r.json()["items"]
        assert len(items) == EVENTS
        for item in items:
            assert item["status"] == "closed"
            trace = httpx.get(
                f"{service.url}/v1/episodes/{item['episode_id']}", headers=auth, timeout=30
            ).json()
            robots_seen.add(trace["robot_id"])
        assert robots_seen <= {f"sim-robot-{i}" for i in range(1, ROBOTS + 1)}
        assert len(robots_seen) > 1


@pytest.mark.live
def test_fleet_says_why_it_cannot_start(tmp_path: Path) -> None:
    with fresh_database("sqlite") as url, LiveService(url) as service:
        done = simulate(service, "att_not-a-key", tmp_path)
        assert done.returncode == 2
        assert "401" in done.stderr
        service.stop()
        done = simulate(service, "att_not-a-key", tmp_path, "--timeout", "2")
        assert done.returncode == 2
        assert "No service answers" in done.stderr
    assert not (tmp_path / "reward.png").exists()


# -- the parts, without a service ----------------------------------------------------------------
def test_people_are_seeded_and_their_needs_change_where_asked() -> None:
    a = make_people(MISSION, users=3, events=40, change_at=20, seed=1, prefix="p")
    b = make_people(MISSION, users=3, events=40, change_at=20, seed=1, prefix="p")
    assert [p.user_id for p in a] == ["p-u1", "p-u2", "p-u3"]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.contexts, y.contexts)
        np.testing.assert_array_equal(x.uniforms, y.uniforms)
        assert x.profile_at(19) is x.profiles[0]
        assert x.profile_at(20) is x.profiles[1]
        assert x.profiles[0] != x.profiles[1]
    (still,) = make_people(MISSION, users=1, events=10, change_at=None, seed=1, prefix="q")
    assert len(still.profiles) == 1
    with pytest.raises(ValueError, match="change_at"):
        make_people(MISSION, users=1, events=10, change_at=10, seed=1, prefix="q")


def test_event_times_fall_in_their_slot_on_the_local_clock() -> None:
    import datetime as dt

    for slot in MISSION.time_slots:
        for offset in ("+08:00", "-05:00"):
            stamp = dt.datetime.fromisoformat(occurred_at(MISSION, slot.name, offset, 3))
            assert MISSION.slot_at(stamp.timetz().replace(tzinfo=None)) == slot.name


def test_overall_stats_pool_the_users_episodes() -> None:
    a = {
        "episodes": 10,
        "missions": 4,
        "interaction_rate": 0.3,
        "success_rate": 0.5,
        "queries_per_mission": 0.25,
        "total_reward": 12.5,
    }
    b = {
        "episodes": 30,
        "missions": 0,
        "interaction_rate": 0.1,
        "success_rate": None,
        "queries_per_mission": None,
        "total_reward": -3.0,
    }
    got = overall_stats([a, b])
    assert got["episodes"] == 40
    assert got["missions"] == 4
    assert got["interaction_rate"] == pytest.approx((3 + 3) / 40)
    assert got["success_rate"] == pytest.approx(2 / 4)
    assert got["queries_per_mission"] == pytest.approx(1 / 4)
    assert got["total_reward"] == pytest.approx(9.5)
    empty = overall_stats([{**b, "episodes": 0, "interaction_rate": None}])
    assert empty["interaction_rate"] is None


def test_a_difference_between_service_and_robots_is_reported() -> None:
    service = {
        "episodes": 5.0,
        "missions": 2.0,
        "interaction_rate": 0.4,
        "success_rate": 0.5,
        "queries_per_mission": None,
        "total_reward": 3.0,
    }
    assert _differences(service, dict(service)) == []
    found = _differences(service, {**service, "total_reward": 3.5, "queries_per_mission": 0.0})
    assert len(found) == 2
    assert any(line.startswith("total_reward") for line in found)
    total = service["total_reward"]
    assert total is not None
    assert not math.isnan(total)


@pytest.mark.live
def test_a_run_does_not_depend_on_how_many_robots_share_the_people() -> None:
    """Each person's model depends on that person's history only, so with the same people (and
    user ids) the stats are the same whether one robot plays them all or four share them."""
    documents = []
    for robots in (1, 4):
        with fresh_database("sqlite") as url, LiveService(url) as service:
            key = service.create_key("robot")
            done = subprocess.run(
                [
                    ATTUNE,
                    "fleet",
                    "simulate",
                    "--url",
                    service.url,
                    "--key",
                    key,
                    "--robots",
                    str(robots),
                    "--users",
                    "3",
                    "--events",
                    "16",
                    "--seed",
                    "2",
                    "--prefix",
                    "det",
                    "--json",
                    "--no-progress",
                ],
                capture_output=True,
                text=True,
                timeout=300,
                check=False,
            )
            assert done.returncode == 0, done.stderr
            documents.append(json.loads(done.stdout))
    assert documents[0] == documents[1]
