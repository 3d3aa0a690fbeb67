"""An open-loop robot fleet: episodes start on a fixed schedule, whether or not earlier ones are
done, so a slow answer cannot slow the offered load down (no coordinated omission).

    python bench/openloop.py --url http://127.0.0.1:8000 --keys K1,K2 --users u1,u2 \\
        --rate 400 --duration 10

Robot ``i`` serves user ``i``; every ``1 / episode rate`` seconds the next robot in turn starts
an episode (an event near its person) and plays it to its end, each step sent as soon as the
previous answer arrived (a robot negotiates one step at a time). An episode that starts while
the robot's previous one is still running goes on beside it, on a connection of its own. The
request rate asked for is turned into an episode rate with ``--steps`` (requests per episode,
measured on the closed-loop run). Every request's latency is measured from the moment it was
sent; the first ``--warmup`` seconds are not counted. Loopback only; bounded in time and count.

Each person answers as the service's load benchmark's Lua robot does: a pass is met with no
request, a question about the service with ProvideDrink, a question about the detail with that
service's first detail, anything else is accepted.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import time
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

__all__ = ["OpenLoopResult", "run_open_loop"]

DETAIL = {"ProvideDrink": "tea", "BriefInformation": "news", "ArrangeSchedule": "today_agenda"}
SITUATIONS = ("arriving", "working", "stretching")


@dataclass
class OpenLoopResult:
    """Latencies (ms) of the counted requests, and what was offered and done."""

    latencies_ms: list[float] = field(default_factory=list)
    errors: int = 0
    episodes_started: int = 0
    episodes_done: int = 0
    offered_rps: float = 0.0
    seconds: float = 0.0

    def pct(self, q: float) -> float:
        values = sorted(self.latencies_ms)
        if not values:
            return math.nan
        return values[min(len(values) - 1, max(0, math.ceil(q * len(values)) - 1))]

    @property
    def achieved_rps(self) -> float:
        return len(self.latencies_ms) / self.seconds if self.seconds else 0.0


class _Connection:
    """One keep-alive HTTP/1.1 connection, speaking just enough of the protocol."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer

    async def request(self, head: bytes, body: bytes) -> tuple[int, bytes]:
        self.writer.write(head + body)
        status_line = await self.reader.readline()
        if not status_line:  # the server closed the idle keep-alive connection
            raise ConnectionResetError("connection closed before the response")
        status = int(status_line.split(b" ", 2)[1])
        length = 0
        while True:
            line = await self.reader.readline()
            if line in (b"\r\n", b"\n", b""):
                break
            name, _, value = line.partition(b":")
            if name.strip().lower() == b"content-length":
                length = int(value.strip())
        return status, await self.reader.readexactly(length)


class _Pool:
    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.idle: list[_Connection] = []

    async def get(self, *, fresh: bool = False) -> _Connection:
        if self.idle and not fresh:
            return self.idle.pop()
        reader, writer = await asyncio.open_connection(self.host, self.port)
        return _Connection(reader, writer)

    def put(self, connection: _Connection) -> None:
        self.idle.append(connection)

    def close(self) -> None:
        for c in self.idle:
            c.writer.close()


def _answer(decision: dict[str, Any]) -> dict[str, Any]:
    action = decision["action"]
    kind = action["kind"]
    body: dict[str, Any] = {"decision_id": decision["decision_id"]}
    if kind == "pass":
        body["response"] = "none"
    elif kind == "query_type":
        body.update(response="answered", service="ProvideDrink")
    elif kind == "query_detail":
        body.update(response="answered", detail=DETAIL.get(action.get("service", ""), "tea"))
    else:
        body["response"] = "accepted"
    return body


