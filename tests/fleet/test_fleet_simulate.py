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
from app.fleet import Person, make_people, overall_stats
from app.fleet.simulate import METRICS, occurred_at
from app.learning import office_mission
from tests.support.live import ATTUNE, LiveService, fresh_database

MISSION = office_mission()
ROBOTS, USERS, EVENTS, CHANGE_AT = 4, 6, 24, 12


def simulate(
    service: LiveService,
    key: str,
    out: Path,
    *extra: str,
    as_json: bool = True,
    change_at: int | None = CHANGE_AT,
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
        *(["--change-at", str(change_at)] if change_at is not None else []),
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
        # A robot key may not read the changes told to staff: one line says so, and the run
        # goes on.
        (line,) = [x for x in done.stderr.splitlines() if "Changes were not counted" in x]
        assert "this key may not read them" in line
        assert "403" in line
        assert printed["changes"]["counted"] is False
        assert line.endswith(printed["changes"]["why"])
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
        assert not any("Changes told to staff" in line for line in table)
        assert "Changes were not counted" in table_run.stderr
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


def listed_changes(service: LiveService, key: str, user_id: str) -> list[dict[str, Any]]:
    r = httpx.get(
        f"{service.url}/v1/users/{user_id}/changes",
        params={"limit": 500},
        headers={"Authorization": f"Bearer {key}"},
        timeout=30,
    )
    assert r.status_code == 200, r.text
    assert r.json()["next_cursor"] is None
    items: list[dict[str, Any]] = r.json()["items"]
    return items


def counted_here(
    people: list[Person], listed: dict[str, list[dict[str, Any]]], change_at: int
) -> dict[str, Any]:
    """The changes the service listed, counted against the people's true changes by the rule
    the command documents, written out here: a need replaced or ended at the change point is a
    true change; the first change listed in its context and decided at or after the change
    point catches it; every other change listed is a false alarm."""
    true = caught = within = 0
    late: list[int] = []
    for person in people:
        before, after = person.profiles
        decided = sorted(
            (c["decided"]["episode"] - 1, MISSION.context_index(c["time_slot"], c["situation"]))
            for c in listed[person.user_id]
        )
        used: set[int] = set()
        for need in before.needs:
            if after.need_at(need.context) == need:
                continue
            true += 1
            hit = next(
                (
                    i
                    for i, (event, context) in enumerate(decided)
                    if i not in used and context == need.context and event >= change_at
                ),
                None,
            )
            if hit is None:
                continue
            used.add(hit)
            event = decided[hit][0]
            caught += 1
            late.append(event - change_at)
            seen = int(np.count_nonzero(person.contexts[change_at : event + 1] == need.context))
            within += seen <= 3
    recorded = sum(len(items) for items in listed.values())
    return {
        "true_changes": true,
        "caught": caught,
        "caught_within": within,
        "recorded": recorded,
        "false_alarms": recorded - caught,
        "max_events_late": max(late) if late else None,
    }


@pytest.mark.live
def test_the_changes_told_to_staff_are_counted_against_the_true_ones(tmp_path: Path) -> None:
    """A staff key reads each person's changes told to staff: the command counts them against
    the changes the people's needs went through, its figures agree with each other and with a
    count made here from the service's own lists, and on this seeded run the default learner
    catches some changes, each after the change point. A run whose needs never change checks
    the false alarms target instead."""
    events, change_at = 60, 30
    with fresh_database("sqlite") as url, LiveService(url) as service:
        key = service.create_key("staff", name="fleet-staff")
        done = simulate(
            service,
            key,
            tmp_path,
            "--events",
            str(events),
            "--prefix",
            "fleet-s",
            change_at=change_at,
        )
        assert done.returncode == 0, done.stdout + done.stderr
        assert "Changes were not counted" not in done.stderr
        changes = json.loads(done.stdout)["changes"]
        assert set(changes) == {
            "counted",
            "persons",
            "events",
            "recorded",
            "true_changes",
            "caught",
            "caught_share",
            "missed",
            "within_visits",
            "caught_within",
            "caught_within_share",
            "median_events_late",
            "max_events_late",
            "false_alarms",
            "events_per_month",
            "false_alarms_per_person_month",
            "targets",
        }
        assert changes["counted"] is True
        assert (changes["persons"], changes["events"]) == (USERS, USERS * events)
        assert changes["caught"] + changes["missed"] == changes["true_changes"]
        assert changes["recorded"] == changes["caught"] + changes["false_alarms"]
        for share in ("caught_share", "caught_within_share"):
            assert 0 <= changes[share] <= 1
        assert changes["caught_share"] == changes["caught"] / changes["true_changes"]
        assert changes["false_alarms_per_person_month"] == pytest.approx(
            changes["events_per_month"] * changes["false_alarms"] / (USERS * events)
        )

        people = make_people(
            MISSION, users=USERS, events=events, change_at=change_at, seed=5, prefix="fleet-s"
        )
        listed = {p.user_id: listed_changes(service, key, p.user_id) for p in people}
        for name, value in counted_here(people, listed, change_at).items():
            assert changes[name] == value, name

        # This seeded run, with the default learner: changes to catch, some caught in time,
        # none of them before the change point, all within the run.
        assert changes["true_changes"] > 0
        assert 0 < changes["caught_within"] <= changes["caught"] <= changes["true_changes"]
        assert 0 <= changes["median_events_late"] <= changes["max_events_late"]
        assert changes["max_events_late"] < events - change_at
        caught_target, alarms_target = changes["targets"]
        assert caught_target["met"] == (changes["caught_within_share"] >= 0.9)
        assert caught_target["value"] == changes["caught_within_share"]
        assert alarms_target["met"] is None
        assert alarms_target["why"] == "needs a run without --change-at"

        # Needs that never change: no true change, every recorded one a false alarm; the
        # false alarms target is the one checked, in the table.
        still = simulate(
            service,
            key,
            tmp_path,
            "--users",
            "3",
            "--events",
            "40",
            "--prefix",
            "fleet-still",
            as_json=False,
            change_at=None,
        )
        assert still.returncode == 0, still.stderr
        table = still.stdout.splitlines()
        assert any("Changes told to staff" in line for line in table)
        row = next(line for line in table if line.startswith("│ true changes "))
        assert row.split("│")[2].strip() == "0"
        caught_row = next(
            line
            for line in table
            if "caught within 3 visits of the changed" in line and "target" in line
        )
        assert "not checked: needs a run with --change-at" in caught_row
        alarms_row = next(line for line in table if "≤ 1 false alarm per person" in line)
        assert alarms_row.rstrip(" │").endswith(("met", "MISSED"))


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
