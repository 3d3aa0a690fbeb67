"""What a shadow costs the robots: their latency and the server's CPU per request, without and
with a shadow whose pass runs every second.

    .venv/bin/python bench/shadow.py                                     # both engines
    .venv/bin/python bench/shadow.py --engine sqlite --people 50 --rate 100 --seconds 30
    .venv/bin/python bench/shadow.py --engine postgresql --delay 1        # the database a hop away
    .venv/bin/python bench/shadow.py --engine postgresql --pooler pgbouncer
    .venv/bin/python bench/shadow.py --engine sqlite --json > shadow.json

Loopback only. Per engine, in one run: a fresh database (a file on SQLite, ``attune_bench_...``
on the PostgreSQL server at 127.0.0.1:5432, ``ATTUNE_TEST_POSTGRES_URL``) and ``attune serve``
(1 worker on SQLite, 2 on PostgreSQL, as ``bench/service.py`` runs them) with
``ATTUNE_SHADOW_SECONDS=1`` (``--shadow-seconds``): the shadow pass (app/services/shadows.py)
wakes every second, the worst case (the service's default is 30). The rate limiter stays on,
far above the load. A staff key is made with ``attune keys create --role staff``, and
``--people`` people (default 50) of the fleet ``default`` get ``--history`` episodes each
(default 4) through the API first, so that a pass has a history to replay. Then, each phase
after ``--warmup`` seconds (default 5) of the same load, not counted:

- **no shadow** (the reference): the open-loop robots of ``bench/openloop.py`` (episodes start on
  a fixed schedule, whether or not earlier answers came back, so a slow answer cannot slow the
  offered load) at ``--rate`` requests a second (default 100: a moderate load, well under the
  half of its capacity at which ``bench/service.py``'s open loop runs on this kind of machine,
  250 to 600) for ``--seconds`` (default 30). Robot ``i`` serves person ``i``, each person
  answers as the load benchmark's robot does; the rate is turned into episodes with the
  requests per episode of the first warm-up (of the history fill without one). The pass runs
  too, with no shadow to serve.
- **shadow**: ``PUT /v1/admin/fleets/default/shadow`` with ``{"candidate": ..., "share": 1.0}``
  (``--candidate``, default ``dts``; ``ALGORITHM[:NAME=VALUE,...]`` as ``attune evaluate``
  takes it), the same load for the same time; then, the robots stopped, a wait until the pass
  has looked at every episode they closed.

Of each phase it prints the robots' requests, p50, p99 and max of every request's latency, the
server's CPU per request (all its processes, from /proc), the database's (PostgreSQL: its server
processes of the benchmark's database, from /proc), each worker's worst event-loop stall
(``attune_event_loop_stall_max_seconds`` of /metrics, read as ``bench/remote_db.py`` reads it),
and of it the CPU of the shadow passes (each pass runs in a Python process of its own that a
worker starts, ``python -m app.services.shadows``: the CPU of such processes still running, read
from /proc, plus the CPU of those that ended, which the kernel adds to the worker that waited
for them, ``cutime`` and ``cstime``; the server's CPU counts both too). Of the shadow phase
also the decisions the shadow stored (``GET .../shadow``) a second in the window, and once the
robots stop, how many it stored in all after the pass caught up. Then both phases side by side
with the ratios (shadow / no shadow: p50, p99, CPU per request), and the bound the docs give,
met or missed: **p99 with the shadow at most 1.5 times the p99 without, and at most 10 ms more**.
The exit status is 0 when every engine's shadow stored decisions (the bound is reported, not
enforced), 1 otherwise.

``--estimate-minutes`` sets ``ATTUNE_SHADOW_ESTIMATE_MINUTES`` (default: the service's, 60, so
the shadow's off-policy estimate is made once, at the first pass, over the few episodes since the
shadow started; a smaller value puts estimates over a growing fleet history in the window).
``--rounds N`` runs the two phases N times in turn (the shadow stopped with ``DELETE`` before
each later reference, a new one started for each shadow phase), each window ``--seconds`` long,
and pools each phase's windows: on a machine whose other work comes and goes, and with a
database that grows as the robots play, figures taken in turn compare better than one window
after the other.

``--delay MS`` (PostgreSQL) puts the database one network hop away for the service, through the
delaying TCP proxy of ``bench/remote_db.py`` (``bench/delayproxy.py``); ``--pooler pgbouncer``
puts Debian's PgBouncer in transaction pooling between them (both as ``bench/retention.py`` does).

Bounded: every robot request times out after 10 s (a history request after 30 s), each phase
lasts ``--warmup`` + ``--seconds`` and the episodes in flight at its end, the wait for the pass
to catch up at most 60 s and two passes.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as dt
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

import httpx  # noqa: E402
from openloop import SITUATIONS, OpenLoopResult, _answer, run_open_loop  # noqa: E402
from remote_db import StallWatch  # noqa: E402
from retention import place  # noqa: E402
from service import group_cpu_s, machine, wait_workers  # noqa: E402
from sqlalchemy.engine import make_url  # noqa: E402

from app.services.evaluation import parse_candidate  # noqa: E402
from tests.support.live import LiveService, make_keys  # noqa: E402
from tests.support.pgbouncer import PgBouncerFailed  # noqa: E402

FLEET = "default"
SHADOW_SECONDS = 1.0  # ATTUNE_SHADOW_SECONDS of the measured service by default: the worst case
P99_RATIO = 1.5  # the bound: p99 with the shadow at most this × the p99 without...
P99_MARGIN_MS = 10.0  # ...and at most this much more
REQUEST_TIMEOUT_S = 10.0  # a robot request of the phases
HISTORY_TIMEOUT_S = 30.0  # a request of the history fill (a person's first one makes them)
CATCH_UP_S = 60.0  # the longest wait for the pass to shadow the last episodes
MAX_STEPS = 8  # a negotiation has at most four visible steps
FILL_THREADS = 4
REFERENCE = "no shadow"
SHADOWED = "shadow"
_TICK = os.sysconf("SC_CLK_TCK")


def say(line: str) -> None:
    """A progress line, on stderr (stdout is for the report)."""
    print(f"{time.strftime('%H:%M:%S')} {line}", file=sys.stderr, flush=True)


# -- CPU from /proc -------------------------------------------------------------------------------
def _ticks(stat_path: str) -> int | None:
    try:
        fields = Path(stat_path).read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return int(fields[11]) + int(fields[12])  # utime, stime


def _pass_process(pid: int) -> bool:
    """Whether process ``pid`` is a shadow pass (``python -m app.services.shadows``)."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    return b"app.services.shadows" in argv