async def run_open_loop(
    url: str,
    keys: list[str],
    users: list[str],
    *,
    rate: float,
    steps: float,
    duration: float,
    warmup: float,
    tag: str,
    timeout: float = 10.0,
) -> OpenLoopResult:
    """Offer ``rate`` requests a second (as episodes of ``steps`` requests) for ``duration``
    seconds; the latencies of requests sent after ``warmup`` seconds are counted."""
    parts = urlsplit(url)
    host, port = parts.hostname or "127.0.0.1", parts.port or 80
    robots = [(_Pool(host, port), keys[i % len(keys)], users[i]) for i in range(len(users))]
    result = OpenLoopResult(offered_rps=rate)
    episode_rate = rate / max(1.0, steps)
    begin = time.monotonic()
    counted_from = begin + warmup
    tasks: list[asyncio.Task[None]] = []

    def head(method: str, path: str, key: str, length: int) -> bytes:
        return (
            f"{method} {path} HTTP/1.1\r\nHost: {host}:{port}\r\n"
            f"Authorization: Bearer {key}\r\nContent-Type: application/json\r\n"
            f"Content-Length: {length}\r\n\r\n"
        ).encode()

    async def call(
        pool: _Pool, key: str, path: str, doc: dict[str, Any]
    ) -> tuple[int, dict[str, Any]]:
        body = json.dumps(doc).encode()
        sent = time.monotonic()
        for attempt in range(2):
            connection = await pool.get(fresh=attempt > 0)
            try:
                status, raw = await asyncio.wait_for(
                    connection.request(head("POST", path, key, len(body)), body), timeout
                )
                break
            except ConnectionResetError:
                # A keep-alive connection the server had closed while idle: send again on a
                # new one, as HTTP clients do (the request is idempotent on its id).
                connection.writer.close()
                if attempt == 0:
                    continue
                result.errors += 1
                return 0, {}
            except (TimeoutError, OSError, asyncio.IncompleteReadError, ValueError):
                connection.writer.close()
                result.errors += 1
                return 0, {}
        pool.put(connection)
        if sent >= counted_from:
            if status < 300:
                result.latencies_ms.append((time.monotonic() - sent) * 1000.0)
            else:
                result.errors += 1
        return status, json.loads(raw) if raw else {}

    async def episode(n: int) -> None:
        pool, key, user = robots[n % len(robots)]
        status, doc = await call(
            pool,
            key,
            f"/v1/users/{user}/episodes",
            {
                "event_id": f"{tag}-{n}",
                "occurred_at": "2026-11-22T15:10:00+08:00",
                "situation": SITUATIONS[n % 3],
                "initiator": "robot",
                "robot_id": f"open-{n % 64}",
            },
        )
        decision = doc.get("decision") if status < 300 else None
        episode_id = doc.get("episode_id")
        for _ in range(8):  # a negotiation has at most four visible steps
            if decision is None:
                break
            status, doc = await call(
                pool, key, f"/v1/episodes/{episode_id}/outcomes", _answer(decision)
            )
            decision = doc.get("decision") if status < 300 else None
        result.episodes_done += 1

    n = 0
    while True:
        due = begin + n / episode_rate
        now = time.monotonic()
        if due - begin >= duration:
            break
        if due > now:
            await asyncio.sleep(due - now)
        tasks.append(asyncio.create_task(episode(n)))
        n += 1
    result.episodes_started = n
    if tasks:
        await asyncio.wait(tasks, timeout=timeout + 5)
    result.seconds = max(1e-9, duration - warmup)
    for pool, _, _ in robots:
        pool.close()
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", required=True)
    parser.add_argument("--keys", required=True, help="API keys, comma-separated")
    parser.add_argument("--users", required=True, help="user ids, one per robot")
    parser.add_argument("--rate", type=float, required=True, help="requests a second")
    parser.add_argument("--steps", type=float, default=3.0, help="requests per episode")
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--warmup", type=float, default=1.0)
    args = parser.parse_args()
    result = asyncio.run(
        run_open_loop(
            args.url,
            args.keys.split(","),
            args.users.split(","),
            rate=args.rate,
            steps=args.steps,
            duration=args.duration,
            warmup=args.warmup,
            tag=f"open-{int(time.time())}",
        )
    )
    print(
        json.dumps(
            {
                "offered_rps": result.offered_rps,
                "achieved_rps": result.achieved_rps,
                "p50_ms": result.pct(0.5),
                "p99_ms": result.pct(0.99),
                "errors": result.errors,
                "episodes": result.episodes_done,
            }
        )
    )


if __name__ == "__main__":
    main()
