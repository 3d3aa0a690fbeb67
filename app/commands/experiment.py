"""``attune experiment ...``: the paper's experiments and the studies built on them, run on
simulated people in worker processes; each writes a report into ``--out`` and prints its table.

Every command has the same shape: its options (the shared ones are defined once here), the
runs (:func:`_run_protocols` for the paper's protocols; the studies' own tasks with
:func:`_timed`), then the report (:func:`_report`): the files written, where they are, and the
summary as JSON (``--json``) or the table on stdout. The numbers and the files are
``app.experiments``'s; this module parses, runs and tells.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer

from ._extras import require
from ._help import Typer
from ._output import print_json, stderr_console, stdout_console

if TYPE_CHECKING:  # the commands import these when they run; --help needs none of them
    from rich.console import Console

    from app.learning import Mission
    from app.learning.evaluation import Method, Protocol

__all__ = ["experiment"]

T = TypeVar("T")

experiment = Typer(
    help="Reproduce the paper's experiments with simulated users (docs/method.md §12).\n\n"
    "Every run is seeded and deterministic: the same options give the same numbers, whatever "
    "--jobs is. Runs go to worker processes in parallel, with a progress bar.",
    no_args_is_help=True,
)

# -- the options the commands share -------------------------------------------------------------

SeedsOption = Annotated[
    int,
    typer.Option(
        "--seeds",
        min=1,
        help="Independent repetitions (seeds 0..N-1) per method and "
        "protocol; every repetition simulates --users users.",
    ),
]
SuiteSeedsOption = Annotated[
    int,
    typer.Option("--seeds", min=2, help="Seeds (0..N-1) per family; the intervals are over seeds."),
]
_JOBS_HELP = (
    # os.cpu_count() is app.experiments.runner.default_workers(), without importing the runner
    # (and numpy) for --help.
    f"Worker processes (default: one per CPU, {os.cpu_count() or 1} here). "
    "1 runs everything in this process."
)
JobsOption = Annotated[
    int | None, typer.Option("--jobs", "-j", min=1, show_default=False, help=_JOBS_HELP)
]
UsersOption = Annotated[int, typer.Option("--users", min=1, help="Simulated users per run.")]
UserOption = Annotated[
    list[str] | None,
    typer.Option(
        "--user",
        metavar="NAME=VALUE",
        show_default=False,
        help="Override a response parameter of every simulated user, e.g. "
        "--user p_self=0.2 --user eps_fb=0 (p_acc, p_self, eps_fb, p_abort, p_idle_acc; "
        "each in [0, 1]). Repeatable.",
    ),
]
FamiliesOption = Annotated[
    str | None,
    typer.Option(
        "--families",
        metavar="A,B",
        show_default=False,
        help="Families to run, separated by commas (default: all).",
    ),
]
OutOption = Annotated[
    Path,
    typer.Option("--out", "-o", help="Output folder (created if needed).", file_okay=False),
]
ProgressOption = Annotated[
    bool, typer.Option("--progress/--no-progress", help="Show a progress bar (on stderr).")
]
MissionOption = Annotated[
    Path | None,
    typer.Option(
        "--mission",
        metavar="FILE",
        show_default=False,
        dir_okay=False,
        help="The simulated users live in the mission in FILE (JSON, like "
        "docs/examples/care-home-mission.json: its situations, time slots, services "
        "and rewards) instead of the paper's office mission; the reports say so. The "
        "paper's numbers are targets for the office mission only.",
    ),
]
JsonOption = Annotated[
    bool,
    typer.Option(
        "--json",
        help="Print the summary (summary.json) on stdout instead of "
        "the table; messages and progress go to stderr as always.",
    ),
]


# -- parsing ------------------------------------------------------------------------------------


def _mission(console: Console, path: Path | None) -> Mission:
    """The mission of ``--mission FILE`` (the office mission without it); a file that is not a
    mission is one line on stderr and exit code 2."""
    from app.learning import MissionError, load_mission, office_mission

    if path is None:
        return office_mission()
    try:
        return load_mission(path)
    except MissionError as exc:
        console.print(f"[red]--mission:[/red] {exc}")
        raise typer.Exit(2) from None


def _document(world: Mission, path: Path | None) -> str | None:
    """The mission as the worker processes get it: canonical JSON; None for the office mission
    (``--mission`` not given)."""
    import json

    return None if path is None else json.dumps(world.to_dict(), sort_keys=True)


def _mission_info(world: Mission, path: Path | None) -> dict[str, Any]:
    """The mission of a run, as the summary names it."""
    return {
        "name": world.name,
        "file": None if path is None else str(path),
        "fingerprint": world.fingerprint,
    }


def _user_params(pairs: Sequence[str]) -> dict[str, float]:
    """Parse ``--user NAME=VALUE`` options, refusing unknown names and values outside [0, 1]."""
    from app.learning.simulation import UserProfile

    allowed = [f.name for f in dataclasses.fields(UserProfile) if f.name != "needs"]
    out: dict[str, float] = {}
    for pair in pairs:
        name, sep, raw = pair.partition("=")
        if not sep or name not in allowed:
            raise typer.BadParameter(
                f"{pair!r}: expected NAME=VALUE with NAME one of {', '.join(allowed)}.",
                param_hint="--user",
            )
        try:
            value = float(raw)
        except ValueError:
            value = float("nan")
        if not 0.0 <= value <= 1.0:
            raise typer.BadParameter(
                f"{pair!r}: the value must be a number in [0, 1].", param_hint="--user"
            )
        out[name] = value
    return out


def _names(raw: str | None, known: Sequence[str], default: Sequence[str], option: str) -> list[str]:
    """A comma-separated list of names out of ``known`` (``default`` when not given), in the
    order given, without repeats; an unknown name is a usage error naming the known ones."""
    if raw is None:
        return list(default)
    names = list(dict.fromkeys(n.strip() for n in raw.split(",") if n.strip()))
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise typer.BadParameter(
            f"{', '.join(map(repr, unknown)) or 'nothing'}: expected names out of "
            f"{', '.join(known)}, separated by commas.",
            param_hint=option,
        )
    return names


def _learners(methods: Sequence[Method]) -> dict[str, Any]:
    """The learners of a run, as the summary lists them."""
    return {m.label: {"algorithm": m.algorithm, "params": dict(m.params)} for m in methods}


# -- running ------------------------------------------------------------------------------------


def _plural(n: int, word: str, plural: str | None = None) -> str:
    """``1 seed``, ``2 seeds``; ``1 worker process``, ``2 worker processes``."""
    return f"{n} {word if n == 1 else (plural or word + 's')}"


def _run_protocols(
    console: Console,
    methods: Sequence[Method],
    protocols: Sequence[Protocol],
    seeds: int,
    users: int,
    jobs: int | None,
    progress: bool,
    what: str,
    user: Sequence[str] | None = None,
    mission_file: Path | None = None,
) -> tuple[list[Any], dict[str, Any]]:
    """Run methods x protocols x seeds, report how many runs and how long; returns the results
    and the run information for the summary."""
    from app.experiments.runner import default_workers, jobs_for, run_jobs

    user_params = _user_params(user or ())
    mission = _mission(console, mission_file)
    todo = jobs_for(
        methods, protocols, seeds, users, user_params, mission if mission_file is not None else None
    )
    workers = min(jobs or default_workers(), len(todo))
    if mission_file is not None:
        console.print(
            f"Mission {mission.name!r} from {mission_file} ({len(mission.situations)} "
            f"situations, {len(mission.time_slots)} time slots, "
            f"{len(mission.services)} services), not the paper's office mission."
        )
    console.print(
        f"{what}: {len(todo)} runs ({len(methods)} methods × {len(protocols)} protocols × "
        f"{_plural(seeds, 'seed')}, {_plural(users, 'user')} "
        f"each) on {_plural(workers, 'worker process', 'worker processes')}."
    )
    start = time.perf_counter()
    results = run_jobs(todo, workers, description=what, console=console, progress=progress)
    seconds = time.perf_counter() - start
    console.print(f"Finished {len(results)} runs in {seconds:.1f} s.")
    info = {
        "seeds": seeds,
        "users": users,
        "protocols": [p.name for p in protocols],
        "runs": len(results),
        "workers": workers,
        "user_params": user_params,
        "seconds": round(seconds, 2),
        "mission": {
            **_mission_info(mission, mission_file),
            "situations": len(mission.situations),
            "time_slots": len(mission.time_slots),
            "services": len(mission.services),
        },
    }
    return results, info


def _cpu_seconds() -> float:
    """CPU time of this process and of its ended children (the runner's worker processes), which
    the machine's other load does not inflate; NaN where the platform does not tell."""
    try:
        import resource
    except ImportError:  # not on Windows
        return float("nan")
    return sum(
        u.ru_utime + u.ru_stime
        for u in (
            resource.getrusage(resource.RUSAGE_SELF),
            resource.getrusage(resource.RUSAGE_CHILDREN),
        )
    )


@dataclasses.dataclass(frozen=True)
class Timing:
    """How long a study's runs took: wall and CPU seconds, and the machine's load average then
    (NaN where the platform does not tell)."""

    seconds: float
    cpu: float
    load: float

    def verdict(self, target: float, default: bool, what: str) -> str:
        """``met`` or ``missed`` for the default ``what`` (run, suite, map) against its target
        in seconds; ``not the default ...`` otherwise."""
        if not default:
            return f"not the default {what}"
        return "met" if self.seconds < target else "missed"


def _timed(run: Callable[[], T]) -> tuple[T, Timing]:
    """``run()``, and how long it took."""
    start, cpu_start = time.perf_counter(), _cpu_seconds()
    result = run()
    seconds, cpu = time.perf_counter() - start, _cpu_seconds() - cpu_start
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return result, Timing(seconds, cpu, load)


def _finished(
    console: Console, runs: int, timing: Timing, target: float, verdict: str, what: str
) -> None:
    """The line that says how long a study took, and whether the default met its target."""
    console.print(
        f"Finished {runs} runs in {timing.seconds:.1f} s, {timing.cpu:.1f} s of CPU time "
        f"(target for the default {what} on 2 CPUs: under {target:.0f} s; {verdict}; load "
        f"average {timing.load:.2f} on {os.cpu_count() or 1} CPUs)."
    )


# -- the report ---------------------------------------------------------------------------------


def _report(
    console: Console,
    out: Path,
    json_output: bool,
    write: Callable[[], tuple[dict[str, Any], list[Path]]],
    show: Callable[[dict[str, Any], Console], None],
) -> None:
    """Write the report (``write()``: the summary and the files), say where it is, then print
    the summary as JSON (``--json``) or ``show`` it on stdout."""
    start = time.perf_counter()
    summary, files = write()
    seconds = time.perf_counter() - start
    console.print(f"Wrote {len(files)} files to [bold]{out}[/bold] in {seconds:.1f} s:")
    for path in files:
        console.print(f"  {path}")
    if json_output:
        print_json(summary)
    else:
        show(summary, stdout_console())


def _needs_the_extra() -> None:
    require("matplotlib", "experiments", "attune experiment")


# -- the commands -------------------------------------------------------------------------------


@experiment.command(
    "paper",
    help="Run the paper's experiments E1/E2, E3 and PA for R-MAX, Q-learning, HRI τ=0.01, "
    "HRI τ=0.005 and DTS; write the figures and tables; print Table II.\n\n"
    "Writes into --out: fig2.png (cumulative reward, events 1-50 of E1/E2), fig3.png (events "
    "51-100, re-zeroed at the needs change), rewards.csv (every event of every run: protocol, "
    "method, seed, user, event, reward, initiated, interaction, success, queries), table2.md "
    "(Table II beside the paper's targets, and the 200-event PA per 100-event block), "
    "summary.json (all the numbers) and claims.md (each of the paper's qualitative claims, "
    "reproduced or not, with the numbers it was decided on).\n\n"
    "Takes about 30 s with the default 20 seeds on 2 CPUs (time grows linearly with --seeds "
    "and --users, and shrinks with more --jobs).",
)
def paper(
    seeds: SeedsOption = 20,
    out: OutOption = Path("results/paper"),
    jobs: JobsOption = None,
    users: UsersOption = 6,
    user: UserOption = None,
    mission: MissionOption = None,
    progress: ProgressOption = True,
    json_output: JsonOption = False,
) -> None:
    """Run E1/E2, E3 and PA for the paper's methods and write the reports."""
    _needs_the_extra()
    from app.experiments.outputs import write_paper_report
    from app.experiments.text import print_table2
    from app.learning.evaluation import E1E2, E3, PA, PAPER_METHODS

    console = stderr_console()
    results, info = _run_protocols(
        console,
        PAPER_METHODS,
        (E1E2, E3, PA),
        seeds,
        users,
        jobs,
        progress,
        "Paper experiments",
        user,
        mission,
    )
    _report(console, out, json_output, lambda: write_paper_report(results, out, info), print_table2)


@experiment.command(
    "ablation",
    help="Run the ablations of HRI τ=0.01 (exclusion, measure, adaptive τ, I1 weight, "
    "staleness, unknown values) on E3 and on the 200-event PA; write and print their table.\n\n"
    "Writes into --out: ablation.md (the metrics on E3 and per 100-event PA block), "
    "summary.json (all the numbers), pa_cumulative.png (cumulative reward over the PA run) and "
    "rewards.csv (every event of every run).\n\n"
    "Takes about 25 s with the default 20 seeds on 2 CPUs (time grows linearly with --seeds "
    "and --users, and shrinks with more --jobs).",
)
def ablation(
    seeds: SeedsOption = 20,
    out: OutOption = Path("results/ablation"),
    jobs: JobsOption = None,
    users: UsersOption = 6,
    user: UserOption = None,
    mission: MissionOption = None,
    progress: ProgressOption = True,
    json_output: JsonOption = False,
) -> None:
    """Run the HRI ablations on E3 and PA and write the reports."""
    _needs_the_extra()
    from app.experiments.outputs import write_ablation_report
    from app.experiments.text import print_metrics_table
    from app.learning.evaluation import ABLATION_METHODS, E3, PA

    console = stderr_console()
    results, info = _run_protocols(
        console,
        ABLATION_METHODS,
        (E3, PA),
        seeds,
        users,
        jobs,
        progress,
        "Ablations",
        user,
        mission,
    )

    def show(summary: dict[str, Any], stdout: Console) -> None:
        blocks = summary["protocols"][E3.name]["blocks"]
        print_metrics_table(
            blocks[f"1-{E3.n_events}"],
            summary["methods"],
            "Ablations on E3",
            stdout,
            with_paper=False,
        )

    _report(console, out, json_output, lambda: write_ablation_report(results, out, info), show)


@experiment.command(
    "robustness",
    help="Run every learner on families of simulated people and print, per family and "
    "learner, its reward as a share of the oracle's in the windows first 20 events, the 30 "
    "before the change, the 15 and 30 after it, the last 30, and all, and the 15 and 30 after "
    "the change as a share of the one-miss oracle's, with 95% intervals over seeds; then the "
    "changes each learner decided against the true ones, and the targets, met or missed "
    "(docs/method.md §12, Robustness).\n\n"
    "Families: paper (the paper's simulated users, whose routines drift), individual (routines "
    "and habits drawn per person), home (residents sharing most routines), abrupt (some "
    "routines switch at the change), gradual (some drift over 40 events), noisy (10-20% of "
    "answers random), shy (never speak first), refusing (often refuse an offer), many (6-9 "
    "routines); held out, run only when named: restless (5-8 routines, three changes). The "
    "windows about the change are blank for families without one. The oracle knows every "
    "need: it initiates, infers and performs when a need exists and the person is available, "
    "and passes otherwise; it meets the same events and answers as the learners. The one-miss "
    "oracle loses the first visit of each changed context after the change.\n\n"
    "Writes into --out: robustness.md (the table), robustness.csv (one row per family, learner "
    "and window), robustness.png (a heatmap of shares per window) and summary.json (every "
    "number, per seed too). Prints the elapsed time and whether the default suite met its "
    "target of under 2 minutes on 2 CPUs.",
)
def robustness(
    seeds: SuiteSeedsOption = 8,
    events: Annotated[
        int,
        typer.Option(
            "--events",
            min=20,
            help="Events per person; the changing families change at 5/8 of them (event 101 "
            "of 160).",
        ),
    ] = 160,
    persons: Annotated[
        int,
        typer.Option(
            "--persons", min=1, help="Simulated persons per family and seed (a home's residents)."
        ),
    ] = 3,
    families: FamiliesOption = None,
    learners: Annotated[
        str | None,
        typer.Option(
            "--learners",
            metavar="A,B",
            show_default=False,
            help="Learners to run, separated by commas, out of rmax, qlearning, hri (τ=0.01), "
            "hri-0.005, dts, dts-change, dts-change-0.05, dts-adapt and dts-routine (default: "
            "rmax,qlearning,hri,dts,dts-adapt,dts-routine).",
        ),
    ] = None,
    out: OutOption = Path("results/robustness"),
    jobs: JobsOption = None,
    mission: MissionOption = None,
    progress: ProgressOption = True,
    json_output: JsonOption = False,
) -> None:
    """Run the robustness suite and write its reports."""
    _needs_the_extra()
    from app.experiments import robustness as suite
    from app.experiments.runner import default_workers, run_tasks
    from app.learning.population import DEFAULT_FAMILIES, FAMILIES, change_event

    console = stderr_console()
    chosen = _names(families, list(FAMILIES), list(DEFAULT_FAMILIES), "--families")
    keys = _names(learners, list(suite.LEARNERS), suite.DEFAULT_LEARNERS, "--learners")
    methods = [suite.LEARNERS[k] for k in keys]
    world = _mission(console, mission)
    todo = suite.tasks_for(chosen, methods, seeds, persons, events, _document(world, mission))
    workers = min(jobs or default_workers(), len(todo))
    default = (seeds, events, persons, families, learners, mission) == (
        suite.DEFAULT_SEEDS,
        suite.DEFAULT_EVENTS,
        suite.DEFAULT_PERSONS,
        None,
        None,
        None,
    )
    if mission is not None:
        console.print(f"Mission {world.name!r} from {mission}, not the paper's office mission.")
    console.print(
        f"Robustness: {len(chosen)} families × {seeds} seeds × {persons} persons × {events} "
        f"events, {len(methods)} learners and the oracle; {len(todo)} runs on "
        f"{_plural(workers, 'worker process', 'worker processes')}."
    )
    runs, timing = _timed(
        lambda: run_tasks(
            suite.run_robust_task,
            todo,
            workers,
            description="Robustness",
            console=console,
            progress=progress,
            describe=suite.RobustTask.describe,
        )
    )
    verdict = timing.verdict(suite.TARGET_SECONDS, default, "suite")
    _finished(console, len(runs), timing, suite.TARGET_SECONDS, verdict, "suite")
    info = {
        "seeds": seeds,
        "persons": persons,
        "events": events,
        "change_at_event": change_event(events) + 1,
        "families": chosen,
        "learners": _learners(methods),
        "workers": workers,
        "seconds": round(timing.seconds, 2),
        "load_average": round(timing.load, 2),
        "target_seconds": suite.TARGET_SECONDS,
        "default_suite": default,
        "mission": _mission_info(world, mission),
    }
    summary = suite.build_summary(runs, chosen, [m.label for m in methods], events, info)

    def show(summary: dict[str, Any], stdout: Console) -> None:
        suite.print_table(summary, stdout)
        stdout.print(f"Elapsed: {timing.seconds:.1f} s ({verdict}).")

    _report(console, out, json_output, lambda: (summary, suite.write_report(summary, out)), show)


@experiment.command(
    "claims-map",
    help="Sweep the choices the paper left open and print, for each of its claims, the share "
    "of settings under which it holds, and the setting(s) under which most hold "
    "(docs/method.md §13, A map of the claims).\n\n"
    "The choices and their ranges, the default marked *: time slots per day 2, 4*, 8 "
    "(contexts: slots × 4 situations); users speak first p_self 0.2, 0.5*, 0.8; users' answer "
    "noise ν 0, 0.05*, 0.1 (accept an offer 1 − ν, refuse the right service ν); R-MAX's known "
    "threshold m 1, 2*, 4 and the value of its unknown pairs, Vmax × 1* or × 0.1; HRI's "
    "exclusion scope per_pair*, root_only, none; HRI's preference scale vmax*, raw. The "
    "default setting is what every other command runs; every other setting is a reading of "
    "the paper, not the paper.\n\n"
    "Each setting is decided on E1/E2 and E3 of the paper's four methods with --seeds seeds; "
    "each method variant runs once per world (time slots, p_self, ν), so the runs grow with "
    "the worlds, not with the settings. The default and the best settings are then decided "
    "again on held-out seeds (--confirm-seeds).\n\n"
    "Writes into --out: claims-map.md (the table), claims-map.csv (one row per setting: its "
    "values, the claims that hold, one 0/1 column per claim), claims-map.png (claims × settings, "
    "and the share of settings per value of each choice) and summary.json. Prints the table "
    "and the elapsed time and CPU time: the default map needs about 270 s of CPU time, about "
    "2.5 minutes on 2 idle CPUs (target: under 5); --quick, a reduced grid with 1 seed and 2 "
    "users, takes seconds.",
)
def claims_map(
    seeds: Annotated[
        int | None,
        typer.Option(
            "--seeds",
            min=1,
            show_default=False,
            help="Seeds (0..N-1) per setting; default 2 (1 with --quick).",
        ),
    ] = None,
    confirm_seeds: Annotated[
        int | None,
        typer.Option(
            "--confirm-seeds",
            min=0,
            show_default=False,
            help="Held-out seeds (the N after the sweep's) on which the default and the best "
            "settings are decided again; 0 skips it. Default 10 (2 with --quick).",
        ),
    ] = None,
    users: Annotated[
        int | None,
        typer.Option(
            "--users",
            min=1,
            show_default=False,
            help="Simulated users per run; default 6, as in the paper (2 with --quick).",
        ),
    ] = None,
    quick: Annotated[
        bool,
        typer.Option(
            "--quick",
            help="A reduced grid (time slots 2, 4; m 1, 2; exclusion per_pair, none; "
            "the other choices at their default) on 1 seed and 2 users: seconds, for checks.",
        ),
    ] = False,
    out: OutOption = Path("results/claims-map"),
    jobs: Annotated[
        int | None,
        typer.Option("--jobs", "-j", "--workers", min=1, show_default=False, help=_JOBS_HELP),
    ] = None,
    progress: ProgressOption = True,
    json_output: JsonOption = False,
) -> None:
    """Map the paper's claims over the reconstruction's open choices."""
    _needs_the_extra()
    from app.experiments import claims_map as cmap
    from app.experiments.runner import default_workers
    from app.learning.claims_map import AXES, Grid

    console = stderr_console()
    grid = Grid.quick() if quick else Grid.full()
    seeds = seeds or (cmap.QUICK_SEEDS if quick else cmap.DEFAULT_SEEDS)
    users = users or (cmap.QUICK_USERS if quick else cmap.DEFAULT_USERS)
    if confirm_seeds is None:
        confirm_seeds = 2 if quick else cmap.DEFAULT_CONFIRM_SEEDS
    settings = grid.settings()
    worlds = grid.worlds()
    variants = grid.methods()
    workers = jobs or default_workers()
    default = not quick and (seeds, confirm_seeds, users) == (
        cmap.DEFAULT_SEEDS,
        cmap.DEFAULT_CONFIRM_SEEDS,
        cmap.DEFAULT_USERS,
    )
    console.print(
        f"Claims map: {len(settings)} settings ("
        + " × ".join(f"{len(grid.values[a.key])} {a.key}" for a in AXES)
        + f") from {len(worlds)} worlds × {len(variants)} method variants × "
        f"{len(cmap.PROTOCOLS)} protocols × {_plural(seeds, 'seed')}, {_plural(users, 'user')} "
        f"each, on {_plural(workers, 'worker process', 'worker processes')}."
    )

    def sweep_and_confirm() -> tuple[Any, int, Any, int]:
        claim_map, runs = cmap.sweep(
            grid, seeds, users, workers, console=console, progress=progress
        )
        if not confirm_seeds:
            return claim_map, runs, None, 0
        chosen = cmap.confirmed_settings(claim_map)
        console.print(
            f"Held-out seeds {seeds}–{seeds + confirm_seeds - 1}: the default and "
            f"{len(chosen) - 1} best setting(s)."
        )
        confirmed, confirm_runs = cmap.confirm(
            chosen, seeds, confirm_seeds, users, workers, console=console, progress=progress
        )
        return claim_map, runs, confirmed, confirm_runs

    (claim_map, runs, confirmed, confirm_runs), timing = _timed(sweep_and_confirm)
    verdict = timing.verdict(cmap.TARGET_SECONDS, default, "map")
    _finished(console, runs + confirm_runs, timing, cmap.TARGET_SECONDS, verdict, "map")
    info = {
        "seeds": seeds,
        "users": users,
        "quick": quick,
        "settings": len(settings),
        "worlds": len(worlds),
        "method_variants": len(variants),
        "runs": runs,
        "confirm_seeds": confirm_seeds,
        "confirm_first_seed": seeds,
        "confirm_runs": confirm_runs,
        "workers": workers,
        "seconds": round(timing.seconds, 2),
        "cpu_seconds": round(timing.cpu, 2) if math.isfinite(timing.cpu) else None,
        "load_average": round(timing.load, 2),
        "target_seconds": cmap.TARGET_SECONDS,
        "default_map": default,
    }
    summary = cmap.build_summary(claim_map, confirmed, grid, info)

    def show(summary: dict[str, Any], stdout: Console) -> None:
        cmap.print_table(summary, stdout)
        stdout.print(f"Elapsed: {timing.seconds:.1f} s ({verdict}).")

    _report(console, out, json_output, lambda: (summary, cmap.write_report(summary, out)), show)


@experiment.command(
    "newcomers",
    help="Measure the fleet's prior for newcomers (docs/method.md §16): per family and "
    "learner, a new resident's reward as a share of the oracle's, fresh and from the prior of "
    "the other residents, in the first 20 events, events 21-100, after event 100 and all, with "
    "95% intervals over seeds and the paired difference; prints the issue's targets, met or "
    "missed.\n\n"
    "Leave-one-out, with common random numbers: for each family and seed, --residents persons "
    "are drawn (in home they share most routines); every learner runs fresh through each of "
    "them; then each person is run again, on the same events, coin flips and learner "
    "generator, from the prior built from the other residents' final learners. Targets, per "
    "learner: (a) home, from the prior, at least 80% of the oracle in the first 20 events; (b) "
    "individual, first 20 and all: the prior not below fresh; (c) every family, after event "
    "100: the prior not below fresh. Not below: the upper bound of the 95% interval of the "
    "per-seed difference (prior - fresh) is at least 0.\n\n"
    "Writes into --out: newcomers.md (the table and the targets), newcomers.csv (one row per "
    "family, learner, start and window), newcomers.png (the share per event, smoothed, fresh "
    "and from the prior) and summary.json (every number, per seed too). Prints the elapsed "
    "time; the default run takes under 2 minutes on 2 CPUs.",
)
def newcomers(
    seeds: SuiteSeedsOption = 8,
    residents: Annotated[
        int,
        typer.Option(
            "--residents",
            min=2,
            help="Persons per family and seed (a home's residents); each newcomer's prior "
            "has the other residents.",
        ),
    ] = 6,
    events: Annotated[int, typer.Option("--events", min=20, help="Events per person.")] = 160,
    families: Annotated[
        str | None,
        typer.Option(
            "--families",
            metavar="A,B",
            show_default=False,
            help="Families to run, separated by commas, out of the robustness suite's (default: "
            "home,individual).",
        ),
    ] = None,
    learners: Annotated[
        str | None,
        typer.Option(
            "--learners",
            metavar="A,B",
            show_default=False,
            help="Learners to run, separated by commas, by the robustness suite's names (default: "
            "the suite's default learners).",
        ),
    ] = None,
    strength: Annotated[
        float,
        typer.Option(
            "--strength",
            help="The prior's weight: pseudo-samples per pair that every contributor "
            "has evidence on (positive).",
        ),
    ] = 4.0,
    min_support: Annotated[
        int,
        typer.Option(
            "--min-support",
            min=1,
            help="The fewest contributors with evidence on a pair for it to enter the prior.",
        ),
    ] = 3,
    out: OutOption = Path("results/newcomers"),
    jobs: JobsOption = None,
    mission: MissionOption = None,
    progress: ProgressOption = True,
    json_output: JsonOption = False,
) -> None:
    """Run newcomers fresh and from the fleet's prior, and write the reports."""
    _needs_the_extra()
    from app.experiments import newcomers as study
    from app.experiments import robustness as suite
    from app.experiments.runner import default_workers, run_tasks
    from app.learning.population import FAMILIES

    if not strength > 0.0 or not math.isfinite(strength):
        raise typer.BadParameter(
            f"{strength!r}: must be a positive number.", param_hint="--strength"
        )
    console = stderr_console()
    chosen = _names(families, list(FAMILIES), study.DEFAULT_FAMILIES, "--families")
    keys = _names(learners, list(suite.LEARNERS), suite.DEFAULT_LEARNERS, "--learners")
    methods = [suite.LEARNERS[k] for k in keys]
    world = _mission(console, mission)
    todo = study.tasks_for(
        chosen,
        methods,
        seeds,
        residents,
        events,
        strength=strength,
        min_support=min_support,
        mission=_document(world, mission),
    )
    workers = min(jobs or default_workers(), len(todo))
    default = (seeds, residents, events, families, learners, strength, min_support, mission) == (
        study.DEFAULT_SEEDS,
        study.DEFAULT_RESIDENTS,
        study.DEFAULT_EVENTS,
        None,
        None,
        study.DEFAULT_STRENGTH,
        study.MIN_SUPPORT,
        None,
    )
    if mission is not None:
        console.print(f"Mission {world.name!r} from {mission}, not the paper's office mission.")
    if residents - 1 < min_support:
        console.print(
            f"Each newcomer has {residents - 1} contributors, fewer than "
            f"--min-support {min_support}: every prior is a fresh learner."
        )
    console.print(
        f"Newcomers: {len(chosen)} families × {seeds} seeds × {residents} residents × {events} "
        f"events, {len(methods)} learners fresh and from the prior, and the oracle; "
        f"{len(todo)} runs on {_plural(workers, 'worker process', 'worker processes')}."
    )
    runs, timing = _timed(
        lambda: run_tasks(
            study.run_newcomer_task,
            todo,
            workers,
            description="Newcomers",
            console=console,
            progress=progress,
            describe=study.NewcomerTask.describe,
        )
    )
    verdict = timing.verdict(suite.TARGET_SECONDS, default, "run")
    _finished(console, len(runs), timing, suite.TARGET_SECONDS, verdict, "run")
    info = {
        "seeds": seeds,
        "residents": residents,
        "events": events,
        "families": chosen,
        "learners": _learners(methods),
        "strength": strength,
        "min_support": min_support,
        "workers": workers,
        "seconds": round(timing.seconds, 2),
        "cpu_seconds": round(timing.cpu, 2),
        "load_average": round(timing.load, 2),
        "target_seconds": suite.TARGET_SECONDS,
        "default_run": default,
        "mission": _mission_info(world, mission),
    }
    summary = study.build_summary(runs, chosen, [m.label for m in methods], events, info)

    def show(summary: dict[str, Any], stdout: Console) -> None:
        study.print_table(summary, stdout)
        stdout.print(f"Elapsed: {timing.seconds:.1f} s, CPU time {timing.cpu:.1f} s ({verdict}).")

    _report(console, out, json_output, lambda: (summary, study.write_report(summary, out)), show)


@experiment.command(
    "what-if",
    help="Check the off-policy estimates of other learners against their truth (docs/method.md "
    "§17): fleets of simulated persons are served by one learner (--logger) and its decisions "
    "logged; every candidate is replayed over the logs and estimated by each estimator "
    "(per-decision importance sampling, its self-normalised form, doubly robust and its "
    "weighted form), with 95% "
    "intervals (bootstrap over persons, and an empirical Bernstein bound); and each candidate "
    "also serves the same persons, events and coin flips itself: its true value. Prints, per "
    "setting (episodes per fleet), candidate and estimator, the coverage of the intervals, "
    "bias, RMSE, width, effective sample size and the candidate's mass on actions the logger "
    "never takes; at the largest setting, how often two arms whose truths differ by 0.1 or more "
    "in a family of people are ranked right in that family's fleets (and how often the fleets' "
    "own truths order them so), in all and per family; the targets "
    "(coverage at least 93% for the default estimator; ranking at least 90%), met or missed."
    "\n\n"
    "Writes into --out: whatif.md (the table, the targets and the ranking by family), "
    "whatif.csv (one row per setting, arm, estimator and interval), whatif.png (coverage and "
    "RMSE per setting) and summary.json "
    "(every number). Prints the elapsed time; the default run's target is 5 minutes on 2 CPUs.",
)
def what_if(
    trials: Annotated[
        int, typer.Option("--trials", min=1, help="Fleets simulated, the families in turn.")
    ] = 200,
    persons: Annotated[
        int, typer.Option("--persons", min=2, help="Persons per fleet (the clusters).")
    ] = 10,
    sizes: Annotated[
        str,
        typer.Option(
            "--sizes",
            metavar="N,M",
            help="Episodes per fleet of each setting, separated by commas; each a multiple of "
            "--persons (each person's first N/persons events).",
        ),
    ] = "50,200,1000",
    logger: Annotated[
        str,
        typer.Option("--logger", help="The learner that serves the fleets and is logged."),
    ] = "hri",
    candidates: Annotated[
        str | None,
        typer.Option(
            "--candidates",
            metavar="A,B",
            show_default=False,
            help="The learners to estimate, separated by commas (default: hri-0.005, hri-0.1, "
            "dts). Known: hri, hri-0.005, hri-0.02, hri-0.1, dts, dts-adapt, dts-routine, "
            "qlearning, rmax.",
        ),
    ] = None,
    families: Annotated[
        str | None,
        typer.Option(
            "--families",
            metavar="A,B",
            show_default=False,
            help="Families of the robustness suite the fleets are drawn from, in turn (default: "
            "individual, home, abrupt, gradual, noisy, shy, refusing).",
        ),
    ] = None,
    truth_runs: Annotated[
        int,
        typer.Option(
            "--truth-runs",
            min=1,
            help="On-policy runs of each candidate averaged into its true value (its own "
            "draws differ between runs).",
        ),
    ] = 2,
    replay_value: Annotated[
        bool,
        typer.Option(
            "--replay-value",
            help="Also measure what the replay's approximation costs: before each logged "
            "event, a copy of each candidate as the replay has taught it serves the event "
            "itself; prints, per setting and candidate, that value against the truth and the "
            "default estimator's own error against it (adds about a third to the run's time).",
        ),
    ] = False,
    out: OutOption = Path("results/what-if"),
    jobs: JobsOption = None,
    mission: MissionOption = None,
    progress: ProgressOption = True,
    json_output: JsonOption = False,
) -> None:
    """Estimate other learners from one learner's logs, and check the estimates."""
    _needs_the_extra()
    from app.experiments import whatif as study
    from app.experiments.runner import default_workers, run_tasks
    from app.learning.population import FAMILIES

    console = stderr_console()
    try:
        settings = sorted({int(s) for s in sizes.split(",") if s.strip()})
    except ValueError:
        raise typer.BadParameter(
            f"{sizes!r}: numbers separated by commas.", param_hint="--sizes"
        ) from None
    if not settings or any(k < persons or k % persons for k in settings):
        raise typer.BadParameter(
            f"{sizes!r}: each must be a positive multiple of --persons ({persons}).",
            param_hint="--sizes",
        )
    known = list(study.CANDIDATES)
    if logger not in study.CANDIDATES:
        raise typer.BadParameter(f"{logger!r}: one of {', '.join(known)}.", param_hint="--logger")
    keys = _names(candidates, known, study.DEFAULT_CANDIDATES, "--candidates")
    chosen = _names(families, list(FAMILIES), study.DEFAULT_FAMILIES, "--families")
    world = _mission(console, mission)
    methods = [study.CANDIDATES[k] for k in keys if k != logger]
    todo = study.tasks_for(
        trials,
        persons,
        settings,
        study.CANDIDATES[logger],
        methods,
        chosen,
        truth_runs,
        _document(world, mission),
        replay_value,
    )
    workers = min(jobs or default_workers(), len(todo))
    default = (
        trials,
        persons,
        sizes,
        logger,
        candidates,
        families,
        truth_runs,
        mission,
        replay_value,
    ) == (
        study.DEFAULT_TRIALS,
        study.DEFAULT_PERSONS,
        ",".join(str(k) for k in study.DEFAULT_SIZES),
        study.DEFAULT_LOGGER,
        None,
        None,
        2,
        None,
        False,
    )
    console.print(
        f"What if: {trials} fleets of {persons} persons ({', '.join(chosen)} in turn), "
        f"{max(settings) // persons} events each, logged under {study.CANDIDATES[logger].label}; "
        f"{len(methods)} candidates replayed and run {truth_runs} times each on-policy; "
        f"on {_plural(workers, 'worker process', 'worker processes')}."
    )
    results, timing = _timed(
        lambda: run_tasks(
            study.run_trial,
            todo,
            workers,
            description="What if",
            console=console,
            progress=progress,
            describe=study.WhatIfTask.describe,
        )
    )
    verdict = timing.verdict(study.TARGET_SECONDS, default, "run")
    _finished(console, len(results), timing, study.TARGET_SECONDS, verdict, "run")
    info = {
        "trials": trials,
        "persons": persons,
        "families": chosen,
        "logger": _learners([study.CANDIDATES[logger]]),
        "candidates": _learners(methods),
        "truth_runs": truth_runs,
        "replay_value": replay_value,
        "workers": workers,
        "seconds": round(timing.seconds, 2),
        "cpu_seconds": round(timing.cpu, 2),
        "load_average": round(timing.load, 2),
        "target_seconds": study.TARGET_SECONDS,
        "time_target": verdict,
        "default_run": default,
        "mission": _mission_info(world, mission),
    }
    summary = study.build_summary(results, study.CANDIDATES[logger], methods, settings, info)

    def show(summary: dict[str, Any], stdout: Console) -> None:
        study.print_table(summary, stdout)
        stdout.print(f"Elapsed: {timing.seconds:.1f} s, CPU time {timing.cpu:.1f} s ({verdict}).")

    _report(console, out, json_output, lambda: (summary, study.write_report(summary, out)), show)