def server_cpu_s(pgid: int) -> tuple[float, float]:
    """CPU seconds so far of the server's process group, and of it the shadow passes'.

    The server's: ``group_cpu_s`` (every process of the group as it runs) plus the CPU of the
    group's children that ended and were waited for (``cutime`` + ``cstime``: the passes, each
    a short-lived process of a worker). The passes': those ended ones plus those running now.
    Between two readings each difference is the CPU spent in between, a pass that ran across a
    reading included (its part before it counted at the first, its whole at the second)."""
    reaped = 0
    running = 0
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) != pgid:  # pgrp
            continue
        reaped += int(fields[13]) + int(fields[14])  # cutime, cstime
        if _pass_process(int(entry)):
            running += int(fields[11]) + int(fields[12])  # utime, stime
    return group_cpu_s(pgid) + reaped / _TICK, (reaped + running) / _TICK


def database_ticks(name: str) -> dict[int, int]:
    """PostgreSQL: CPU ticks so far of each server process of database ``name`` (a backend's
    title names its database), when the server runs on this machine; {} otherwise."""
    found: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            title = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, UnicodeDecodeError):
            continue
        if title.startswith("postgres:") and f" {name} " in f"{title} ":
            ticks = _ticks(f"/proc/{entry}/stat")
            if ticks is not None:
                found[int(entry)] = ticks
    return found


def database_cpu_s(before: dict[int, int], after: dict[int, int]) -> float:
    """CPU seconds of the database's processes between two readings (a process that ended in
    between is not counted; one that started is counted from 0)."""
    return sum(t - before.get(pid, 0) for pid, t in after.items()) / _TICK


