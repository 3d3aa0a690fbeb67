"""Off-policy evaluation at scale: the time and memory of ``attune evaluate`` over a fleet's
100,000 logged steps, on SQLite and on PostgreSQL.

    .venv/bin/python bench/evaluation.py                         # both engines, 100,000 steps
    .venv/bin/python bench/evaluation.py --engine sqlite --steps 20000
    .venv/bin/python bench/evaluation.py --candidate dts --candidate rmax --tracemalloc
    .venv/bin/python bench/evaluation.py --engine postgresql --delay 1   # the database a hop away
    .venv/bin/python bench/evaluation.py --engine sqlite --json > evaluation.json

Loopback only. Per engine, on a fresh database (a SQLite file in WAL mode, or a database
``attune_bench_...`` on the PostgreSQL server at 127.0.0.1:5432, dropped after):

**The fleet.** Filled as ``bench/retention.py`` fills its databases ("Filling fast" there):
``--template-people`` people play ``--template-episodes`` episodes through a live ``attune
serve`` (explicit feedback on some, staff corrections on two of them), then they are cloned in
SQL (``INSERT ... SELECT``) under new people, after a trial clone of each is rebuilt from its
journal (a person whose clone does not rebuild is not cloned, and the output says why). The
clone goes on until the fleet holds at least ``--steps`` *logged steps*: the steps of the closed
episodes the evaluation counts, each decision's drawn silent steps and its visible step (forced
ones too), which is what the evaluation's estimators weigh. A template person's steps are
counted by the evaluation's own reading of a person (``_read_person`` of
``app.services.evaluation``), before the clone; a clone is an exact copy, so the fill knows the
fleet's steps as it goes. No ages are moved: the evaluation counts every closed episode
whatever its time (no ``--since``/``--until``). After the fill the service is stopped (nothing
else runs beside the measurements); PostgreSQL gets a ``VACUUM ANALYZE`` and a ``CHECKPOINT``
(what autovacuum would have done, and the fill's writes out of the way).

**The measurements**, each in a fresh Python process of its own (this script, ``--child``), so
that its memory is its own, reading the database as ``attune evaluate`` does (the same
settings, ``ServiceContext.from_settings``, a ``Database`` of its own):

- *read only* (the reference): the evaluation's own read path without the replay: the fleet's
  people a page at a time, each person read in one read transaction by ``_read_person`` (the
  journal, the episodes, the decisions, the feedback), the episodes and steps that count summed.
  Its steps are the figure the report gives as the fleet's logged steps, and the check compares
  them with what the fill planned.
- *full evaluation*: ``evaluate_fleet(database, ctx, fleet, candidates)`` with the
  ``--candidate`` learners (default ``dts`` and ``hri:tau=0.005``, as ``attune evaluate
  --candidate dts --candidate 'hri:tau=0.005'`` runs), the default estimator. Its ``progress``
  callback, called after each person, tells when the last person was read and replayed: the
  time before it is reading and replaying, the time after it the estimators, the bootstrap
  intervals (the fleet's, the differences', and each person's). The check: the evaluation
  counted the people and episodes the read-only pass counted, and left no person out.

Per process: wall seconds of the work (the process's start, imports and the database's opening
not counted), its CPU seconds (user + system, ``getrusage``), its RSS just before the work
(*baseline*: the interpreter, the imports, the database opened and one ``SELECT 1``) and the
peak RSS during the work (``VmHWM`` of ``/proc/self/status``, set back to the RSS of the moment
just before the work through ``/proc/self/clear_refs``): the work's own memory is the
difference. Not ``getrusage``'s ``ru_maxrss``: in a process started by fork and exec it keeps
the peak of the memory it had before the exec, the parent's (this script's, 130 MiB or so with
what it imports), which hides any smaller peak; the JSON has it beside, for comparison. With
``--tracemalloc`` a third process runs the full evaluation again under ``tracemalloc`` for the
peak of the Python heap (numpy's arrays included); it is slower, which is why its time is not
the one reported. On PostgreSQL the database server's own CPU and memory are not in these
figures (the wall time includes the waits for it).

``--delay MS`` (PostgreSQL) puts the database one network hop away for the measurements,
through the delaying TCP proxy of ``bench/remote_db.py`` (``bench/delayproxy.py``), as
``bench/retention.py --delay`` does; the fill goes to the database directly.

Bounded: the whole run stops at ``--max-minutes`` (default 60): a fill still cloning stops
cloning, a measurement still running is killed, and the output says which, with what was
measured before; the exit code is then 3. A failed check gives exit 1.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

FLEET = "default"
DEFAULT_CANDIDATES = ("dts", "hri:tau=0.005")
MIB = 2**20


# -- a measurement, in a process of its own -------------------------------------------------------
# Only what the evaluation needs is imported here: the baseline RSS is then close to that of
# ``attune evaluate`` before its work (the parent's modules, httpx, pytest, uvicorn, are not).


def _status_bytes(name: str) -> int:
    """A figure of ``/proc/self/status`` in bytes: ``VmRSS`` (the resident set now), ``VmHWM``
    (its peak)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{name}:"):
            return int(line.split()[1]) * 1024
    return 0


