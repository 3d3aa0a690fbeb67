"""Benchmark of the service's hot path: does a request cost more for a user with a long history,
or in a deployment with many users? (Issue "the service": a request's cost must not grow with the
user's history length or the number of users.)

    python bench/service.py                      # SQLite and PostgreSQL (127.0.0.1:5432)
    python bench/service.py --engine sqlite      # one engine
    python bench/service.py --history 2000       # a longer history for the "long" user

For each engine, in one run: one user's history is grown to 10 and then to --history episodes,
and the deployment to --users users; at each point the median latency of the robot's write path
(POST an episode, then POST its outcomes until it ends) is measured over --samples episodes,
through the ASGI app in-process (no network). The reference is the first point (10 episodes, or
--samples if more; one user) of the same run; the script prints each point's ratio to it.
"""

from __future__ import annotations

import argparse
import os
import secrets
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import psycopg  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.progress import track  # noqa: E402
from rich.table import Table  # noqa: E402

from app.db import migrate  # noqa: E402
from app.main import create_app  # noqa: E402
from app.services.auth import create_key  # noqa: E402
from app.settings import Settings  # noqa: E402

PG_SERVER = os.environ.get("ATTUNE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432")
SITUATIONS = ("arriving", "working", "stretching")


class Robot:
    """A scripted robot: accepts initiations, answers queries, accepts what is performed."""

    def __init__(self, client: TestClient) -> None:
        self.client = client
        self.n = 0

    def episode(self, user: str) -> list[float]:
        """Run one episode; the latency (s) of each write."""
        self.n += 1
        times = []
        t = time.perf_counter()
        r = self.client.post(f"/v1/users/{user}/episodes", json={
            "event_id": f"e{self.n}", "occurred_at": "2026-11-22T15:10:00+08:00",
            "situation": SITUATIONS[self.n % 3], "initiator": "robot"})
        times.append(time.perf_counter() - t)
        body: dict[str, Any] = r.json()
        assert r.status_code == 201, r.text
        ep, decision = body["episode_id"], body["decision"]
        while decision is not None:
            kind = decision["action"]["kind"]
            payload: dict[str, Any] = {"decision_id": decision["decision_id"]}
            if kind == "pass":
                payload["response"] = "none"
            elif kind == "query_type":
                payload.update(response="answered", service="ProvideDrink")
            elif kind == "query_detail":
                detail = {"ProvideDrink": "tea", "BriefInformation": "news",
                          "ArrangeSchedule": "today_agenda"}[decision["action"]["service"]]
                payload.update(response="answered", detail=detail)
            else:
                payload["response"] = "accepted"
            t = time.perf_counter()
            r = self.client.post(f"/v1/episodes/{ep}/outcomes", json=payload)
            times.append(time.perf_counter() - t)
            assert r.status_code == 200, r.text
            decision = r.json()["decision"]
        return times


def _database(engine: str, tmp: Path) -> tuple[str, Any]:
    if engine == "sqlite":
        return f"sqlite:///{tmp / 'bench.db'}", None
    name = f"attune_bench_{secrets.token_hex(4)}"
    with psycopg.connect(f"{PG_SERVER}/postgres", autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')

    def drop() -> None:
        with psycopg.connect(f"{PG_SERVER}/postgres", autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')

    return f"postgresql+psycopg://{PG_SERVER.split('://', 1)[1]}/{name}", drop


def _median_ms(robot: Robot, user: str, samples: int) -> float:
    times: list[float] = []
    for _ in range(samples):
        times += robot.episode(user)
    return statistics.median(times) * 1000


def run_engine(engine: str, history: int, users: int, samples: int, console: Console
               ) -> list[tuple[str, float]]:
    with tempfile.TemporaryDirectory() as tmp:
        url, drop = _database(engine, Path(tmp))
        try:
            migrate.upgrade(url)
            app = create_app(Settings(database_url=url, _env_file=None))  # type: ignore[call-arg]
            with app.state.db.transaction() as session:
                _, key = create_key(session, role="robot")
            with TestClient(app, headers={"Authorization": f"Bearer {key}"}) as client:
                robot = Robot(client)
                base = max(10, samples)
                for _ in range(base - samples):
                    robot.episode("long")
                points = [(f"{base} episodes, 1 user", _median_ms(robot, "long", samples))]
                grown = base + samples
                for _ in track(range(history - grown), description=f"{engine}: history",
                               console=console, transient=True):
                    robot.episode("long")
                points.append((f"{history} episodes, 1 user",
                               _median_ms(robot, "long", samples)))
                for i in track(range(users - 1), description=f"{engine}: users",
                               console=console, transient=True):
                    robot.episode(f"u{i}")
                points.append((f"{history} episodes, {users} users",
                               _median_ms(robot, "long", samples)))
                points.append((f"new user among {users} users",
                               _median_ms(robot, "fresh", min(samples, 10))))
            app.state.db.dispose()
        finally:
            if drop is not None:
                drop()
    return points


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--engine", choices=["sqlite", "postgresql", "both"], default="both")
    parser.add_argument("--history", type=int, default=1000, help="long user's episodes")
    parser.add_argument("--users", type=int, default=300, help="users in the deployment")
    parser.add_argument("--samples", type=int, default=5,
                        help="episodes timed per point (each has 2-4 writes)")
    args = parser.parse_args()
    console = Console()
    engines = ["sqlite", "postgresql"] if args.engine == "both" else [args.engine]
    table = Table("engine", "point", "median write (ms)", "× reference",
                  title="Robot write latency (POST episode / outcome), in-process ASGI")
    for engine in engines:
        points = run_engine(engine, args.history, args.users, args.samples, console)
        ref = points[0][1]
        for label, ms in points:
            table.add_row(engine, label, f"{ms:.2f}", f"{ms / ref:.2f}")
    console.print(table)
    console.print("Reference: the first point (short history, one user) of the same engine "
                  "and run.")


if __name__ == "__main__":
    main()