# -- the service ----------------------------------------------------------------------------------
def api(service: LiveService, key: str, method: str, path: str, body: Any = None) -> httpx.Response:
    return httpx.request(
        method,
        f"{service.url}{path}",
        json=body,
        headers={"Authorization": f"Bearer {key}"},
        timeout=HISTORY_TIMEOUT_S,
    )


def look(service: LiveService, staff: str) -> dict[str, Any]:
    """``GET .../shadow``."""
    r = api(service, staff, "GET", f"/v1/admin/fleets/{FLEET}/shadow")
    r.raise_for_status()
    doc: dict[str, Any] = r.json()
    return doc


def fill_history(url: str, keys: list[str], people: list[str], episodes: int) -> dict[str, Any]:
    """``episodes`` whole episodes of each person through the API, a few robots at once, each
    person's in order; the requests per episode they took."""

    def play(i: int) -> int:
        person = people[i]
        headers = {"Authorization": f"Bearer {keys[i % len(keys)]}"}
        sent = 0
        with httpx.Client(base_url=url, headers=headers, timeout=HISTORY_TIMEOUT_S) as client:
            for e in range(episodes):
                r = client.post(
                    f"/v1/users/{person}/episodes",
                    json={
                        "event_id": f"history-{i}-{e}",
                        "occurred_at": "2026-11-22T15:10:00+08:00",
                        "situation": SITUATIONS[e % len(SITUATIONS)],
                        "initiator": "robot",
                        "robot_id": f"history-{i % 64}",
                    },
                )
                r.raise_for_status()
                sent += 1
                started = r.json()
                decision = started["decision"]
                for _ in range(MAX_STEPS):
                    if decision is None:
                        break
                    r = client.post(
                        f"/v1/episodes/{started['episode_id']}/outcomes", json=_answer(decision)
                    )
                    r.raise_for_status()
                    sent += 1
                    decision = r.json()["decision"]
        return sent

    began = time.monotonic()
    with ThreadPoolExecutor(FILL_THREADS) as pool:
        requests = sum(pool.map(play, range(len(people))))
    total = len(people) * episodes
    return {
        "people": len(people),
        "episodes": total,
        "requests": requests,
        "requests_per_episode": requests / max(total, 1),
        "seconds": time.monotonic() - began,
    }


# -- a phase --------------------------------------------------------------------------------------
@dataclass
class Window:
    """What one measured window of a phase saw (a phase has one per round)."""

    latencies_ms: list[float]
    errors: int
    episodes: int
    seconds: float
    cpu_s: float  # the server's processes
    pass_cpu_s: float  # of it, the shadow pass's thread(s)
    database_cpu_s: float  # PostgreSQL's processes of the database
    worst_stall_ms: dict[str, float]
    worst_busy_stall_ms: dict[str, float]
    decisions: int | None  # stored by the shadow during the window


@dataclass
class Phase:
    """The figures of a phase: its measured windows together."""

    name: str
    offered_rps: float
    windows: int
    seconds: float
    requests: int
    rps: float
    errors: int
    episodes: int
    p50_ms: float
    p99_ms: float
    max_ms: float
    cpu_ms_per_request: float
    pass_cpu_ms_per_request: float | None  # of it, the shadow pass's thread(s)
    pass_cpu_share: float | None  # the pass's CPU seconds per second: the share of a core
    database_cpu_ms_per_request: float | None  # PostgreSQL's processes, beside the server's
    worst_stall_ms: dict[str, float] = field(default_factory=dict)  # by worker pid
    worst_busy_stall_ms: dict[str, float] = field(default_factory=dict)  # the loop's own part
    decisions: int | None = None  # stored by the shadow during the windows
    decisions_per_s: float | None = None


def _pct(values: list[float], q: float) -> float:
    return OpenLoopResult(latencies_ms=values).pct(q)


def _worst(maps: list[dict[str, float]]) -> dict[str, float]:
    out: dict[str, float] = {}
    for m in maps:
        for pid, ms in m.items():
            out[pid] = max(out.get(pid, 0.0), ms)
    return dict(sorted(out.items()))