def _reset_peak() -> bool:
    """Set the peak resident set (``VmHWM``) back to the resident set now (``clear_refs``, Linux
    4.0 on): from then on the peak is the work's. False when the kernel refuses."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def _cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return float(usage.ru_utime + usage.ru_stime)


def read_fleet(database: Any, ctx: Any, fleet: str) -> dict[str, Any]:
    """The evaluation's read path without the replay: each person of ``fleet`` read as
    ``evaluate_fleet`` reads them (``_people``, then ``_read_person`` in a read transaction of
    its own); their episodes and steps that count (the steps: the sum of the episodes'
    lengths, as the evaluation's ``Steps`` holds them)."""
    from app.services import evaluation

    people = 0
    per_person: dict[str, tuple[int, int]] = {}
    skipped: dict[str, int] = {}
    left_out: list[tuple[str, str]] = []
    for page in evaluation._people(database, fleet):
        for user in page:
            people += 1
            try:
                with database.transaction(write=False) as session:
                    history = evaluation._read_person(session, ctx, user, None, None)
            except (ValueError, KeyError, LookupError) as exc:
                left_out.append((user.user_id, str(exc)))
                continue
            for why, n in history.skipped.items():
                skipped[why] = skipped.get(why, 0) + n
            if history.lengths:
                per_person[user.user_id] = (len(history.lengths), sum(history.lengths))
    return {
        "people": people,
        "people_counted": len(per_person),
        "episodes": sum(e for e, _ in per_person.values()),
        "steps": sum(s for _, s in per_person.values()),
        "skipped": dict(sorted(skipped.items())),
        "people_skipped": len(left_out),
        "per_person": per_person,
    }


def _child(argv: list[str]) -> int:
    """``--child read|evaluate --url URL [--candidate C ...] [--tracemalloc]``: one
    measurement, one JSON document on stdout."""
    parser = argparse.ArgumentParser(prog="bench/evaluation.py --child")
    parser.add_argument("mode", choices=("read", "evaluate"))
    parser.add_argument("--url", required=True)
    parser.add_argument("--fleet", default=FLEET)
    parser.add_argument("--candidate", action="append", default=[])
    parser.add_argument("--tracemalloc", action="store_true")
    args = parser.parse_args(argv)

    from sqlalchemy import text

    from app.db.session import Database
    from app.services import evaluation
    from app.services.context import ServiceContext
    from app.settings import Settings

    settings = Settings(database_url=args.url, _env_file=None)  # type: ignore[call-arg]
    ctx = ServiceContext.from_settings(settings)
    specs = [evaluation.parse_candidate(c) for c in args.candidate]
    database = Database(settings)
    try:
        with database.transaction(write=False) as session:
            session.execute(text("SELECT 1"))
        baseline, startup_peak = _status_bytes("VmRSS"), _status_bytes("VmHWM")
        reset = _reset_peak()
        if args.tracemalloc:
            import tracemalloc

            tracemalloc.start()
        last_person = [0.0]

        def progress(done: int, total: int) -> None:
            last_person[0] = time.perf_counter()

        cpu0, began = _cpu_s(), time.perf_counter()
        doc: dict[str, Any] = {"mode": args.mode, "tracemalloc": args.tracemalloc}
        if args.mode == "read":
            found = read_fleet(database, ctx, args.fleet)
            doc.update({k: v for k, v in found.items() if k != "per_person"})
        else:
            result = evaluation.evaluate_fleet(database, ctx, args.fleet, specs, progress=progress)
            doc.update(
                {
                    "people": result.people,
                    "people_counted": result.people_counted,
                    "episodes": result.episodes,
                    "skipped": dict(result.skipped),
                    "people_skipped": len(result.people_skipped),
                    "estimator": result.estimator,
                    "logged": result.logged.to_dict(),
                    "candidates": [
                        {
                            "key": c.spec.key,
                            "label": c.spec.label,
                            "estimate": c.estimate.to_dict(),
                            "enough": c.enough,
                            "verdict": c.verdict,
                            "entries_refused": c.entries_refused,
                        }
                        for c in result.candidates
                    ],
                }
            )
        ended = time.perf_counter()
        doc.update(
            {
                "seconds": ended - began,
                "cpu_seconds": _cpu_s() - cpu0,
                "baseline_rss_bytes": baseline,
                "startup_peak_rss_bytes": startup_peak,
                # the peak since the reset, the work's (else the process's whole life's)
                "peak_rss_bytes": _status_bytes("VmHWM"),
                "peak_reset": reset,
                # getrusage's, for comparison: after a fork-and-exec it also holds the
                # parent's resident set at the exec (the kernel carries the old memory's peak
                # over), so it is not this process's own
                "ru_maxrss_bytes": int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024,
            }
        )
        if args.mode == "evaluate":
            replayed = (last_person[0] or began) - began
            doc["read_replay_seconds"] = replayed
            doc["estimators_seconds"] = ended - began - replayed
        if args.tracemalloc:
            import tracemalloc

            doc["tracemalloc_peak_bytes"] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    finally:
        database.dispose()
    print(json.dumps(doc))
    return 0


if __name__ == "__main__" and sys.argv[1:2] == ["--child"]:
    sys.exit(_child(sys.argv[2:]))


# -- the parent: the fleets, the measurements, the report -----------------------------------------
import math  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
from dataclasses import asdict, dataclass, field  # noqa: E402

import retention  # noqa: E402
from retention import CloneRefused, say  # noqa: E402
from service import machine  # noqa: E402
from sqlalchemy import delete, select  # noqa: E402

from app.db import models  # noqa: E402
from app.db.base import Base  # noqa: E402
from app.db.session import Database  # noqa: E402
from app.services.context import ServiceContext  # noqa: E402
from app.services.evaluation import parse_candidate  # noqa: E402
from app.settings import Settings  # noqa: E402
from tests.support.live import LiveService, make_keys  # noqa: E402


class OutOfTime(RuntimeError):
    """``--max-minutes`` reached."""


@dataclass
class Filled:
    """What the fill made: ``steps_planned`` is the fleet's logged steps as the fill counted
    them (each template person's, read as the evaluation reads them, times their copies)."""

    target_steps: int
    people: int
    episodes: int  # rows of the episodes table, open and closed
    steps_planned: int
    template_people: int
    template_episodes: int
    template_steps: int
    template_requests: int
    template_seconds: float
    clones: int  # cloned people
    not_cloned: dict[str, str]  # template person -> why its trial clone was refused
    clone_seconds: float
    stopped: str = ""  # why the fill stopped short ("" when it reached the target)
    rows: dict[str, int] = field(default_factory=dict)


def _settings(url: str) -> Settings:
    return Settings(database_url=url, _env_file=None)  # type: ignore[call-arg]


def _template_steps(url: str) -> dict[str, tuple[int, int]]:
    """Each person's (episodes, steps) that count, read as the evaluation reads them."""
    settings = _settings(url)
    db = Database(settings)
    try:
        found = read_fleet(db, ServiceContext.from_settings(settings), FLEET)
    finally:
        db.dispose()
    counted: dict[str, tuple[int, int]] = found["per_person"]
    return counted


def fill(args: argparse.Namespace, service: LiveService, url: str, deadline: float) -> Filled:
    """Template people through the API, then cloned in SQL until the fleet holds at least
    ``args.steps`` logged steps (retention's template and clone, counted in steps)."""
    target = args.steps
    schema = retention.Schema.read(Base.metadata, retention._table(models.User), "user_id")
    robot_keys = make_keys(url, args.template_robots, "robot", FLEET)
    staff_key = make_keys(url, 1, "staff", FLEET)[0]
    say(
        f"  template: {args.template_people} people play {args.template_episodes:,} episodes "
        f"through the API ({args.template_robots} robots)"
    )
    tpl = retention.play_template(
        service.url,
        robot_keys,
        staff_key,
        args.template_people,
        args.template_episodes,
        args.seed,
    )
    per_person = _template_steps(url)
    steps_of = {p: per_person.get(p, (0, 0))[1] for p in tpl.people}
    template_steps = sum(steps_of.values())
    say(
        f"  template played in {tpl.seconds:.1f} s ({tpl.requests:,} requests): "
        f"{template_steps:,} logged steps in {sum(e for e, _ in per_person.values()):,} "
        "closed episodes"
    )
    db = Database(_settings(url))
    began = time.monotonic()
    refused: dict[str, str] = {}
    clones = 0
    stopped = ""
    total = template_steps
    try:
        with db.engine.connect() as conn:
            cloner = retention.Cloner(conn, schema)
            conn.commit()
            users, key = schema.users, schema.key
            pk = users.primary_key.columns.values()[0]
            ids = dict(conn.execute(select(users.c[key.name], pk)).all())
            clonable = [p for p in tpl.people if steps_of[p] > 0]
            if total < target:
                # One trial clone of everyone, rebuilt: those that do not rebuild are removed.
                cloner.clone([ids[p] for p in clonable], [1])
                conn.commit()
                for person in clonable:
                    why = retention._rebuilds(url, f"{person}-c1")
                    if why is not None:
                        refused[person] = why
                if refused:
                    conn.execute(
                        delete(users).where(users.c[key.name].in_([f"{p}-c1" for p in refused]))
                    )
                    conn.commit()
                    say(
                        "  not cloned (their trial clone does not rebuild): "
                        + ", ".join(f"{p} ({why[:160]})" for p, why in refused.items())
                    )
                clonable = [p for p in clonable if p not in refused]
                if not clonable:
                    raise CloneRefused("no template person's clone rebuilds: nothing to clone")
                clones += len(clonable)
                total += sum(steps_of[p] for p in clonable)
            block = sum(steps_of[p] for p in clonable)
            block_episodes = sum(per_person[p][0] for p in clonable) or 1
            full = max(0, (target - total) // max(block, 1))
            if full + 2 > cloner.capacity():
                raise CloneRefused(f"{full + 2} clones do not fit the ids' room")
            per_chunk = max(1, retention.CHUNK_EPISODES // block_episodes)
            n = 2
            last_line = time.monotonic()
            while n < 2 + full:
                if time.monotonic() > deadline:
                    stopped = f"--max-minutes reached while cloning, at {total:,} steps"
                    break
                numbers = list(range(n, min(2 + full, n + per_chunk)))
                cloner.clone([ids[p] for p in clonable], numbers)
                conn.commit()
                total += block * len(numbers)
                clones += len(clonable) * len(numbers)
                n = numbers[-1] + 1
                if time.monotonic() - last_line > 10 or n >= 2 + full:
                    say(f"  cloned: {total:,} / {target:,} logged steps")
                    last_line = time.monotonic()
            if not stopped and total < target:  # the rest: the first people of one more clone
                part: list[str] = []
                for p in clonable:
                    if total >= target:
                        break
                    part.append(p)
                    total += steps_of[p]
                cloner.clone([ids[p] for p in part], [n])
                conn.commit()
                clones += len(part)
            rows = retention._counts(conn, schema)
            conn.commit()
    finally:
        db.dispose()
    seconds = time.monotonic() - began
    ep = retention._table(models.Episode).name
    say(
        f"  filled: {total:,} logged steps, {rows[ep]:,} episodes of "
        f"{rows[schema.users.name]:,} people (cloned in {seconds:.1f} s)"
    )
    return Filled(
        target_steps=target,
        people=rows[schema.users.name],
        episodes=rows[ep],
        steps_planned=total,
        template_people=len(tpl.people),
        template_episodes=tpl.episodes,
        template_steps=template_steps,
        template_requests=tpl.requests,
        template_seconds=tpl.seconds,
        clones=clones,
        not_cloned=refused,
        clone_seconds=seconds,
        stopped=stopped,
        rows=rows,
    )


def measure(
    mode: str,
    url: str,
    candidates: list[str],
    deadline: float,
    *,
    traced: bool = False,
    env: dict[str, str] | None = None,
) -> dict[str, Any]:
    """One measurement in a process of its own (this script, ``--child``); ``OutOfTime`` (the
    process killed) past ``deadline``."""
    command = [sys.executable, str(Path(__file__).resolve()), "--child", mode, "--url", url]
    for c in candidates if mode == "evaluate" else []:
        command += ["--candidate", c]
    if traced:
        command.append("--tracemalloc")
    remaining = deadline - time.monotonic()
    if remaining <= 0:
        raise OutOfTime(f"--max-minutes reached before the {_what(mode, traced)}")
    began = time.monotonic()
    proc = subprocess.Popen(
        command,
        env={**os.environ, **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=remaining)
    except subprocess.TimeoutExpired:
        retention._stop(proc)
        raise OutOfTime(
            f"--max-minutes reached during the {_what(mode, traced)}: stopped after "
            f"{time.monotonic() - began:,.0f} s"
        ) from None
    if proc.returncode != 0:
        raise RuntimeError(f"the {_what(mode, traced)} failed ({proc.returncode}):\n{err[-4000:]}")
    doc: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    doc["process_seconds"] = time.monotonic() - began
    return doc


def _what(mode: str, traced: bool) -> str:
    name = "read-only pass" if mode == "read" else "full evaluation"
    return f"{name} under tracemalloc" if traced else name


def engine_run(
    engine: str, args: argparse.Namespace, folder: Path, deadline: float
) -> dict[str, Any]:
    """One engine: a fresh database, filled; the measurements; the check."""
    say(f"{engine}: a fleet of at least {args.steps:,} logged steps")
    found: dict[str, Any] = {"stopped": ""}
    place_args = argparse.Namespace(
        pooler="none", delay=args.delay, max_run_minutes=args.max_minutes
    )
    with retention.place(engine, place_args, folder) as where:
        found["place"] = where.note or "the database on this machine"
        found["round_trip_ms"] = where.round_trip_ms
        with LiveService(
            where.direct_url,
            workers=1 if engine == "sqlite" else 2,
            log_path=folder / f"serve-{engine}.log",
        ) as service:
            filled = fill(args, service, where.direct_url, deadline)
        found["fill"] = asdict(filled)
        if engine == "postgresql":
            retention.vacuum(engine, where.direct_url)  # ANALYZE, and a CHECKPOINT
        found["size"] = retention.size(engine, where.direct_url)
        if filled.stopped:
            found["stopped"] = filled.stopped
            say(f"  stopped: {filled.stopped}")
            return found
        try:
            say("  read only (the evaluation's read path, no replay)")
            read = measure("read", where.service_url, args.candidate, deadline, env=where.env)
            found["read"] = read
            say(
                f"  read only: {read['steps']:,} steps of {read['episodes']:,} episodes in "
                f"{read['seconds']:,.1f} s, peak RSS {read['peak_rss_bytes'] / MIB:,.1f} MiB"
            )
            say(f"  full evaluation: {', '.join(args.candidate)}")
            full = measure("evaluate", where.service_url, args.candidate, deadline, env=where.env)
            found["evaluate"] = full
            say(
                f"  full evaluation: {full['episodes']:,} episodes in {full['seconds']:,.1f} s, "
                f"peak RSS {full['peak_rss_bytes'] / MIB:,.1f} MiB"
            )
            if args.tracemalloc:
                say("  full evaluation under tracemalloc")
                found["traced"] = measure(
                    "evaluate",
                    where.service_url,
                    args.candidate,
                    deadline,
                    traced=True,
                    env=where.env,
                )
        except OutOfTime as stop:
            found["stopped"] = str(stop)
            say(f"  stopped: {stop}")
    if "read" in found:
        read = found["read"]
        evaluated: dict[str, Any] | None = found.get("evaluate")
        found["check"] = {
            "steps_at_least_requested": read["steps"] >= args.steps,
            "steps_as_planned": read["steps"] == filled.steps_planned,
            "no_person_left_out": read["people_skipped"] == 0
            and (evaluated is None or evaluated["people_skipped"] == 0),
            "evaluation_counted_the_same": evaluated is None
            or (
                evaluated["episodes"] == read["episodes"]
                and evaluated["people"] == read["people"]
                and evaluated["people_counted"] == read["people_counted"]
            ),
        }
        found["check"]["ok"] = all(found["check"].values())
    return found


# -- the report -----------------------------------------------------------------------------------
def _mib(n: float | None) -> str:
    return "-" if n is None else f"{n / MIB:,.1f}"


def _num(x: float | None, digits: int = 2) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def rows_of(doc: dict[str, Any], engine: str) -> list[dict[str, Any]]:
    """The table of one engine: the reference and the evaluation, with the steps the reference
    counted (the evaluation's own count of steps is not in its result)."""
    found = doc["engines"][engine]
    read = found.get("read")
    if read is None:
        return []
    out = []
    for label, run, n in (
        ("read only (reference)", read, 0),
        ("full evaluation", found.get("evaluate"), len(doc["candidates"])),
    ):
        if run is None:
            continue
        out.append(
            {
                "run": label,
                "people": run["people"],
                "episodes": run["episodes"],
                "steps": read["steps"],
                "candidates": n,
                "seconds": run["seconds"],
                "steps_per_second": read["steps"] / max(run["seconds"], 1e-9),
                "cpu_seconds": run["cpu_seconds"],
                "baseline_rss_mib": run["baseline_rss_bytes"] / MIB,
                "peak_rss_mib": run["peak_rss_bytes"] / MIB,
                "own_mib": (run["peak_rss_bytes"] - run["baseline_rss_bytes"]) / MIB,
            }
        )
    return out


def render(doc: dict[str, Any]) -> str:
    lines: list[str] = []
    add = lines.append
    m = doc["machine"]
    add(
        f"Evaluation benchmark: {m['cpus']} CPUs ({m['cpu']}), {m['system']}, Python "
        f"{m['python']}; load average {m['load'][0]:.2f} before, {doc['load_after'][0]:.2f} "
        f"after; {doc['minutes']:.1f} min."
    )
    add(f"Command: {doc['command']}")
    add(
        f"Candidates: {', '.join(f'{c} ({k})' for k, c in doc['labels'].items())}; the default "
        f"estimator; the reference is the evaluation's read path alone (no replay, no estimate)."
    )
    for engine, found in doc["engines"].items():
        add("")
        add(f"== {engine} ({found['place']}) ==")
        if "fill" not in found:
            add(f"  STOPPED: {found['stopped']}")
            continue
        f = found["fill"]
        add(
            f"The fleet: {f['people']:,} people, {f['episodes']:,} episodes "
            f"({f['template_people']} people played {f['template_episodes']:,} through the API "
            f"in {f['template_seconds']:.0f} s, {f['template_steps']:,} logged steps; "
            f"{f['clones']:,} clones in SQL in {f['clone_seconds']:.0f} s); "
            f"the database {_mib(found['size']['bytes'])} MiB."
        )
        if f["not_cloned"]:
            add(
                "  not cloned (their trial clone did not rebuild): "
                + ", ".join(f"{p}: {why[:160]}" for p, why in f["not_cloned"].items())
            )
        table = rows_of(doc, engine)
        if table:
            add(
                f"  {'':<22} {'people':>7} {'episodes':>9} {'steps':>9} {'cand.':>5} "
                f"{'seconds':>8} {'steps/s':>8} {'CPU s':>7} {'base RSS':>9} {'peak RSS':>9} "
                f"{'own':>8}"
            )
            for r in table:
                add(
                    f"  {r['run']:<22} {r['people']:>7,} {r['episodes']:>9,} {r['steps']:>9,} "
                    f"{r['candidates']:>5} {r['seconds']:>8,.1f} {r['steps_per_second']:>8,.0f} "
                    f"{r['cpu_seconds']:>7,.1f} {r['baseline_rss_mib']:>9,.1f} "
                    f"{r['peak_rss_mib']:>9,.1f} {r['own_mib']:>8,.1f}"
                )
            add(
                "  (RSS in MiB: base just before the work, peak during it (VmHWM reset at its "
                "start); own = peak - base)"
            )
        full = found.get("evaluate")
        read = found.get("read")
        if full and read:
            n = max(len(doc["candidates"]), 1)
            replay = full["read_replay_seconds"] - read["seconds"]
            add(
                f"  where the evaluation's time goes: reading and replaying "
                f"{full['read_replay_seconds']:,.1f} s (until its last person; reading alone "
                f"{read['seconds']:,.1f} s, so the replay about {replay:,.1f} s, "
                f"{replay / n:,.1f} s a candidate, "
                f"{replay / n / max(read['steps'], 1) * 1e6:,.0f} µs a step), the estimators "
                f"and their intervals {full['estimators_seconds']:,.1f} s"
            )
            logged = full["logged"]
            add(
                f"  the estimates ({full['estimator']}): what the robots do now "
                f"{_num(logged['value'])}; "
                + "; ".join(
                    f"{c['label']} {_num(c['estimate']['value'])} (ESS "
                    f"{c['estimate']['ess']:,.1f}): {c['verdict']}"
                    for c in full["candidates"]
                )
            )
            if full.get("skipped"):
                add(
                    "  episodes not counted: "
                    + ", ".join(f"{n:,} {why}" for why, n in full["skipped"].items())
                )
        traced = found.get("traced")
        if traced:
            add(
                f"  under tracemalloc (a run of its own, {traced['seconds']:,.1f} s): the Python "
                f"heap's peak {_mib(traced['tracemalloc_peak_bytes'])} MiB"
            )
        if "check" in found:
            c = found["check"]
            add(
                f"  check: {read['steps']:,} steps (at least {f['target_steps']:,}: "
                f"{'yes' if c['steps_at_least_requested'] else 'NO'}; as the fill planned, "
                f"{f['steps_planned']:,}: {'yes' if c['steps_as_planned'] else 'NO'}); the "
                f"evaluation counted the people and episodes the read counted: "
                f"{'yes' if c['evaluation_counted_the_same'] else 'NO'}; no person left out: "
                f"{'yes' if c['no_person_left_out'] else 'NO'}: "
                + ("ok" if c["ok"] else "MISMATCH")
            )
        if found["stopped"]:
            add(f"  STOPPED: {found['stopped']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bench/evaluation.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--engine",
        choices=("sqlite", "postgresql", "both"),
        default="both",
        help="the database engine (default both, one after the other)",
    )
    parser.add_argument(
        "--steps",
        type=int,
        default=100_000,
        help="logged steps the fleet holds at least (default 100,000)",
    )
    parser.add_argument(
        "--candidate",
        action="append",
        metavar="ALGORITHM[:NAME=VALUE,...]",
        help="a learner to evaluate, as attune evaluate --candidate reads it; repeat for "
        f"several (default {' and '.join(DEFAULT_CANDIDATES)})",
    )
    parser.add_argument(
        "--tracemalloc",
        action="store_true",
        help="also run the evaluation under tracemalloc for the Python heap's peak (slower: "
        "a run of its own)",
    )
    parser.add_argument(
        "--max-minutes",
        type=float,
        default=60.0,
        help="stop the whole run after this, saying so (default 60)",
    )
    parser.add_argument(
        "--template-people",
        type=int,
        default=20,
        help="people who play through the API (default 20)",
    )
    parser.add_argument(
        "--template-episodes",
        type=int,
        default=2_000,
        help="episodes they play in all (default 2,000)",
    )
    parser.add_argument(
        "--template-robots", type=int, default=4, help="robots that play them (default 4)"
    )
    parser.add_argument(
        "--delay",
        type=float,
        help="PostgreSQL: ms each way between the measurements and the database",
    )
    parser.add_argument(
        "--seed", type=int, default=1, help="the template people's draws (default 1)"
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON document instead of the text"
    )
    args = parser.parse_args(argv)
    args.candidate = args.candidate or list(DEFAULT_CANDIDATES)
    try:
        specs = [parse_candidate(c) for c in args.candidate]
    except ValueError as exc:
        parser.error(str(exc))
    engines = ["sqlite", "postgresql"] if args.engine == "both" else [args.engine]
    if args.delay is not None and "sqlite" in engines:
        parser.error("--delay is for --engine postgresql")
    if args.template_people < 2 or args.template_episodes < args.template_people:
        parser.error("--template-people must be at least 2, with at least one episode each")
    if args.steps < 1 or args.max_minutes <= 0:
        parser.error("--steps must be at least 1, --max-minutes more than 0")
    before = machine()
    began = time.monotonic()
    deadline = began + args.max_minutes * 60
    doc: dict[str, Any] = {
        "machine": before,
        "command": " ".join(["bench/evaluation.py", *(sys.argv[1:] if argv is None else argv)]),
        "steps_requested": args.steps,
        "candidates": [s.key for s in specs],
        "labels": {s.key: s.label for s in specs},
        "max_minutes": args.max_minutes,
        "engines": {},
    }
    try:
        for engine in engines:
            if time.monotonic() > deadline:
                doc["engines"][engine] = {
                    "stopped": "--max-minutes reached before this engine",
                    "place": "not run",
                }
                continue
            with tempfile.TemporaryDirectory(prefix="attune-evaluation-") as tmp:
                doc["engines"][engine] = engine_run(engine, args, Path(tmp), deadline)
    except CloneRefused as failure:
        print(f"bench/evaluation.py: {failure}", file=sys.stderr)
        return 2
    for engine, found in doc["engines"].items():
        found["table"] = rows_of(doc, engine)
    doc["load_after"] = os.getloadavg()
    doc["minutes"] = (time.monotonic() - began) / 60
    if args.json:
        print(json.dumps(doc, indent=1, default=str))
    else:
        print(render(doc))
    if any(found["stopped"] for found in doc["engines"].values()):
        return 3
    checks = [found["check"]["ok"] for found in doc["engines"].values() if "check" in found]
    return 0 if all(checks) else 1


if __name__ == "__main__":
    sys.exit(main())
