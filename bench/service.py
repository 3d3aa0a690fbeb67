"""The service under load, against what this machine's HTTP layer can do at all.

    python bench/service.py                  # the full table, SQLite and PostgreSQL
    python bench/service.py --quick          # short runs at 8 and 16 robots, small seeded data
    python bench/service.py --engine sqlite --clients 8 --duration 5 --no-large --loop-only

Loopback only. In one run, on one machine, this starts ``attune serve`` (SQLite with 1 worker,
PostgreSQL at 127.0.0.1:5432 with 2 workers, each on a fresh database) and, beside it with the
same worker count and uvicorn options, a bare FastAPI app with one ``async def`` POST endpoint
that parses a small pydantic body: the *reference*, what the HTTP stack alone costs here.
wrk (Debian's ``wrk``; ``apt-get install -y wrk``) drives both with one connection per thread,
through a Lua script that plays the robot:

- **robot loop**: start an episode, report outcomes until it closes, again (each client its
  own user); requests/s and per-request p50/p99, plus whole loops/s;
- **outcome**: only outcome requests, on episodes opened beforehand (in-process);
- **model read**: ``GET /v1/users/{id}/model``;

at 1, 8 and 16 concurrent clients. For every run it also reads the server's CPU time (all its
processes, from /proc) and divides it by the requests answered: **CPU per request**, the figure
the targets use, because the load generator shares the machine's cores with the server and
saturates before it, so requests per second say less. Then an **open loop** (``openloop.py``):
robots that start episodes on a fixed schedule at half the capacity the closed loop measured,
whether or not earlier answers came back, and the latency of every request at that realistic
load. Then the database gets 100,000 users (bulk SQL) and one user with 10,000 episodes
(through the service's use cases, in-process), and the closed-loop figures are taken again on
those, against the same figure on the empty database. The targets are checked at the end
(met / missed): a robot-loop request at most 4× the bare POST's CPU on SQLite (1 worker, 8
robots) and 5× on PostgreSQL (2 workers, 16 robots); open-loop p99 under 30 ms on SQLite and
60 ms on PostgreSQL; the large data within 1.2× of the empty database. Beside the CPU target
it prints the **floor** (``floor.py``, after the runs, on a database of its own): the bare POST
plus what the learner's calls and the requests' statements through the bare driver cost per
robot request, measured in-process; what the target leaves above that floor is all the rest of
a request may cost.

Each run is bounded: ``--duration`` seconds of wrk (the first ``--warmup`` seconds are not
counted), twice that for the open loop, a request timeout of 10 s, and every seeding loop
bounded in count.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fastapi import FastAPI
from pydantic import BaseModel

if TYPE_CHECKING:
    from floor import Floor

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PG_SERVER = os.environ.get("ATTUNE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432")
ATTUNE = str(Path(sys.executable).with_name("attune"))
SITUATIONS = ("arriving", "working", "stretching")
DETAIL = {"ProvideDrink": "tea", "BriefInformation": "news", "ArrangeSchedule": "today_agenda"}


# -- the reference: a bare FastAPI app ---------------------------------------------------------
class Ping(BaseModel):
    """The reference's small body."""

    event_id: str
    situation: str
    n: int


def reference_app() -> FastAPI:
    """``uvicorn --factory service:reference_app``: one async POST that parses a small body."""
    app = FastAPI()

    @app.post("/echo")
    async def echo(body: Ping) -> dict[str, Any]:
        return {"event_id": body.event_id, "n": body.n + 1}

    return app