def summarize(
    name: str, windows: list[Window], rate: float, separated: bool, database: bool
) -> Phase:
    """A phase's figures over its windows: the latencies pooled, CPU per request over all."""
    latencies = [ms for w in windows for ms in w.latencies_ms]
    seconds = sum(w.seconds for w in windows)
    done = len(latencies)
    per = 1000.0 / max(done, 1)
    counted = [w.decisions for w in windows if w.decisions is not None]
    decisions = sum(counted) if counted else None
    pass_s = sum(w.pass_cpu_s for w in windows)
    return Phase(
        name=name,
        offered_rps=rate,
        windows=len(windows),
        seconds=seconds,
        requests=done,
        rps=done / max(seconds, 1e-9),
        errors=sum(w.errors for w in windows),
        episodes=sum(w.episodes for w in windows),
        p50_ms=_pct(latencies, 0.50),
        p99_ms=_pct(latencies, 0.99),
        max_ms=max(latencies, default=math.nan),
        cpu_ms_per_request=sum(w.cpu_s for w in windows) * per,
        pass_cpu_ms_per_request=pass_s * per if separated else None,
        pass_cpu_share=pass_s / max(seconds, 1e-9) if separated else None,
        database_cpu_ms_per_request=(
            sum(w.database_cpu_s for w in windows) * per if database else None
        ),
        worst_stall_ms=_worst([w.worst_stall_ms for w in windows]),
        worst_busy_stall_ms=_worst([w.worst_busy_stall_ms for w in windows]),
        decisions=decisions,
        decisions_per_s=None if decisions is None else decisions / max(seconds, 1e-9),
    )


@dataclass
class Robots:
    """The service under test and what drives it."""

    service: LiveService
    keys: list[str]
    people: list[str]
    steps: float  # requests per episode: the history's, then the first warm-up's
    database: str | None  # PostgreSQL: the database's name, for its processes' CPU
    calibrated: bool = False


def run_window(
    name: str,
    robots: Robots,
    args: argparse.Namespace,
    count_decisions: Callable[[], int] | None = None,
) -> Window:
    """``--warmup`` s of load (not counted), then ``--seconds`` measured."""
    service = robots.service
    assert service.process is not None
    pgid = service.process.pid
    tag = f"{name.replace(' ', '-')}-{time.time_ns()}"

    def load(duration: float, warmup: float, tag: str) -> OpenLoopResult:
        return asyncio.run(
            run_open_loop(
                service.url,
                robots.keys,
                robots.people,
                rate=args.rate,
                steps=robots.steps,
                duration=duration,
                warmup=warmup,
                tag=tag,
                timeout=REQUEST_TIMEOUT_S,
            )
        )

    say(f"  {name}: {args.rate:g} requests/s, {args.warmup:g} s warm-up, {args.seconds:g} s")
    if args.warmup > 0:
        warm = load(args.warmup, 0.0, f"{tag}-w")  # not counted
        if not robots.calibrated and warm.episodes_done:
            # Episodes get shorter as the learners learn their people: the requests per
            # episode of the first warm-up, not of the history, set every window's episode
            # rate, so that the requests a second come near --rate.
            robots.steps = (len(warm.latencies_ms) + warm.errors) / warm.episodes_done
            robots.calibrated = True
    decisions0 = count_decisions() if count_decisions is not None else None
    db0 = database_ticks(robots.database) if robots.database else {}
    cpu0, pass0 = server_cpu_s(pgid)
    began = time.monotonic()
    with StallWatch(service.url, args.seconds) as stalls:
        result = load(args.seconds, 0.0, tag)
    cpu1, pass1 = server_cpu_s(pgid)
    wall = time.monotonic() - began
    db1 = database_ticks(robots.database) if robots.database else {}
    decisions1 = count_decisions() if count_decisions is not None else None
    return Window(
        latencies_ms=result.latencies_ms,
        errors=result.errors,
        episodes=result.episodes_done,
        seconds=wall,
        cpu_s=cpu1 - cpu0,
        pass_cpu_s=pass1 - pass0,
        database_cpu_s=database_cpu_s(db0, db1),
        worst_stall_ms={pid: v * 1000 for pid, v in stalls.worst.items()},
        worst_busy_stall_ms={pid: v * 1000 for pid, v in stalls.busy.items()},
        decisions=(None if decisions0 is None or decisions1 is None else decisions1 - decisions0),
    )


