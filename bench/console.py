"""Benchmark of the admin console: does a user with a long history open in under a second?

    .venv/bin/python bench/console.py                        # 10,000 episodes, SQLite
    .venv/bin/python bench/console.py --engine postgresql    # on 127.0.0.1:5432
    .venv/bin/python bench/console.py --episodes 2000 --runs 5

One process builds a fresh database: one person with --episodes episodes (written through the
services the v1 API uses, a few hundred episodes per transaction; 1 to 3 minutes for 10,000 on
two cores) and --users more users without history. Then ``attune serve`` starts on 127.0.0.1
(loopback only) on that database, an admin key signs in to the console, and each page is timed
over --runs runs after one warm-up:

- server: GET of the page's HTML over HTTP, until the last byte;
- chromium: headless Chromium (/usr/bin/chromium) navigating to the page, until the load event
  (HTML, styles, scripts, the reward chart drawn), from the Navigation Timing of the page itself.

It prints min / median / max per page and says whether every page met the target (--target,
1 s). Every loop is bounded by the arguments.
"""

from __future__ import annotations

import argparse
import datetime as dt
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import httpx
from rich.console import Console
from rich.progress import track
from rich.table import Table

from app.db import migrate
from app.db.session import Database
from app.schemas.episodes import EpisodeIn, OutcomeIn
from app.schemas.users import UserIn
from app.services import episodes, users
from app.services.context import Principal, ServiceContext
from app.settings import Settings
from tests.support.live import LiveService, fresh_database
from tests.support.people import answer

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
USER = "big"
BATCH = 250  # episodes per transaction while building the history
SLOTS = {"morning": 9, "noon": 12, "afternoon": 15, "evening": 19}
SITUATIONS = ("arriving", "working", "stretching", "busy")
NEEDS = {
    ("afternoon", "stretching"): ("ProvideDrink", "tea"),
    ("morning", "arriving"): ("BriefInformation", "news"),
    ("morning", "working"): ("ArrangeSchedule", "today_agenda"),
}

out = Console()