# -- the load generator: wrk with a robot in Lua -----------------------------------------------
LUA = r"""
-- One connection per thread: each thread is one robot (or reader) with its own key and user.
-- Every response is written to rec-<tid>.txt: kind status latency_us end_us (CLOCK_MONOTONIC).
local ffi = require("ffi")
ffi.cdef[[
typedef struct { long tv_sec; long tv_nsec; } bench_timespec;
int clock_gettime(int clk_id, bench_timespec *tp);
]]
local ts = ffi.new("bench_timespec")
local function now_us()
  ffi.C.clock_gettime(1, ts)
  return tonumber(ts.tv_sec) * 1000000 + math.floor(tonumber(ts.tv_nsec) / 1000)
end

local counter = 0
function setup(thread)
  counter = counter + 1
  thread:set("tid", counter)
end

local DETAIL = {ProvideDrink = "tea", BriefInformation = "news", ArrangeSchedule = "today_agenda"}
local SIT = {"arriving", "working", "stretching"}
local opts, headers, user, out = {}, {}, nil, nil
local pending, current = {}, nil
local sent_at, sent_kind, loop_start = 0, "none", 0
local n = 0

local function lines(path)
  local t = {}
  local f = io.open(path, "r")
  if f then
    for l in f:lines() do t[#t + 1] = l end
    f:close()
  end
  return t
end

function init(args)
  for _, a in pairs(args) do
    local k, v = tostring(a):match("^(%w+)=(.*)$")
    if k then opts[k] = v end
  end
  local dir = opts.dir
  headers = {["Content-Type"] = "application/json",
             Authorization = "Bearer " .. (lines(dir .. "/keys.txt")[tid] or "none")}
  user = lines(dir .. "/users.txt")[tid]
  out = io.open(dir .. "/rec-" .. tid .. ".txt", "w")
  if opts.mode == "outcome" then
    for _, l in ipairs(lines(dir .. "/episodes-" .. tid .. ".txt")) do
      local e, d, k, s = l:match("(%S+) (%S+) (%S+) (%S+)")
      pending[#pending + 1] = {episode = e, decision = d, kind = k, service = s}
    end
  end
end

local function outcome_body(c)
  local r
  if c.kind == "pass" then r = '"response":"none"'
  elseif c.kind == "query_type" then r = '"response":"answered","service":"ProvideDrink"'
  elseif c.kind == "query_detail" then
    r = '"response":"answered","detail":"' .. (DETAIL[c.service] or "tea") .. '"'
  else r = '"response":"accepted"' end
  return '{"decision_id":"' .. c.decision .. '",' .. r .. '}'
end

function request()
  local path, body
  if opts.mode == "ref" then
    n = n + 1
    sent_kind = "ref"
    path = "/echo"
    body = '{"event_id":"robot7-' .. n .. '","situation":"stretching","n":' .. n .. '}'
  elseif opts.mode == "model" then
    sent_kind = "model"
    sent_at = now_us()
    return wrk.format("GET", "/v1/users/" .. user .. "/model", headers)
  else
    if current == nil and #pending > 0 then current = table.remove(pending) end
    if current == nil then
      n = n + 1
      sent_kind = (opts.mode == "outcome") and "spare" or "episode"
      path = "/v1/users/" .. user .. "/episodes"
      body = '{"event_id":"' .. opts.tag .. '-' .. tid .. '-' .. n ..
             '","occurred_at":"2026-11-22T15:10:00+08:00","situation":"' .. SIT[n % 3 + 1] ..
             '","initiator":"robot","robot_id":"bench-' .. tid .. '"}'
      loop_start = now_us()
    else
      sent_kind = "outcome"
      path = "/v1/episodes/" .. current.episode .. "/outcomes"
      body = outcome_body(current)
    end
  end
  sent_at = now_us()
  return wrk.format("POST", path, headers, body)
end

function response(status, hdrs, body)
  local t = now_us()
  out:write(sent_kind, " ", status, " ", t - sent_at, " ", t, "\n")
  if status >= 300 or opts.mode == "ref" or opts.mode == "model" then return end
  if sent_kind ~= "outcome" then
    current = {episode = body:match('"episode_id":"([^"]+)"')}
  end
  local d = body:match('"decision":(%b{})')
  if d == nil then
    if opts.mode == "loop" then out:write("loop 200 ", t - loop_start, " ", t, "\n") end
    current = nil
  else
    local a = d:match('"action":(%b{})')
    current.decision = d:match('"decision_id":"([^"]+)"')
    current.kind = a:match('"kind":"([^"]+)"')
    current.service = a:match('"service":"([^"]+)"') or "-"
  end
end
"""


def require_wrk() -> str:
    path = shutil.which("wrk")
    if path is None:
        sys.exit(
            "bench/service.py needs wrk, the HTTP load generator: "
            "apt-get install -y wrk (Debian/Ubuntu), then run again."
        )
    return path


@dataclass
class Figures:
    """One measured run: throughput and latency of the counted requests."""

    rps: float
    p50_ms: float
    p99_ms: float
    count: int
    errors: int
    loops_per_s: float | None = None
    loop_p50_ms: float | None = None
    cpu_ms: float | None = None  # the server's CPU per answered request (all its processes)
    notes: list[str] = field(default_factory=list)


_TICK = os.sysconf("SC_CLK_TCK")


def group_cpu_s(pgid: int) -> float:
    """CPU seconds (user + system) used so far by the processes of group ``pgid``: the server
    and its workers (all started in a session of their own). Linux ``/proc``."""
    total = 0
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[2]) == pgid:  # pgrp
            total += int(fields[11]) + int(fields[12])  # utime, stime
    return total / _TICK


def _pct(values: list[float], q: float) -> float:
    values = sorted(values)
    if not values:
        return math.nan
    return values[min(len(values) - 1, max(0, math.ceil(q * len(values)) - 1))]


def run_wrk(
    wrk: str,
    url: str,
    mode: str,
    clients: int,
    workdir: Path,
    duration: float,
    warmup: float,
    tag: str,
    pgid: int | None = None,
) -> Figures:
    """Drive ``url`` with ``clients`` wrk connections for ``duration`` s in ``mode``; with
    ``pgid``, also the server's CPU per answered request over the whole run."""
    for old in workdir.glob("rec-*.txt"):
        old.unlink()
    script = workdir / "robot.lua"
    script.write_text(LUA)
    cmd = [
        wrk,
        "-t",
        str(clients),
        "-c",
        str(clients),
        "-d",
        f"{duration:g}s",
        "--timeout",
        "10s",
        "-s",
        str(script),
        url,
        "--",
        f"mode={mode}",
        f"dir={workdir}",
        f"tag={tag}",
    ]
    cpu_before = group_cpu_s(pgid) if pgid is not None else 0.0
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=duration + 60, check=False)
    cpu_s = group_cpu_s(pgid) - cpu_before if pgid is not None else None
    if done.returncode != 0:
        raise RuntimeError(f"wrk failed: {done.stderr or done.stdout}")
    records: list[tuple[str, int, float, float]] = []
    for path in workdir.glob("rec-*.txt"):
        for line in path.read_text().splitlines():
            kind, status, latency, end = line.split()
            records.append((kind, int(status), int(latency) / 1000.0, int(end) / 1e6))
    if not records:
        raise RuntimeError(f"wrk recorded nothing: {done.stdout}\n{done.stderr}")
    first = min(r[3] for r in records)
    last = max(r[3] for r in records)
    start = first + warmup
    window = max(1e-9, last - start)
    counted = {
        "ref": ("ref",),
        "model": ("model",),
        "outcome": ("outcome",),
        "loop": ("episode", "outcome"),
    }[mode]
    mine = [r for r in records if r[3] >= start and r[0] in counted]
    ok = [r[2] for r in mine if r[1] < 300]
    fig = Figures(
        rps=len(ok) / window,
        p50_ms=_pct(ok, 0.50),
        p99_ms=_pct(ok, 0.99),
        count=len(ok),
        errors=len(mine) - len(ok),
    )
    answered = sum(1 for r in records if r[0] != "loop")
    if cpu_s is not None and answered:
        fig.cpu_ms = cpu_s * 1000.0 / answered
    if mode == "loop":
        loops = [r[2] for r in records if r[3] >= start and r[0] == "loop"]
        fig.loops_per_s = len(loops) / window
        fig.loop_p50_ms = _pct(loops, 0.50)
    spare = sum(1 for r in records if r[0] == "spare")
    if spare:
        fig.notes.append(f"{spare} extra episodes started after the prepared ones ran out")
    statuses = sorted({r[1] for r in mine if r[1] >= 300})
    if statuses:
        fig.notes.append(f"non-2xx statuses: {statuses}")
    return fig