def catch_up(
    service: LiveService, staff: str, until: dt.datetime, every: float
) -> tuple[dict[str, Any], float]:
    """Wait (at most ``CATCH_UP_S`` + two passes ``every`` s apart) until the pass has looked at
    every episode closed before ``until`` and stored nothing more for a pass; the look then,
    and the seconds waited."""
    began = time.monotonic()
    seen = look(service, staff)
    while time.monotonic() - began < CATCH_UP_S + 2 * every:
        time.sleep(every * 1.5)
        now = look(service, staff)
        checked = dt.datetime.fromisoformat(now["checked_until"])
        if checked >= until and now["decisions"] == seen["decisions"]:
            return now, time.monotonic() - began
        seen = now
    return seen, time.monotonic() - began


# -- an engine ------------------------------------------------------------------------------------
def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or math.isnan(a) or math.isnan(b) or not b:
        return None
    return a / b


def _workers(engine: str, args: argparse.Namespace) -> int:
    return int(args.workers or (1 if engine == "sqlite" else 2))


def bound(reference: Phase, shadowed: Phase) -> dict[str, Any]:
    """The documented bound on the robots' p99 with a shadow, checked."""
    limit = min(P99_RATIO * reference.p99_ms, reference.p99_ms + P99_MARGIN_MS)
    return {
        "rule": f"p99 with the shadow <= {P99_RATIO:g} x the p99 without, "
        f"and <= that + {P99_MARGIN_MS:g} ms",
        "p99_ratio_max": P99_RATIO,
        "p99_margin_ms": P99_MARGIN_MS,
        "limit_ms": limit,
        "p99_ms": shadowed.p99_ms,
        "met": bool(shadowed.p99_ms <= limit),
    }


