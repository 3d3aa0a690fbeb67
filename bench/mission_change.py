"""Benchmark of a mission change: how long does a fleet's change hold its users?

    .venv/bin/python bench/mission_change.py                       # 100 and 1000 users, SQLite
    .venv/bin/python bench/mission_change.py --engine postgresql   # on 127.0.0.1:5432
    .venv/bin/python bench/mission_change.py --users 200,2000 --episodes 10 --json out.json

For each fleet size, one process builds a fresh database: --users people of one fleet, each with
--episodes episodes written through the services the v1 API uses (so every model has history
and a stored learner state). Then the fleet's mission changes (cocoa added under ProvideDrink,
stocks dropped) through the same service function as ``PUT /v1/admin/fleets/{fleet}/mission``,
in one transaction, as the API runs it: every model is loaded, carried to the new version and
stored, and the fleet's users wait meanwhile. Printed per size: the change's wall time, the time
per model moved, and, as the reference, the median time of one robot write (an episode's start)
measured while building, in the same run: "models per robot write" says how many robot writes'
worth of time each moved model costs. Every loop is bounded by the arguments.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import random
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rich.console import Console
from rich.progress import track
from rich.table import Table

from app.db import migrate
from app.db.session import Database
from app.learning import office_mission
from app.schemas.episodes import EpisodeIn, OutcomeIn
from app.services import episodes, missions
from app.services.context import Principal, ServiceContext
from app.settings import Settings
from tests.support.live import fresh_database
from tests.support.people import answer

out = Console(stderr=True)
WHO = Principal("key_bench", "admin", "default")
SITUATIONS = ("arriving", "working", "stretching")
HOURS = (9, 12, 15, 19)


def changed_mission() -> dict[str, Any]:
    doc = office_mission().to_dict()
    doc["services"] = [
        {
            "name": s["name"],
            "details": [*s["details"], "cocoa"]
            if s["name"] == "ProvideDrink"
            else [d for d in s["details"] if d != "stocks"],
        }
        for s in doc["services"]
    ]
    return doc


def run(engine: str, n_users: int, n_episodes: int) -> dict[str, Any]:
    with fresh_database(engine) as url:
        migrate.upgrade(url)
        settings = Settings(database_url=url, _env_file=None)  # type: ignore[call-arg]
        db, ctx = Database(settings), ServiceContext.from_settings(settings)
        rnd = random.Random(5)
        start = dt.datetime(2026, 1, 1, tzinfo=dt.timezone(dt.timedelta(hours=8)))
        writes: list[float] = []
        try:
            for u in track(range(n_users), description=f"{engine}: {n_users} people", console=out):
                with db.transaction() as session:
                    for n in range(n_episodes):
                        when = (start + dt.timedelta(days=n)).replace(hour=HOURS[n % 4])
                        t = time.perf_counter()
                        body = episodes.start_episode(
                            session,
                            ctx,
                            WHO,
                            f"p{u:05d}",
                            EpisodeIn(
                                event_id=f"e{n}", occurred_at=when, situation=SITUATIONS[n % 3]
                            ),
                        ).body
                        writes.append(time.perf_counter() - t)
                        decision = body["decision"]
                        while decision is not None:
                            outcome = OutcomeIn(
                                decision_id=decision["decision_id"],
                                **answer(decision["action"], rng=rnd, yes=0.9, asks=0.5),
                            )
                            decision = episodes.report_outcome(
                                session, ctx, WHO, body["episode_id"], outcome
                            ).body["decision"]
            t = time.perf_counter()
            with db.transaction() as session:
                answer_ = missions.set_mission(
                    session,
                    ctx,
                    WHO,
                    "default",
                    change_id="bench",
                    mission_doc=changed_mission(),
                    renames_doc=None,
                )[0]
            took = time.perf_counter() - t
        finally:
            db.dispose()
    assert answer_["users_moved"] == n_users, answer_
    write = statistics.median(writes)
    return {
        "engine": engine,
        "users": n_users,
        "episodes_per_user": n_episodes,
        "change_s": took,
        "ms_per_model": 1000 * took / n_users,
        "robot_write_ms": 1000 * write,
        "models_per_robot_write": took / n_users / write,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--engine", choices=["sqlite", "postgresql", "both"], default="sqlite")
    parser.add_argument(
        "--users", default="100,1000", help="fleet sizes, comma-separated (default: 100,1000)"
    )
    parser.add_argument("--episodes", type=int, default=5, help="episodes per person")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    engines = ["sqlite", "postgresql"] if args.engine == "both" else [args.engine]
    sizes = [int(n) for n in args.users.split(",")]
    rows = [run(engine, n, args.episodes) for engine in engines for n in sizes]
    table = Table(
        "engine",
        "people",
        "change (s)",
        "ms per model moved",
        "one robot write (ms, median)",
        "robot writes per model moved",
    )
    for r in rows:
        table.add_row(
            r["engine"],
            str(r["users"]),
            f"{r['change_s']:.2f}",
            f"{r['ms_per_model']:.2f}",
            f"{r['robot_write_ms']:.2f}",
            f"{r['models_per_robot_write']:.1f}",
        )
    Console().print(table)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
