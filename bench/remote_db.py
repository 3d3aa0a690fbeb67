"""The service with its PostgreSQL one network hop away: the same robots, the database delayed.

    python bench/remote_db.py                         # 0, 0.25, 1 and 2.5 ms each way, 16 robots
    python bench/remote_db.py --delays 0,1 --seconds 5 --inline-writes false
    python bench/remote_db.py --delays 0 --instances 2     # two instances on one PostgreSQL
    python bench/remote_db.py --delays 0,1 --pooler pgbouncer     # PgBouncer beside the database

Loopback only. For each delay, in one run: a fresh database on the PostgreSQL server at
127.0.0.1:5432 (``ATTUNE_TEST_POSTGRES_URL``), a delaying TCP proxy in front of it
(``delayproxy.py``, a process of its own, every chunk delayed by the delay each way), and
``attune serve`` with 2 workers whose database URL leads through the proxy. wrk drives it with
the robot loop of ``service.py`` (start an episode, report outcomes until it closes; each robot
its own user and key), first ``--warmup`` seconds not counted, then a window of ``--seconds``.
Per delay it prints: the round trip through the proxy (``SELECT 1`` from this process), the
throughput, p50 and p99 of the window, the service's CPU per request (its whole process group,
from /proc) and the proxy's (which a real network hop does not cost this machine), the worst
event-loop stall of each worker (``attune_event_loop_stall_max_seconds`` of /metrics, read
during and at the end of the window) and the part of it the loop's thread ran
(``attune_event_loop_busy_stall_max_seconds``: its own computing; the rest it waited, for a
CPU of this busy machine, for the interpreter's lock, or for the database in a write inline),
the stalls over 5 ms (from the histogram ``attune_event_loop_stall_seconds`` between the
window's start and end), and where the robots' writes ran (``attune_robot_writes``: inline on
the event loop, or in the thread pool). Then the targets, met or missed: at 1 ms each way, at
least 0.85 of the no-delay throughput, p99 at most the no-delay p99 + 20 ms, and no worker's
event loop held up over 5 ms (the wall stall, and the part its thread ran).

``--pooler pgbouncer`` puts Debian's PgBouncer in transaction pooling between the proxy and
PostgreSQL (beside the database, as managed services run it) and the service in
``ATTUNE_DATABASE_POOLER=transaction``.

``--instances 2`` starts two ``attune serve`` (2 workers each) on the same database and shares
the robots out among them: what a second instance adds on one PostgreSQL.

Bounded: each delay takes the service's start, ``--warmup`` + ``--seconds`` of load and the
stop; every request times out after 10 s; the proxy stops by itself after the run's time.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import httpx
from service import (
    PG_SERVER,
    Data,
    Figures,
    Samples,
    fresh_database,
    group_cpu_s,
    machine,
    require_wrk,
    run_wrk,
    scrape,
    server,
    writes_by_path,
)

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # the repository, for its PgBouncer launcher
from tests.support.pgbouncer import PgBouncerFailed  # noqa: E402
from tests.support.pgbouncer import launch as launch_pgbouncer  # noqa: E402

WORKERS = 2
STALL_MS = 5.0  # the stall target
TARGET_DELAY_MS = 1.0
THROUGHPUT_RATIO = 0.85
P99_MARGIN_MS = 20.0
STALL_WINDOW_S = 5.0  # attune_event_loop_stall_max_seconds covers the last 5 seconds


@dataclass
class Window:
    """The figures of one delay."""

    delay_ms: float
    proxy_rtt_ms: float
    rps: float
    p50_ms: float
    p99_ms: float
    cpu_ms: float | None
    errors: int
    worst_stall_ms: dict[str, float] = field(default_factory=dict)  # by worker pid
    worst_busy_ms: dict[str, float] = field(default_factory=dict)  # of it, the loop's own run
    stalls_over_5ms: int = 0
    writes: dict[str, float] = field(default_factory=dict)  # by path, in the window
    service_rtt_ms: float | None = None
    proxy_cpu_ms: float | None = None  # the delay proxy's CPU per request (no real hop has it)


def say(text: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {text}", flush=True)


# -- /metrics ----------------------------------------------------------------------------------
def stall_max_by_worker(
    samples: Samples,
    metric: str = "attune_event_loop_stall_max_seconds",
) -> dict[str, float]:
    return {
        dict(labels).get("pid", "-"): value
        for (name, labels), value in samples.items()
        if name == metric
    }


def stalls_over(samples: Samples, limit_s: float) -> float:
    """How many stalls the histogram counted above ``limit_s`` (a bucket's bound)."""
    total = samples.get(("attune_event_loop_stall_seconds_count", ()), 0.0)
    under = samples.get(("attune_event_loop_stall_seconds_bucket", (("le", f"{limit_s}"),)), 0.0)
    return total - under


class StallWatch:
    """Reads the per-worker worst stall while the window runs: the gauge covers the last 5 s,
    so a read every 2.5 s from 5 s into the window on, and one at its end, see all of it and
    nothing before it (a window shorter than 5 s: the read at its end, which also covers the
    last seconds of the warm-up)."""

    def __init__(self, url: str, seconds: float) -> None:
        self.url, self.seconds = url, seconds
        self.worst: dict[str, float] = {}
        self.busy: dict[str, float] = {}  # the part of it the loop's thread ran
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _read(self) -> None:
        try:
            samples = scrape(self.url)
            for pid, value in stall_max_by_worker(samples).items():
                self.worst[pid] = max(self.worst.get(pid, 0.0), value)
            busy = stall_max_by_worker(samples, "attune_event_loop_busy_stall_max_seconds")
            for pid, value in busy.items():
                self.busy[pid] = max(self.busy.get(pid, 0.0), value)
        except httpx.HTTPError:
            pass

    def _run(self) -> None:
        began = time.monotonic()
        wait = STALL_WINDOW_S
        while wait < self.seconds and not self._stop.wait(began + wait - time.monotonic()):
            self._read()
            wait += STALL_WINDOW_S / 2

    def __enter__(self) -> StallWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=15)
        self._read()