Samples = dict[tuple[str, tuple[tuple[str, str], ...]], float]
"""A /metrics scrape: each sample's value by its name and its sorted labels."""


def scrape(url: str, timeout: float = 10) -> Samples:
    """Every sample of the service's /metrics at ``url``, parsed by prometheus_client."""
    import httpx
    from prometheus_client.parser import text_string_to_metric_families

    text = httpx.get(f"{url}/metrics", timeout=timeout).text
    return {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
    }


def writes_by_path(samples: Samples) -> dict[str, float]:
    """PostgreSQL: the robots' writes so far by where they ran (``attune_robot_writes_total``:
    inline on the event loop, or in the thread pool)."""
    return {
        dict(labels)["path"]: value
        for (name, labels), value in samples.items()
        if name == "attune_robot_writes_total"
    }


def robot_writes(url: str) -> dict[str, float]:
    """``writes_by_path`` of the service at ``url`` now."""
    return writes_by_path(scrape(url))


# -- processes and databases -------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def wait_ready(url: str, proc: subprocess.Popen[bytes], log: Path, timeout: float = 60) -> None:
    import httpx

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited with {proc.returncode}:\n{log.read_text()[-3000:]}")
        try:
            httpx.get(url, timeout=2)
            return
        except httpx.TransportError:
            time.sleep(0.1)
    raise RuntimeError(f"server not ready within {timeout} s:\n{log.read_text()[-3000:]}")


def wait_workers(base: str, workers: int, log: Path, timeout: float = 60) -> None:
    """Until every worker of ``attune serve`` runs (``attune_workers`` of /metrics counts the
    live ones): the first one answers /readyz while the others may still be starting, and a
    window measured then would count one worker's throughput and the others' start-up."""
    import httpx

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            running = scrape(base, timeout=2).get(("attune_workers", ()), 0.0)
        except httpx.TransportError:
            running = 0.0
        if running >= workers:
            return
        time.sleep(0.2)
    tail = log.read_text()[-3000:]
    raise RuntimeError(f"{workers} workers not running within {timeout} s:\n{tail}")


@dataclass(frozen=True)
class Served:
    """A server started by :func:`server`: its base URL and its process group (for its CPU)."""

    url: str
    pgid: int


@contextmanager
def server(
    kind: str,
    workers: int,
    workdir: Path,
    database_url: str = "",
    profile: Path | None = None,
    profile_format: str = "flamegraph",
) -> Iterator[Served]:
    """``attune serve`` (kind "service") or the reference app, on a free port; its base URL.

    With ``profile``, the service runs under py-spy, which writes a flame graph of all its
    processes there when the server stops.
    """
    port = free_port()
    log = workdir / f"{kind}-{port}.log"
    env = {
        **os.environ,
        "ATTUNE_DATABASE_URL": database_url,
        "ATTUNE_LOG_LEVEL": "warning",
        # The limiter stays on (its cost is part of the figures) but far above the load.
        "ATTUNE_RATE_LIMIT_PER_S": "1000000",
        "ATTUNE_RATE_LIMIT_BURST": "1000000",
    }
    if kind == "service":
        cmd = [
            ATTUNE,
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--workers",
            str(workers),
        ]
        if profile is not None:
            profile.mkdir(parents=True, exist_ok=True)
            suffix = {"flamegraph": "svg", "speedscope": "json"}.get(profile_format, "txt")
            graph = profile / f"{Path(database_url.split('?')[0]).name or 'db'}-{port}.{suffix}"
            cmd = [
                str(Path(sys.executable).with_name("py-spy")),
                "record",
                "--subprocesses",
                "--rate",
                "100",
                "--format",
                profile_format,
                "--output",
                str(graph),
                "--",
                *cmd,
            ]
        probe = f"http://127.0.0.1:{port}/readyz"
    else:
        cmd = [sys.executable, __file__, "--serve-reference", str(port), str(workers)]
        probe = f"http://127.0.0.1:{port}/docs"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            cmd, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True, cwd=ROOT
        )
    try:
        wait_ready(probe, proc, log)
        if kind == "service" and workers > 1:
            wait_workers(f"http://127.0.0.1:{port}", workers, log)
        yield Served(f"http://127.0.0.1:{port}", proc.pid)
    finally:
        if profile is not None and kind == "service" and proc.poll() is None:
            os.kill(proc.pid, signal.SIGINT)  # py-spy writes its flame graph on SIGINT
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                pass
        with contextlib.suppress(ProcessLookupError):  # the service, once py-spy is gone
            os.killpg(proc.pid, signal.SIGTERM)
        if proc.poll() is None:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)