def run_engine(engine: str, args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    workers = _workers(engine, args)
    spec = parse_candidate(args.candidate)
    candidate = {"algorithm": spec.algorithm, "params": dict(spec.params)}
    say(f"{engine}: {workers} worker(s), {args.people} people, candidate {spec.label}")
    # The proxy (--delay) stops by itself after the run's longest time.
    per_round = 2 * (args.warmup + args.seconds + 30) + CATCH_UP_S + 2 * args.shadow_seconds
    minutes = (args.rounds * per_round + 900) / 60
    where_args = argparse.Namespace(delay=args.delay, pooler=args.pooler, max_run_minutes=minutes)
    with place(engine, where_args, folder) as where:
        env = {
            **where.env,
            "ATTUNE_SHADOW_SECONDS": f"{args.shadow_seconds:g}",
            # The limiter stays on (its cost is part of the figures) but far above the load.
            "ATTUNE_RATE_LIMIT_PER_S": "1000000",
            "ATTUNE_RATE_LIMIT_BURST": "1000000",
        }
        if args.estimate_minutes is not None:
            env["ATTUNE_SHADOW_ESTIMATE_MINUTES"] = f"{args.estimate_minutes:g}"
        log_path = folder / f"serve-{engine}.log"
        with LiveService(where.service_url, workers=workers, env=env, log_path=log_path) as service:
            if workers > 1:
                wait_workers(service.url, workers, log_path)
            assert service.process is not None
            staff = service.create_key("staff", FLEET, name="bench-shadow")
            keys = make_keys(where.direct_url, args.keys, "robot", FLEET)
            people = [f"shadow-{i:04d}" for i in range(args.people)]
            say(f"  history: {args.history} episodes of each of {args.people} people")
            fill = fill_history(service.url, keys, people, args.history)
            robots = Robots(
                service,
                keys,
                people,
                fill["requests_per_episode"],
                make_url(where.direct_url).database if engine != "sqlite" else None,
            )
            windows: dict[str, list[Window]] = {REFERENCE: [], SHADOWED: []}
            shadows: list[dict[str, Any]] = []
            for n in range(args.rounds):
                if args.rounds > 1:
                    say(f"  round {n + 1} of {args.rounds}")
                windows[REFERENCE].append(run_window(REFERENCE, robots, args))
                r = api(
                    service,
                    staff,
                    "PUT",
                    f"/v1/admin/fleets/{FLEET}/shadow",
                    {"candidate": candidate, "share": 1.0},
                )
                if r.status_code != 201:
                    raise RuntimeError(f"PUT .../shadow: {r.status_code} {r.text[:500]}")
                shadow_id = r.json()["shadow_id"]
                windows[SHADOWED].append(
                    run_window(
                        SHADOWED,
                        robots,
                        args,
                        count_decisions=lambda: int(look(service, staff)["decisions"]),
                    )
                )
                ended = dt.datetime.now(dt.UTC)
                say("  waiting for the pass to shadow the last episodes")
                final, waited = catch_up(service, staff, ended, args.shadow_seconds)
                shadows.append(
                    {
                        "shadow_id": shadow_id,
                        "decisions": final["decisions"],
                        "people": final["people"],
                        "agreement": final["agreement"],
                        "checked_until": final["checked_until"],
                        "caught_up_seconds": waited,
                    }
                )
                if n + 1 < args.rounds:  # stopped, for the next round's reference
                    api(
                        service, staff, "DELETE", f"/v1/admin/fleets/{FLEET}/shadow"
                    ).raise_for_status()
    separated = True  # the passes' processes are always found (their command line)
    database = robots.database is not None
    reference = summarize(REFERENCE, windows[REFERENCE], args.rate, separated, database)
    shadowed = summarize(SHADOWED, windows[SHADOWED], args.rate, separated, database)
    pass_s = sum(w.pass_cpu_s for w in windows[SHADOWED])
    return {
        "place": where.note or "the database on this machine",
        "round_trip_ms": where.round_trip_ms,
        "workers": workers,
        "fill": fill,
        "requests_per_episode": robots.steps,  # what set the windows' episode rate
        "phases": {p.name: asdict(p) for p in (reference, shadowed)},
        "ratios": {
            "p50": _ratio(shadowed.p50_ms, reference.p50_ms),
            "p99": _ratio(shadowed.p99_ms, reference.p99_ms),
            "max": _ratio(shadowed.max_ms, reference.max_ms),
            "cpu_per_request": _ratio(shadowed.cpu_ms_per_request, reference.cpu_ms_per_request),
        },
        "cpu_ms_per_request_added": shadowed.cpu_ms_per_request - reference.cpu_ms_per_request,
        "shadow": {
            "candidate": spec.key,
            "share": 1.0,
            "decisions": sum(s["decisions"] for s in shadows),
            "people": max(s["people"] for s in shadows),
            "agreement": shadows[-1]["agreement"],
            "caught_up_seconds": max(s["caught_up_seconds"] for s in shadows),
            "pass_cpu_ms_per_decision": (
                pass_s * 1000 / shadowed.decisions if separated and shadowed.decisions else None
            ),
            "rounds": shadows,
        },
        "bound": bound(reference, shadowed),
    }


# -- the report -----------------------------------------------------------------------------------
def _ms(x: float | None, digits: int = 1) -> str:
    return "-" if x is None or math.isnan(x) else f"{x:,.{digits}f}"


def _x(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}×"


_WIDTH = 22


def render(doc: dict[str, Any]) -> str:
    lines: list[str] = []
    add = lines.append
    m = doc["machine"]
    add(
        f"Shadow benchmark: {m['cpus']} CPUs ({m['cpu']}), {m['system']}, Python {m['python']}; "
        f"load average {m['load'][0]:.2f} before, {doc['load_after'][0]:.2f} after; "
        f"{doc['minutes']:.1f} min."
    )
    add(f"Command: {doc['command']}")
    for engine, e in doc["engines"].items():
        f = e["fill"]
        add("")
        add(f"== {engine}: attune serve with {e['workers']} worker(s), {e['place']} ==")
        add(
            f"{f['people']} people with {f['episodes'] // max(f['people'], 1)} episodes each "
            f"through the API first ({f['requests']:,} requests, "
            f"{f['requests_per_episode']:.2f} per episode); open-loop robots at "
            f"{doc['rate']:g} requests/s ({e['requests_per_episode']:.2f} per episode, as the "
            f"first warm-up played them), {doc['seconds']:g} s per phase after "
            f"{doc['warmup']:g} s of warm-up"
            + ("" if doc["rounds"] == 1 else f", {doc['rounds']} rounds in turn")
            + f"; ATTUNE_SHADOW_SECONDS={doc['shadow_seconds']:g}."
        )
        phases = list(e["phases"].values())
        ref, sh = e["phases"][REFERENCE], e["phases"][SHADOWED]
        head = f"  {'':<34}" + "".join(
            f"{(p['name'] + (' (reference)' if p['name'] == REFERENCE else '')):>{_WIDTH}}"
            for p in phases
        )
        add(head + f"{'shadow / no shadow':>{_WIDTH}}")

        def row(
            label: str,
            key: str,
            fmt: Callable[[Any], str],
            ratio: str = "",
            phases: list[dict[str, Any]] = phases,
        ) -> None:
            add(
                f"  {label:<34}"
                + "".join(f"{fmt(p[key]):>{_WIDTH}}" for p in phases)
                + f"{ratio:>{_WIDTH}}"
            )

        r = e["ratios"]
        row("requests", "requests", lambda v: f"{v:,}")
        row("requests/s", "rps", lambda v: f"{v:,.1f}")
        row("errors", "errors", lambda v: f"{v}")
        row("p50 ms", "p50_ms", _ms, _x(r["p50"]))
        row("p99 ms", "p99_ms", _ms, _x(r["p99"]))
        row("max ms", "max_ms", _ms, _x(r["max"]))
        row(
            "server CPU ms/request",
            "cpu_ms_per_request",
            lambda v: _ms(v, 3),
            _x(r["cpu_per_request"]),
        )
        if sh["pass_cpu_ms_per_request"] is not None:
            row(
                "  of it, the shadow passes' processes",
                "pass_cpu_ms_per_request",
                lambda v: _ms(v, 3),
            )
            row(
                "the pass's CPU, share of a core",
                "pass_cpu_share",
                lambda v: "-" if v is None else f"{100 * v:.1f}%",
            )
        if sh["database_cpu_ms_per_request"] is not None:
            row(
                "database CPU ms/request",
                "database_cpu_ms_per_request",
                lambda v: _ms(v, 3),
                _x(_ratio(sh["database_cpu_ms_per_request"], ref["database_cpu_ms_per_request"])),
            )
        row(
            "worst event-loop stall ms",
            "worst_stall_ms",
            lambda v: "/".join(_ms(x) for x in v.values()) or "-",
        )
        row(
            "  of it, the loop's own run",
            "worst_busy_stall_ms",
            lambda v: "/".join(_ms(x) for x in v.values()) or "-",
        )
        row("shadow decisions stored/s", "decisions_per_s", lambda v: _ms(v))
        s = e["shadow"]
        times = "" if doc["rounds"] == 1 else f" in {doc['rounds']} shadows"
        add(
            f"  the shadow ({s['candidate']}, share {s['share']:g}): {s['decisions']:,} decisions "
            f"of {s['people']} people stored{times} once the pass caught up "
            f"(at most {s['caught_up_seconds']:.1f} s after the robots stopped), agreement "
            + ("-" if s["agreement"] is None else f"{100 * s['agreement']:.0f}%")
            + (
                f"; the pass's CPU {s['pass_cpu_ms_per_decision']:.2f} ms per decision stored"
                if s["pass_cpu_ms_per_decision"] is not None
                else ""
            )
        )
        add(f"  CPU per request: {e['cpu_ms_per_request_added']:+.3f} ms with the shadow")
        b = e["bound"]
        add(
            f"  bound: p99 with the shadow at most {P99_RATIO:g}× {_ms(ref['p99_ms'])} ms and at "
            f"most + {P99_MARGIN_MS:g} ms, so {_ms(b['limit_ms'])} ms: {_ms(b['p99_ms'])} ms, "
            + ("met" if b["met"] else "MISSED")
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bench/shadow.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--engine",
        choices=("sqlite", "postgresql", "both"),
        default="both",
        help="the database engine (default both, one after the other)",
    )
    parser.add_argument("--people", type=int, default=50, help="the fleet's people (default 50)")
    parser.add_argument(
        "--history", type=int, default=4, help="episodes of each person before (default 4)"
    )
    parser.add_argument(
        "--rate", type=float, default=100.0, help="robot requests a second (default 100)"
    )
    parser.add_argument(
        "--seconds", type=float, default=30.0, help="each phase's measured window (default 30)"
    )
    parser.add_argument(
        "--warmup", type=float, default=5.0, help="load before each window, not counted (default 5)"
    )
    parser.add_argument(
        "--candidate",
        default="dts",
        help="the shadow's learner, ALGORITHM[:NAME=VALUE,...] (default dts)",
    )
    parser.add_argument("--keys", type=int, default=8, help="robot API keys (default 8)")
    parser.add_argument(
        "--workers", type=int, help="attune serve's workers (default 1 on SQLite, 2 on PostgreSQL)"
    )
    parser.add_argument(
        "--shadow-seconds",
        type=float,
        default=SHADOW_SECONDS,
        help="ATTUNE_SHADOW_SECONDS, how often the pass runs (default 1, the worst case; the "
        "service's default is 30)",
    )
    parser.add_argument(
        "--estimate-minutes",
        type=float,
        help="ATTUNE_SHADOW_ESTIMATE_MINUTES (default: the service's, 60)",
    )
    parser.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="both phases this many times in turn, each window --seconds long, their figures "
        "pooled (default 1)",
    )
    parser.add_argument(
        "--delay", type=float, help="PostgreSQL: ms each way between the service and the database"
    )
    parser.add_argument(
        "--pooler",
        choices=("none", "pgbouncer"),
        default="none",
        help="PostgreSQL: pgbouncer puts PgBouncer (transaction pooling) beside the database",
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON document instead of the text"
    )
    args = parser.parse_args(argv)
    engines = ["sqlite", "postgresql"] if args.engine == "both" else [args.engine]
    if (args.delay is not None or args.pooler != "none") and "sqlite" in engines:
        parser.error("--delay and --pooler are for --engine postgresql")
    if min(args.people, args.history, args.keys, args.rounds) < 1:
        parser.error("--people, --history, --keys and --rounds must be at least 1")
    if args.rate <= 0 or args.seconds <= 0 or args.warmup < 0:
        parser.error("--rate and --seconds must be above 0, --warmup at least 0")
    if not 0 < args.shadow_seconds <= 3600:
        parser.error("--shadow-seconds must be above 0 and at most 3600")
    if args.delay is not None and args.delay < 0:
        parser.error("--delay must be at least 0")
    try:
        parse_candidate(args.candidate)
    except ValueError as exc:
        parser.error(f"--candidate: {exc}")
    before = machine()
    began = time.monotonic()
    doc: dict[str, Any] = {
        "machine": before,
        "command": " ".join(["bench/shadow.py", *(sys.argv[1:] if argv is None else argv)]),
        "rate": args.rate,
        "seconds": args.seconds,
        "warmup": args.warmup,
        "people": args.people,
        "history": args.history,
        "shadow_seconds": args.shadow_seconds,
        "rounds": args.rounds,
        "reference": REFERENCE,
        "engines": {},
    }
    try:
        for engine in engines:
            with tempfile.TemporaryDirectory(prefix="attune-shadow-") as tmp:
                doc["engines"][engine] = run_engine(engine, args, Path(tmp))
    except PgBouncerFailed as failure:
        print(f"bench/shadow.py: {failure}", file=sys.stderr)
        return 2
    doc["load_after"] = os.getloadavg()
    doc["minutes"] = (time.monotonic() - began) / 60
    if args.json:
        print(json.dumps(doc, indent=1, default=str))
    else:
        print(render(doc))
    decided = [e["shadow"]["decisions"] > 0 for e in doc["engines"].values()]
    return 0 if all(decided) else 1


if __name__ == "__main__":
    sys.exit(main())