# -- the proxy and the round trip --------------------------------------------------------------
def start_proxy(delay_ms: float, target: tuple[str, int], max_seconds: float) -> tuple[Any, int]:
    cmd = [
        sys.executable,
        str(HERE / "delayproxy.py"),
        "--to",
        f"{target[0]}:{target[1]}",
        "--delay-ms",
        f"{delay_ms:g}",
        "--max-seconds",
        f"{max_seconds:g}",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, start_new_session=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("listening on"):
        proc.kill()
        raise RuntimeError(f"the delay proxy did not start: {line!r}")
    return proc, int(line.rsplit(":", 1)[1])


def round_trip_ms(conninfo: str, n: int = 50) -> float:
    """The median wall time of ``SELECT 1`` from this process over ``conninfo``."""
    import psycopg

    times = []
    # No statement prepared on the server: through PgBouncer in transaction pooling, the next
    # one may run on another server connection.
    with psycopg.connect(
        conninfo, autocommit=True, connect_timeout=10, prepare_threshold=None
    ) as conn:
        for _ in range(n):
            t = time.perf_counter()
            conn.execute("SELECT 1").fetchone()
            times.append((time.perf_counter() - t) * 1000)
    return statistics.median(times)


# -- one delay ---------------------------------------------------------------------------------
def _split(robots: int, instances: int) -> list[int]:
    return [robots // instances + (1 if i < robots % instances else 0) for i in range(instances)]


def run_delay(args: argparse.Namespace, wrk: str, delay_ms: float, workdir: Path) -> Window:
    server_url = PG_SERVER.rstrip("/")
    rest = server_url.split("://", 1)[1]
    userinfo, _, hostport = rest.rpartition("@")
    host, _, port = hostport.partition(":")
    budget = args.warmup + args.seconds + 180 * args.instances
    with contextlib.ExitStack() as pooled:
        target = (host, int(port or 5432))
        if args.pooler == "pgbouncer":
            target = ("127.0.0.1", pooled.enter_context(launch_pgbouncer()).port)
        return _run_delay(args, wrk, delay_ms, workdir, target, userinfo, budget)


def _run_delay(
    args: argparse.Namespace,
    wrk: str,
    delay_ms: float,
    workdir: Path,
    target: tuple[str, int],
    userinfo: str,
    budget: float,
) -> Window:
    proxy, proxy_port = start_proxy(delay_ms, target, budget)
    try:
        with fresh_database("postgresql", workdir) as db_url:
            data = Data(db_url)
            try:
                keys = data.keys(args.robots)
            finally:
                data.close()
            name = db_url.rsplit("/", 1)[1]
            auth = f"{userinfo}@" if userinfo else ""
            via = f"postgresql+psycopg://{auth}127.0.0.1:{proxy_port}/{name}"
            rtt = round_trip_ms(f"postgresql://{auth}127.0.0.1:{proxy_port}/{name}")
            say(f"  {delay_ms:g} ms each way: SELECT 1 through the proxy takes {rtt:.3f} ms")
            # Each instance its own robots (a user and a key each), in a folder of its own.
            dirs, first = [], 0
            for i, count in enumerate(_split(args.robots, args.instances)):
                d = workdir / f"instance{i}"
                d.mkdir()
                users = [f"robot{n}" for n in range(first + 1, first + count + 1)]
                (d / "keys.txt").write_text("\n".join(keys[first : first + count]) + "\n")
                (d / "users.txt").write_text("\n".join(users) + "\n")
                dirs.append((d, count))
                first += count
            with contextlib.ExitStack() as stack:
                served = [stack.enter_context(server("service", WORKERS, d, via)) for d, _ in dirs]
                tag = f"d{delay_ms:g}".replace(".", "p")

                def load(seconds: float, label: str) -> list[Figures]:
                    found: list[Figures | BaseException] = [RuntimeError("no run")] * len(dirs)

                    def one(i: int) -> None:
                        d, count = dirs[i]
                        try:
                            found[i] = run_wrk(
                                wrk, served[i].url, "loop", count, d, seconds, 0, f"{label}{i}"
                            )
                        except BaseException as exc:  # reported below, in the caller's thread
                            found[i] = exc

                    threads = [threading.Thread(target=one, args=(i,)) for i in range(len(dirs))]
                    for t in threads:
                        t.start()
                    for t in threads:
                        t.join()
                    for f in found:
                        if isinstance(f, BaseException):
                            raise f
                    return [f for f in found if isinstance(f, Figures)]

                if args.warmup > 0:
                    load(args.warmup, f"{tag}w")
                before = [scrape(s.url) for s in served]
                cpu_before = sum(group_cpu_s(s.pgid) for s in served)
                proxy_before = group_cpu_s(proxy.pid)
                with contextlib.ExitStack() as watching:
                    watches = [
                        watching.enter_context(StallWatch(s.url, args.seconds)) for s in served
                    ]
                    figs = load(args.seconds, f"{tag}m")
                cpu_s = sum(group_cpu_s(s.pgid) for s in served) - cpu_before
                proxy_s = group_cpu_s(proxy.pid) - proxy_before
                after = [scrape(s.url) for s in served]
            limit = STALL_MS / 1000.0
            writes: dict[str, float] = {}
            for b, a in zip(before, after, strict=True):
                wb = writes_by_path(b)
                for path, n in writes_by_path(a).items():
                    writes[path] = writes.get(path, 0.0) + n - wb.get(path, 0.0)
            worst: dict[str, float] = {}
            busiest: dict[str, float] = {}
            for i, watch in enumerate(watches):
                for pid, v in sorted(watch.worst.items()):
                    worst[pid if len(watches) == 1 else f"{i}:{pid}"] = v * 1000
                for pid, v in sorted(watch.busy.items()):
                    busiest[pid if len(watches) == 1 else f"{i}:{pid}"] = v * 1000
            rtts = [a.get(("attune_db_round_trip_seconds", ())) for a in after]
            measured = [r for r in rtts if r is not None]
            answered = sum(f.count + f.errors for f in figs)
            return Window(
                delay_ms=delay_ms,
                proxy_rtt_ms=rtt,
                rps=sum(f.rps for f in figs),
                p50_ms=max(f.p50_ms for f in figs),
                p99_ms=max(f.p99_ms for f in figs),
                cpu_ms=cpu_s * 1000 / answered if answered else None,
                errors=sum(f.errors for f in figs),
                worst_stall_ms=worst,
                worst_busy_ms=busiest,
                stalls_over_5ms=round(
                    sum(
                        stalls_over(a, limit) - stalls_over(b, limit)
                        for b, a in zip(before, after, strict=True)
                    )
                ),
                writes={p: writes[p] for p in sorted(writes)},
                service_rtt_ms=max(measured) * 1000 if measured else None,
                proxy_cpu_ms=proxy_s * 1000 / answered if answered else None,
            )
    finally:
        proxy.terminate()
        try:
            proxy.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proxy.kill()


# -- the report --------------------------------------------------------------------------------
def describe(w: Window) -> str:
    stalls = ", ".join(f"{v:.1f}" for v in w.worst_stall_ms.values()) or "-"
    busy = ", ".join(f"{v:.1f}" for v in w.worst_busy_ms.values()) or "-"
    writes = ", ".join(f"{path} {n:.0f}" for path, n in w.writes.items()) or "-"
    cpu = f"{w.cpu_ms:.3f}" if w.cpu_ms is not None else "-"
    rtt = f"{w.service_rtt_ms:.3f}" if w.service_rtt_ms is not None else "-"
    proxy_cpu = f"{w.proxy_cpu_ms:.3f}" if w.proxy_cpu_ms is not None else "-"
    return (
        f"{w.delay_ms:>5g} ms | {w.proxy_rtt_ms:7.3f} | {w.rps:6.0f} | {w.p50_ms:7.1f} | "
        f"{w.p99_ms:7.1f} | {cpu:>6} | {proxy_cpu:>6} | {stalls:>11} | {busy:>11} | "
        f"{w.stalls_over_5ms:5d} | "
        f"{rtt:>7} | "
        f"{writes}" + (f" | {w.errors} errors" if w.errors else "")
    )


def targets(windows: list[Window]) -> list[str]:
    base = next((w for w in windows if w.delay_ms == 0), None)
    far = next((w for w in windows if w.delay_ms == TARGET_DELAY_MS), None)
    if base is None or far is None:
        return ["the targets need the delays 0 and 1 (--delays 0,1,...)"]

    def verdict(ok: bool) -> str:
        return "met" if ok else "missed"

    ratio = far.rps / base.rps if base.rps else 0.0
    worst = max(far.worst_stall_ms.values(), default=float("nan"))
    busy = max(far.worst_busy_ms.values(), default=float("nan"))
    return [
        f"throughput at 1 ms each way: {far.rps:.0f} req/s = {ratio:.2f} of the "
        f"{base.rps:.0f} without delay (target ≥ {THROUGHPUT_RATIO}): "
        f"{verdict(ratio >= THROUGHPUT_RATIO)}",
        f"p99 at 1 ms each way: {far.p99_ms:.1f} ms against {base.p99_ms:.1f} ms without delay "
        f"(target ≤ +{P99_MARGIN_MS:g} ms): {verdict(far.p99_ms <= base.p99_ms + P99_MARGIN_MS)}",
        f"worst event-loop stall per worker at 1 ms each way: {worst:.1f} ms (target ≤ "
        f"{STALL_MS:g} ms): {verdict(worst <= STALL_MS)}",
        f"  of it, the time the loop's thread ran (its own computing; the rest it waited, for a "
        f"CPU, the interpreter's lock or the database): {busy:.1f} ms (target ≤ "
        f"{STALL_MS:g} ms): {verdict(busy <= STALL_MS)}",
    ]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description="Throughput, latency, CPU and event-loop stalls of attune serve (2 workers, "
        "PostgreSQL) with its database behind a TCP proxy that delays every packet each way, "
        "at several delays in one run (loopback only). Needs wrk (apt-get install -y wrk) and "
        "PostgreSQL at 127.0.0.1:5432 (ATTUNE_TEST_POSTGRES_URL)."
    )
    parser.add_argument(
        "--delays",
        default="0,0.25,1,2.5",
        help="delays each way in ms, comma-separated (default 0,0.25,1,2.5; the targets "
        "compare 1 with 0)",
    )
    parser.add_argument(
        "--seconds", type=float, default=10.0, help="seconds measured per delay (default 10)"
    )
    parser.add_argument(
        "--warmup", type=float, default=2.0, help="seconds of load before each window (default 2)"
    )
    parser.add_argument("--robots", type=int, default=16, help="concurrent robots (default 16)")
    parser.add_argument(
        "--instances",
        type=int,
        default=1,
        help="attune serve instances (2 workers each) on the one database, the robots shared "
        "out among them (default 1); the figures are their sum (throughput, CPU), and the "
        "worst of them (p50, p99)",
    )
    parser.add_argument(
        "--inline-writes",
        choices=["auto", "true", "false"],
        help="ATTUNE_PG_INLINE_WRITES for the service (default: the service's own, auto)",
    )
    parser.add_argument(
        "--pooler",
        choices=["none", "pgbouncer"],
        default="none",
        help="pgbouncer: Debian's PgBouncer in transaction pooling beside the database, the "
        "delay between it and the service (ATTUNE_DATABASE_POOLER=transaction), as a managed "
        "PostgreSQL puts it (default none: the proxy in front of PostgreSQL itself)",
    )
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    delays = [float(d) for d in args.delays.split(",")]
    if args.seconds <= 0 or any(d < 0 for d in delays):
        parser.error("--seconds must be positive, the delays at least 0")
    if not 1 <= args.instances <= args.robots:
        parser.error("--instances must be from 1 to --robots")
    if args.inline_writes:
        os.environ["ATTUNE_PG_INLINE_WRITES"] = args.inline_writes
    if args.pooler == "pgbouncer":
        os.environ["ATTUNE_DATABASE_POOLER"] = "transaction"
    wrk = require_wrk()
    before = machine()
    began = time.monotonic()
    say(
        f"attune serve ×{args.instances}, {WORKERS} workers each, {args.robots} robots, "
        f"PostgreSQL through a delaying proxy"
        + (" and PgBouncer (transaction pooling)" if args.pooler == "pgbouncer" else "")
        + f"; delays {', '.join(f'{d:g}' for d in delays)} ms each way, "
        f"{args.warmup:g} s warm-up + {args.seconds:g} s each; load average "
        f"{before['load'][0]:.2f}"
    )
    windows = []
    for delay in delays:
        say(f"delay {delay:g} ms each way")
        with tempfile.TemporaryDirectory(prefix="attune-remote-") as tmp:
            try:
                w = run_delay(args, wrk, delay, Path(tmp))
            except PgBouncerFailed as failure:
                sys.exit(f"remote_db.py: {failure}")
        windows.append(w)
        say(
            f"  {w.rps:.0f} req/s, p50 {w.p50_ms:.1f} ms, p99 {w.p99_ms:.1f} ms, "
            + (f"{w.cpu_ms:.3f} ms CPU/request, " if w.cpu_ms is not None else "")
            + "worst stall per worker "
            + ", ".join(f"{v:.1f}" for v in w.worst_stall_ms.values())
            + " ms"
        )
    after = machine()
    print()
    print(
        "delay | SELECT 1 ms | req/s | p50 ms | p99 ms | CPU ms/req | proxy CPU ms/req | "
        "worst stall ms by worker | of it, run by the loop ms "
        "| >5 ms | service's round trip ms | writes by path"
    )
    for w in windows:
        print(describe(w))
    print(
        f"Machine: {before['cpus']} CPUs ({before['cpu']}), {before['system']}, Python "
        f"{before['python']}; load average {before['load'][0]:.2f} before, "
        f"{after['load'][0]:.2f} after ({(time.monotonic() - began) / 60:.1f} min); "
        f"ATTUNE_PG_INLINE_WRITES={os.environ.get('ATTUNE_PG_INLINE_WRITES', 'auto')}; "
        f"pooler {args.pooler}."
    )
    lines = targets(windows)
    print("Targets")
    for line in lines:
        print("  " + line)
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "machine": before,
                    "load_after": after["load"],
                    "command": " ".join(sys.argv),
                    "inline_writes": os.environ.get("ATTUNE_PG_INLINE_WRITES", "auto"),
                    "pooler": args.pooler,
                    "windows": [asdict(w) for w in windows],
                    "targets": lines,
                },
                indent=1,
            )
        )


if __name__ == "__main__":
    main()