def build(database_url: str, n_episodes: int, n_users: int) -> None:
    """The person's history and the other users, through the services, in batches."""
    migrate.upgrade(database_url)
    settings = Settings(database_url=database_url, _env_file=None)  # type: ignore[call-arg]
    db, ctx = Database(settings), ServiceContext.from_settings(settings)
    who = Principal("key_bench", "admin", "default")
    rnd = random.Random(11)
    start = dt.datetime(2025, 1, 1, tzinfo=dt.timezone(dt.timedelta(hours=8)))
    try:
        with db.transaction() as session:
            users.put_user(
                session, ctx, who, USER, UserIn(display_name="Long history"), reset_model=False
            )
            for i in range(n_users):
                users.put_user(session, ctx, who, f"user-{i:05d}", UserIn(), reset_model=False)
        for first in track(range(0, n_episodes, BATCH), description="history", console=out):
            with db.transaction() as session:
                for n in range(first, min(n_episodes, first + BATCH)):
                    if rnd.random() < 0.7:
                        slot, situation = rnd.choice(sorted(NEEDS))
                    else:
                        slot, situation = rnd.choice(sorted(SLOTS)), rnd.choice(SITUATIONS)
                    when = (start + dt.timedelta(days=n // 8)).replace(hour=SLOTS[slot])
                    need = NEEDS.get((slot, situation))
                    body = episodes.start_episode(
                        session,
                        ctx,
                        who,
                        USER,
                        EpisodeIn(
                            event_id=f"e{n}",
                            occurred_at=when,
                            situation=situation,
                            robot_id="robot7",
                        ),
                    ).body
                    decision = body["decision"]
                    while decision is not None:
                        outcome = OutcomeIn(
                            decision_id=decision["decision_id"],
                            **answer(
                                decision["action"],
                                need=need,
                                busy=situation == "busy",
                                rng=rnd,
                                yes=0.95,
                                asks=0.5,
                            ),
                        )
                        decision = episodes.report_outcome(
                            session, ctx, who, body["episode_id"], outcome
                        ).body["decision"]
    finally:
        db.dispose()


def _stats(samples: list[float]) -> tuple[float, float, float]:
    return min(samples), statistics.median(samples), max(samples)


def time_server(base: str, key: str, pages: dict[str, str], runs: int) -> dict[str, list[float]]:
    found: dict[str, list[float]] = {}
    with httpx.Client(base_url=base, cookies={"attune_console": key}, timeout=60) as client:
        for name, path in pages.items():
            client.get(path)  # warm-up: the worker's caches, the connection
            found[name] = []
            for _ in range(runs):
                t = time.perf_counter()
                r = client.get(path)
                found[name].append(time.perf_counter() - t)
                assert r.status_code == 200, (path, r.status_code, r.text[:300])
    return found


def time_chromium(
    base: str, key: str, pages: dict[str, str], runs: int
) -> dict[str, list[float]] | None:
    if not Path(CHROMIUM).exists():
        out.print(f"[yellow]{CHROMIUM} is missing: no browser timings[/yellow]")
        return None
    from playwright.sync_api import sync_playwright

    found: dict[str, list[float]] = {}
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS
        )
        context = browser.new_context(viewport={"width": 1280, "height": 800})
        context.add_cookies(
            [
                {
                    "name": "attune_console",
                    "value": key,
                    "url": base + "/admin",
                    "httpOnly": True,
                    "sameSite": "Strict",
                }
            ]
        )
        page = context.new_page()
        for name, path in pages.items():
            page.goto(base + path, wait_until="load")  # warm-up
            found[name] = []
            for _ in range(runs):
                response = page.goto(base + path, wait_until="load")
                if response is None or response.status != 200:
                    raise SystemExit(f"{path}: {response.status if response else 'no answer'}")
                load = page.evaluate("performance.getEntriesByType('navigation')[0].loadEventEnd")
                found[name].append(float(load) / 1000)
        browser.close()
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--engine", choices=["sqlite", "postgresql"], default="sqlite")
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--users", type=int, default=300, help="users without history")
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--target", type=float, default=1.0, help="seconds")
    args = parser.parse_args()
    if not (1 <= args.episodes <= 200_000 and 0 <= args.users <= 100_000 and 1 <= args.runs <= 100):
        parser.error("--episodes 1..200000, --users 0..100000, --runs 1..100")

    with tempfile.TemporaryDirectory() as tmp, fresh_database(args.engine, Path(tmp)) as url:
        t = time.perf_counter()
        build(url, args.episodes, args.users)
        out.print(
            f"Built {args.episodes} episodes of {USER!r} and {args.users} more users "
            f"on {args.engine} in {time.perf_counter() - t:.0f} s."
        )
        with LiveService(url, log_path=Path(tmp) / "serve.log") as service:
            key = service.create_key("admin", name="bench")
            with httpx.Client(
                base_url=service.url, timeout=60, headers={"Authorization": f"Bearer {key}"}
            ) as api:
                latest = api.get(f"/v1/users/{USER}/episodes", params={"limit": 1}).json()
            episode_id = latest["items"][0]["episode_id"]
            pages = {
                "users": "/admin/users",
                "profile": f"/admin/users/{USER}",
                "profile, a box opened": f"/admin/users/{USER}?time_slot=afternoon"
                "&situation=stretching",
                "details for engineers": f"/admin/users/{USER}/details",
                "why this action": f"/admin/users/{USER}/why",
                "episodes": f"/admin/users/{USER}/episodes",
                "trace (fragment)": f"/admin/users/{USER}/episodes/{episode_id}/trace",
            }
            server = time_server(service.url, key, pages, args.runs)
            browser = time_chromium(service.url, key, pages, args.runs)

    table = Table(
        title=f"Console pages, user with {args.episodes:,} episodes, {args.engine}, "
        f"{args.runs} runs (seconds: min / median / max)"
    )
    table.add_column("page")
    table.add_column("server (HTML)", justify="right")
    table.add_column("chromium (load event)", justify="right")
    worst = 0.0
    for name in pages:
        s = _stats(server[name])
        b = _stats(browser[name]) if browser else None
        worst = max(worst, s[2], b[2] if b else 0.0)
        table.add_row(
            name, " / ".join(f"{v:.3f}" for v in s), " / ".join(f"{v:.3f}" for v in b) if b else "—"
        )
    out.print(table)
    verdict = "met" if worst < args.target else "NOT met"
    out.print(
        f"Target: every page under {args.target:g} s, slowest run included: {verdict} "
        f"(slowest {worst:.3f} s)."
    )
    sys.exit(0 if worst < args.target else 1)


if __name__ == "__main__":
    main()