@contextmanager
def fresh_database(engine: str, workdir: Path) -> Iterator[str]:
    if engine == "sqlite":
        yield f"sqlite:///{workdir / 'bench.db'}"
        return
    import psycopg

    name = f"attune_bench_{secrets.token_hex(4)}"
    server_url = PG_SERVER.rstrip("/")
    with psycopg.connect(f"{server_url}/postgres", autocommit=True, connect_timeout=5) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql+psycopg://{server_url.split('://', 1)[1]}/{name}"
    finally:
        with psycopg.connect(f"{server_url}/postgres", autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


# -- data: keys, prepared episodes, 100,000 users, 10,000 episodes -----------------------------
class Data:
    """In-process access to the benchmark's database through the service's own use cases."""

    def __init__(self, database_url: str) -> None:
        from app.db import migrate
        from app.db.session import Database
        from app.services.context import Principal, ServiceContext
        from app.settings import Settings

        migrate.upgrade(database_url)
        self.settings = Settings(database_url=database_url, _env_file=None)  # type: ignore[call-arg]
        self.db = Database(self.settings)
        self.ctx = ServiceContext.from_settings(self.settings)
        self.robot = Principal("bench", "robot", "default")

    def keys(self, n: int) -> list[str]:
        from app.services.auth import create_key

        with self.db.transaction() as session:
            return [create_key(session, role="robot", name=f"bench-{i}")[1] for i in range(n)]

    def start(self, session: Any, user: str, event_id: str, k: int) -> dict[str, Any]:
        from app.schemas.episodes import EpisodeIn
        from app.services.episodes import start_episode

        body = EpisodeIn.model_validate(
            {
                "event_id": event_id,
                "occurred_at": "2026-11-22T15:10:00+08:00",
                "situation": SITUATIONS[k % 3],
                "initiator": "robot",
                "robot_id": "bench",
            }
        )
        return start_episode(session, self.ctx, self.robot, user, body).body

    def open_episodes(self, user: str, n: int, tag: str) -> list[str]:
        """``n`` episodes of ``user`` left open at their first decision: lines for the Lua."""
        out = []
        for i in range(n):
            with self.db.transaction() as session:
                ep = self.start(session, user, f"{tag}-open-{i}", i)
            d = ep["decision"]
            out.append(
                f"{ep['episode_id']} {d['decision_id']} {d['action']['kind']} "
                f"{d['action'].get('service') or '-'}"
            )
        return out

    def history(self, user: str, n: int, progress: Any = None, tag: str = "history") -> None:
        """``n`` whole episodes of ``user`` through the use cases (as a robot would); their
        event ids are ``tag-0``, ``tag-1``..."""
        from app.schemas.episodes import OutcomeIn
        from app.services.episodes import report_outcome

        for i in range(n):
            with self.db.transaction() as session:
                ep = self.start(session, user, f"{tag}-{i}", i)
            decision = ep["decision"]
            for _ in range(8):  # an episode has at most four visible steps
                if decision is None:
                    break
                kind = decision["action"]["kind"]
                body: dict[str, Any] = {"decision_id": decision["decision_id"]}
                if kind == "pass":
                    body["response"] = "none"
                elif kind == "query_type":
                    body.update(response="answered", service="ProvideDrink")
                elif kind == "query_detail":
                    body.update(response="answered", detail=DETAIL[decision["action"]["service"]])
                else:
                    body["response"] = "accepted"
                with self.db.transaction() as session:
                    decision = report_outcome(
                        session,
                        self.ctx,
                        self.robot,
                        ep["episode_id"],
                        OutcomeIn.model_validate(body),
                    ).body["decision"]
            if progress is not None:
                progress()

    def users(self, n: int, prefix: str) -> None:
        """``n`` users with fresh models, by bulk inserts."""
        from sqlalchemy import insert

        from app.db.models import LearnerModel, User
        from app.db.types import utcnow
        from app.services.missions import current_version
        from app.services.person_model import fresh_learner

        learner = fresh_learner("hri", None, self.ctx.mission)
        params, state, now = learner.params.to_dict(), learner.to_state(), utcnow()
        chunk = 5000
        with self.db.transaction() as session:  # the fleet's mission version 1: the default
            current_version(session, self.ctx, "default", for_new_user=True)
        for lo in range(0, n, chunk):
            ids = [f"{prefix}{i:06d}" for i in range(lo, min(n, lo + chunk))]
            with self.db.transaction() as session:
                made = (
                    session.execute(
                        insert(User).returning(User.id),
                        [
                            {
                                "user_id": u,
                                "fleet": "default",
                                "display_name": None,
                                "algorithm": "hri",
                                "params": params,
                                "created_at": now,
                                "episode_count": 0,
                                "draws": 0,
                                "seed_key": f"default/{u}",
                            }
                            for u in ids
                        ],
                    )
                    .scalars()
                    .all()
                )
                session.execute(
                    insert(LearnerModel),
                    [
                        {
                            "user_pk": pk,
                            "version": 0,
                            "state": state,
                            "base_state": None,
                            "base_version": 0,
                            "episode_offset": 0,
                            "updated_at": now,
                            "mission_version": 1,
                            "base_mission_version": 1,
                        }
                        for pk in made
                    ],
                )

    def close(self) -> None:
        self.db.dispose()


# -- the runs ----------------------------------------------------------------------------------
@dataclass
class Row:
    engine: str
    workers: int
    scenario: str  # loop, outcome, model, reference, open loop
    clients: int
    data: str  # "empty", "100k users", "10k episodes"
    fig: Figures
    ref: Figures | None = None
    base: Figures | None = None  # the same figure on the empty database


SCENARIOS = ("loop", "outcome", "model")
# The robots of the CPU and open-loop targets: SQLite with 1 worker, PostgreSQL with 2.
TARGET_CLIENTS = {"sqlite": 8, "postgresql": 16}
CPU_TARGET = {"sqlite": 4.0, "postgresql": 5.0}  # service CPU/request ≤ this × the reference's
FLOOR_TARGET = {"sqlite": 2.0, "postgresql": 1.5}
"""The most a robot-loop request's server CPU may be, × its floor printed in the same run."""
OPEN_P99_MS = {"sqlite": 30.0, "postgresql": 60.0}


class Bench:
    def __init__(self, args: argparse.Namespace, console: Any) -> None:
        self.args, self.console = args, console
        self.wrk = require_wrk()
        self.rows: list[Row] = []
        self.floors: dict[str, Floor] = {}
        self.run_tag = secrets.token_hex(3)

    def say(self, text: str) -> None:
        self.console.print(f"[dim]{time.strftime('%H:%M:%S')}[/dim] {text}")

    def measure(
        self, served: Served, mode: str, clients: int, workdir: Path, label: str
    ) -> Figures:
        paths = label.startswith("postgresql")  # where the robots' writes ran, from /metrics
        before = robot_writes(served.url) if paths else {}
        fig = run_wrk(
            self.wrk,
            served.url,
            mode,
            clients,
            workdir,
            self.args.duration + self.args.warmup,
            self.args.warmup,
            re.sub(r"[^A-Za-z0-9.-]", "-", f"{self.run_tag}-{label}"),
            served.pgid,
        )
        if paths:
            after = robot_writes(served.url)
            fig.notes += [
                "writes "
                + ", ".join(f"{p} {n - before.get(p, 0.0):.0f}" for p, n in sorted(after.items()))
            ]
        extra = f", {fig.loops_per_s:.1f} loops/s" if fig.loops_per_s is not None else ""
        cpu = f", {fig.cpu_ms:.3f} ms CPU/request" if fig.cpu_ms is not None else ""
        self.say(
            f"  {label}: {fig.rps:.0f} req/s, p50 {fig.p50_ms:.1f} ms, "
            f"p99 {fig.p99_ms:.1f} ms{extra}{cpu}"
            + (f", {fig.errors} errors" if fig.errors else "")
            + (f" ({'; '.join(fig.notes)})" if fig.notes else "")
        )
        return fig

    def scenario_files(self, workdir: Path, keys: list[str], users: list[str]) -> None:
        (workdir / "keys.txt").write_text("\n".join(keys) + "\n")
        (workdir / "users.txt").write_text("\n".join(users) + "\n")

    def prepare_outcomes(
        self, data: Data, workdir: Path, users: list[str], loop: Figures, label: str
    ) -> None:
        """Open enough episodes per client for the outcome run (estimated from the loop run)."""
        per_loop = max(1.0, (loop.rps / loop.loops_per_s - 1) if loop.loops_per_s else 2.0)
        # Outcomes alone go faster than whole loops (an episode's start costs more), up to
        # about twice as fast here: open enough for three times, and a margin per client.
        needed = 3.0 * loop.rps * (self.args.duration + self.args.warmup) / per_loop
        per_client = min(self.args.max_open, math.ceil(needed / len(users)) + 5)
        self.say(f"  opening {per_client * len(users)} episodes for the outcome run")
        for i, user in enumerate(users, start=1):
            lines = data.open_episodes(user, per_client, f"{self.run_tag}-{label}-{i}")
            (workdir / f"episodes-{i}.txt").write_text("\n".join(lines) + "\n")

    def run_service(
        self,
        served: Served,
        data: Data,
        workdir: Path,
        keys: list[str],
        users: list[str],
        engine: str,
        workers: int,
        data_label: str,
    ) -> None:
        clients = len(users)
        self.scenario_files(workdir, keys[:clients], users)
        label = f"{engine}-{data_label.replace(' ', '')}-c{clients}"
        loop = self.measure(served, "loop", clients, workdir, f"{label} loop")
        self.rows.append(Row(engine, workers, "loop", clients, data_label, loop))
        if data_label == "empty" and clients == TARGET_CLIENTS[engine]:
            self.open_loop(served, keys[:clients], users, loop, engine, workers, label)
        if self.args.loop_only:
            return
        self.prepare_outcomes(data, workdir, users, loop, label)
        fig = self.measure(served, "outcome", clients, workdir, f"{label} outcome")
        self.rows.append(Row(engine, workers, "outcome", clients, data_label, fig))
        fig = self.measure(served, "model", clients, workdir, f"{label} model")
        self.rows.append(Row(engine, workers, "model", clients, data_label, fig))

    def open_loop(
        self,
        served: Served,
        keys: list[str],
        users: list[str],
        loop: Figures,
        engine: str,
        workers: int,
        label: str,
    ) -> None:
        """Robots that send at a fixed rate, half the capacity the closed loop just measured:
        latency at a realistic load, not at saturation."""
        import asyncio

        from openloop import run_open_loop

        steps = loop.rps / loop.loops_per_s if loop.loops_per_s else 3.0
        rate = loop.rps / 2
        cpu_before = group_cpu_s(served.pgid)
        result = asyncio.run(
            run_open_loop(
                served.url,
                keys,
                users,
                rate=rate,
                steps=steps,
                duration=self.args.duration * 2 + self.args.warmup,
                warmup=self.args.warmup,
                tag=re.sub(r"[^A-Za-z0-9.-]", "-", f"{self.run_tag}-{label}-open"),
            )
        )
        cpu_s = group_cpu_s(served.pgid) - cpu_before
        fig = Figures(
            rps=result.achieved_rps,
            p50_ms=result.pct(0.5),
            p99_ms=result.pct(0.99),
            count=len(result.latencies_ms),
            errors=result.errors,
        )
        if result.latencies_ms:
            fig.cpu_ms = cpu_s * 1000.0 / (len(result.latencies_ms) + result.errors)
        self.say(
            f"  {label} open loop at {rate:.0f} req/s offered: {fig.rps:.0f} req/s done, "
            f"p50 {fig.p50_ms:.1f} ms, p99 {fig.p99_ms:.1f} ms"
            + (f", {fig.errors} errors" if fig.errors else "")
        )
        self.rows.append(Row(engine, workers, "open", len(users), "empty", fig))

    def engine(self, engine: str, workers: int) -> None:
        args = self.args
        with tempfile.TemporaryDirectory(prefix="attune-bench-") as tmp:
            workdir = Path(tmp)
            self.say(f"[bold]{engine}[/bold], {workers} worker(s): reference app")
            refs: dict[int, Figures] = {}
            with server("reference", workers, workdir) as served:
                self.scenario_files(workdir, ["-"] * max(args.clients), ["-"] * max(args.clients))
                for c in args.clients:
                    refs[c] = self.measure(served, "ref", c, workdir, f"reference c{c}")
                    self.rows.append(Row(engine, workers, "reference", c, "-", refs[c]))
            with fresh_database(engine, workdir) as db_url:
                data = Data(db_url)
                try:
                    keys = data.keys(max(args.clients))
                    self.say(f"[bold]{engine}[/bold], {workers} worker(s): attune serve")
                    with server(
                        "service",
                        workers,
                        workdir,
                        db_url,
                        self.args.profile,
                        self.args.profile_format,
                    ) as served:
                        for c in args.clients:
                            users = [f"c{c}-robot{i}" for i in range(1, c + 1)]
                            self.run_service(
                                served, data, workdir, keys, users, engine, workers, "empty"
                            )
                    if args.large:
                        self.large(engine, workers, data, workdir, keys, db_url)
                finally:
                    data.close()
            if args.floor and TARGET_CLIENTS[engine] in args.clients:
                self.floor(engine, workdir / "floor")
            for row in self.rows:
                if row.engine == engine and row.scenario != "reference":
                    row.ref = refs.get(row.clients)

    def floor(self, engine: str, workdir: Path) -> None:
        """What the learner and the bare driver cost per robot request (``floor.py``)."""
        from floor import measure

        workdir.mkdir()
        with fresh_database(engine, workdir) as db_url:
            data = Data(db_url)
            try:
                users = [f"floor-robot{i}" for i in range(1, TARGET_CLIENTS[engine] + 1)]
                found = measure(
                    engine,
                    db_url,
                    data,
                    users,
                    self.args.floor_requests,
                    PG_SERVER.rstrip("/"),
                    self.say,
                    group=TARGET_CLIENTS[engine],
                )
            finally:
                data.close()
        self.floors[engine] = found
        self.say(
            f"  floor over {found.requests} requests: learner {found.learner_ms:.3f} ms, "
            f"{found.statements_per_request:.1f} statements through the bare driver "
            f"{found.statements_ms:.3f} ms"
        )

    def large(
        self, engine: str, workers: int, data: Data, workdir: Path, keys: list[str], db_url: str
    ) -> None:
        args = self.args
        self.say(f"seeding {args.users:,} users (bulk inserts)")
        t = time.perf_counter()
        data.users(args.users, "pop")
        self.say(f"  done in {time.perf_counter() - t:.1f} s")
        self.say(f"seeding one user with {args.episodes:,} episodes (the service's use cases)")
        t = time.perf_counter()
        step = max(1, args.episodes // 10)
        count = [0]

        def tick() -> None:
            count[0] += 1
            if count[0] % step == 0:
                self.say(f"  {count[0]:,} episodes, {time.perf_counter() - t:.0f} s")

        data.history("big", args.episodes, tick)
        self.say(f"  done in {time.perf_counter() - t:.1f} s")
        with server(
            "service", workers, workdir, db_url, self.args.profile, self.args.profile_format
        ) as served:
            wide = 8 if 8 in args.clients else max(args.clients)
            spread = max(1, args.users // wide)
            users = [f"pop{i * spread + spread // 2:06d}" for i in range(wide)]
            self.run_service(
                served, data, workdir, keys, users, engine, workers, f"{args.users // 1000}k users"
            )
            self.run_service(
                served,
                data,
                workdir,
                keys,
                ["big"],
                engine,
                workers,
                f"{args.episodes // 1000}k episodes",
            )
        for row in self.rows:
            if row.engine == engine and row.data not in ("empty", "-"):
                row.base = next(
                    (
                        r.fig
                        for r in self.rows
                        if r.engine == engine
                        and r.data == "empty"
                        and r.scenario == row.scenario
                        and r.clients == row.clients
                    ),
                    None,
                )


# -- the report --------------------------------------------------------------------------------
def machine() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpus": os.cpu_count(),
        "cpu": cpu,
        "python": platform.python_version(),
        "load": os.getloadavg(),
        "system": f"{platform.system()} {platform.release()}",
    }


def _ratio(a: float | None, b: float | None) -> str:
    if a is None or b is None or not b or math.isnan(a) or math.isnan(b):
        return ""
    return f"{a / b:.2f}"


def report(bench: Bench, console: Any, before: dict[str, Any], seconds: float) -> list[str]:
    from rich.table import Table

    names = {
        "loop": "robot loop",
        "outcome": "outcome",
        "model": "model read",
        "reference": "reference",
        "open": "open loop, ½ capacity",
    }
    table = Table(
        "engine",
        "scenario",
        "clients",
        "data",
        "req/s",
        "×ref",
        "p50 ms",
        "p99 ms",
        "CPU ms/req",
        "ref/CPU",
        "loops/s",
        title="attune serve under load. ×ref: throughput divided by the reference's at "
        "the same concurrency (×empty for the seeded data); ref/CPU: the reference's "
        "CPU per request divided by the service's (1 = as cheap as a bare FastAPI POST)",
    )
    for r in bench.rows:
        f = r.fig
        other = r.base if r.base is not None else r.ref
        table.add_row(
            f"{r.engine}/{r.workers}w",
            names[r.scenario],
            str(r.clients),
            r.data,
            f"{f.rps:.0f}",
            _ratio(f.rps, other.rps if other else None),
            f"{f.p50_ms:.1f}",
            f"{f.p99_ms:.1f}",
            f"{f.cpu_ms:.3f}" if f.cpu_ms is not None else "",
            _ratio(r.ref.cpu_ms if r.ref else None, f.cpu_ms) if r.scenario != "reference" else "",
            f"{f.loops_per_s:.1f}" if f.loops_per_s is not None else "",
        )
    console.print(table)
    after = machine()
    console.print(
        f"Machine: {before['cpus']} CPUs ({before['cpu']}), {before['system']}, "
        f"Python {before['python']}; load average {before['load'][0]:.2f} before, "
        f"{after['load'][0]:.2f} after ({seconds / 60:.1f} min)."
        + (
            " The machine was busy with other work before the run."
            if before["load"][0] > 0.5
            else ""
        )
    )
    return targets(bench, console)


def floor_line(engine: str, floor: Floor, bare: float, target: float, service: float) -> str:
    """The floor of a robot-loop request against its CPU target (all in ms per request)."""
    least = bare + floor.learner_ms + floor.statements_ms
    room = target - least
    head = (
        f"{engine}: floor of a robot-loop request: the bare POST {bare:.3f} ms + the "
        f"learner {floor.learner_ms:.3f} ms + {floor.statements_per_request:.1f} statements "
        f"through the bare driver {floor.statements_ms:.3f} ms = {least:.3f} ms, "
        f"{least / bare:.2f}× the bare POST; "
    )
    if room > 0:
        return (
            head + f"the target leaves {room:.3f} ms ({room / bare:.2f}×) for the rest of "
            f"the request, where the service spends {service - least:.3f} ms"
        )
    return (
        head + f"the target is {-room:.3f} ms below this floor: no change outside the "
        f"learner and the statements can meet it (the rest of the request costs the "
        f"service {service - least:.3f} ms)"
    )


def targets(bench: Bench, console: Any) -> list[str]:
    lines: list[str] = []

    def find(engine: str, scenario: str, clients: int, data: str = "empty") -> Row | None:
        return next(
            (
                r
                for r in bench.rows
                if (r.engine, r.scenario, r.clients, r.data) == (engine, scenario, clients, data)
            ),
            None,
        )

    def verdict(ok: bool) -> str:
        return "[green]met[/green]" if ok else "[red]missed[/red]"

    for engine in ("sqlite", "postgresql"):
        clients = TARGET_CLIENTS[engine]
        r = find(engine, "loop", clients)
        if r is not None and r.ref is not None and r.fig.cpu_ms and r.ref.cpu_ms:
            bare = r.ref.cpu_ms
            times = r.fig.cpu_ms / bare
            limit = CPU_TARGET[engine]
            lines.append(
                f"{engine}, {r.workers} worker(s), {clients} robots: a robot-loop "
                f"request costs {r.fig.cpu_ms:.3f} ms of server CPU, {times:.2f}× the "
                f"bare POST's {bare:.3f} ms (ratio {1 / times:.2f}; target ≤ "
                f"{limit:g}×, ratio ≥ {1 / limit:.2f}): {verdict(times <= limit)}"
            )
            floor = bench.floors.get(engine)
            if floor is not None:
                lines.append(floor_line(engine, floor, bare, limit * bare, r.fig.cpu_ms))
                least = bare + floor.learner_ms + floor.statements_ms
                over = r.fig.cpu_ms / least
                lines.append(
                    f"{engine}, {clients} robots: the service's {r.fig.cpu_ms:.3f} ms is "
                    f"{over:.2f}× this floor of {least:.3f} ms (target ≤ "
                    f"{FLOOR_TARGET[engine]:g}×): {verdict(over <= FLOOR_TARGET[engine])}"
                )
        r = find(engine, "open", clients)
        if r is not None:
            limit = OPEN_P99_MS[engine]
            lines.append(
                f"{engine}: open loop at half capacity ({r.fig.rps:.0f} req/s), p99 "
                f"{r.fig.p99_ms:.1f} ms (target < {limit:g} ms): "
                f"{verdict(r.fig.p99_ms < limit and not r.fig.errors)}"
                + (f" ({r.fig.errors} errors)" if r.fig.errors else "")
            )
        for r in bench.rows:
            if r.engine == engine and r.base is not None:
                slower = max(r.base.rps / r.fig.rps, r.fig.p50_ms / r.base.p50_ms)
                lines.append(
                    f"{engine}: {r.scenario} with {r.data} ({r.clients} clients): "
                    f"{slower:.2f}× the empty database's figure (throughput and p50; "
                    f"target ≤ 1.2×): {verdict(slower <= 1.2)}"
                )
    console.print("[bold]Targets[/bold]")
    for line in lines:
        console.print("  " + line)
    return lines


def serve_reference(port: int, workers: int) -> None:
    """The reference app, served exactly as ``attune serve`` serves the service (same uvicorn
    options, no uvicorn access log, the same listening socket with TCP_NODELAY bound first)."""
    import uvicorn

    options: dict[str, Any] = {
        "factory": True,
        "host": "127.0.0.1",
        "port": port,
        "workers": workers,
        "log_level": "warning",
        "access_log": False,
        "proxy_headers": False,
    }
    config = uvicorn.Config("service:reference_app", **options)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.set_inheritable(True)
    if workers == 1:
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl+C: as uvicorn.run does
            uvicorn.Server(config).run(sockets=[sock])
        return
    from uvicorn.supervisors import Multiprocess

    Multiprocess(config, sockets=[sock]).run()


def main() -> None:
    if sys.argv[1:2] == ["--serve-reference"]:
        serve_reference(int(sys.argv[2]), int(sys.argv[3]))
        return
    parser = argparse.ArgumentParser(
        description="Throughput and latency of attune serve under wrk, against a bare FastAPI "
        "app on the same machine (loopback only). Needs wrk (apt-get install -y wrk) and, for "
        "PostgreSQL, a server at 127.0.0.1:5432 (ATTUNE_TEST_POSTGRES_URL)."
    )
    parser.add_argument("--engine", choices=["sqlite", "postgresql", "both"], default="both")
    parser.add_argument(
        "--clients",
        default="1,8,16",
        help="concurrent clients, comma-separated (default 1,8,16; the CPU and "
        "open-loop targets are at 8 robots on SQLite and 16 on PostgreSQL)",
    )
    parser.add_argument(
        "--duration", type=float, default=5.0, help="seconds measured per run (default 5)"
    )
    parser.add_argument(
        "--warmup", type=float, default=1.0, help="seconds run before measuring (default 1)"
    )
    parser.add_argument(
        "--users",
        type=int,
        default=100_000,
        help="users seeded for the large-data runs (default 100000)",
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=10_000,
        help="episodes of the one long-history user (default 10000)",
    )
    parser.add_argument(
        "--no-large", dest="large", action="store_false", help="skip the large-data runs"
    )
    parser.add_argument(
        "--loop-only",
        action="store_true",
        help="only the robot loop (and the open loop): no outcome-only or model-read runs",
    )
    parser.add_argument(
        "--max-open",
        type=int,
        default=3000,
        help="cap on episodes opened per client for the outcome run",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a short check: 8 clients, 2 s runs, 2,000 users, 200 episodes",
    )
    parser.add_argument(
        "--no-floor",
        dest="floor",
        action="store_false",
        help="skip the floor: the learner's and the bare driver's CPU per robot "
        "request, measured in-process after the runs at the target robots",
    )
    parser.add_argument(
        "--floor-requests",
        type=int,
        default=3000,
        help="robot requests recorded and replayed for the floor (default 3000)",
    )
    parser.add_argument("--json", type=Path, help="also write the figures here")
    parser.add_argument(
        "--profile",
        type=Path,
        metavar="DIR",
        help="run the service under py-spy and write its profiles to DIR (one "
        "per server run); the figures then include the profiler's cost",
    )
    parser.add_argument(
        "--profile-format",
        choices=["flamegraph", "speedscope", "raw"],
        default="flamegraph",
        help="py-spy's output: an SVG flame graph (default), a speedscope "
        "JSON, or collapsed stacks as text",
    )
    args = parser.parse_args()
    if args.quick:
        args.clients, args.duration, args.users, args.episodes = "8,16", 2.0, 2000, 200
        args.floor_requests = min(args.floor_requests, 1000)
    if args.floor_requests < 1:
        parser.error("--floor-requests must be at least 1")
    args.clients = sorted({int(c) for c in str(args.clients).split(",")})
    from rich.console import Console

    console = Console(width=None if sys.stdout.isatty() else 150)
    before = machine()
    began = time.monotonic()
    bench = Bench(args, console)
    plan = {
        "sqlite": [("sqlite", 1)],
        "postgresql": [("postgresql", 2)],
        "both": [("sqlite", 1), ("postgresql", 2)],
    }[args.engine]
    for engine, workers in plan:
        bench.engine(engine, workers)
    lines = report(bench, console, before, time.monotonic() - began)
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "machine": before,
                    "command": " ".join(sys.argv),
                    "targets": lines,
                    "floors": {engine: found.__dict__ for engine, found in bench.floors.items()},
                    "rows": [
                        {
                            "engine": r.engine,
                            "workers": r.workers,
                            "scenario": r.scenario,
                            "clients": r.clients,
                            "data": r.data,
                            **r.fig.__dict__,
                            "ref_rps": r.ref.rps if r.ref else None,
                            "base_rps": r.base.rps if r.base else None,
                        }
                        for r in bench.rows
                    ],
                },
                indent=1,
                default=str,
            )
        )


if __name__ == "__main__":
    main()
