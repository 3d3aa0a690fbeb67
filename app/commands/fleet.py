"""``attune fleet simulate``: simulated robots serving simulated people through a live service."""

from __future__ import annotations

import math
import secrets
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from ._extras import require
from ._help import Typer
from ._output import print_json, stderr_console, stdout_console

if TYPE_CHECKING:  # imported by the command when it runs (--help needs none of them)
    from attune_client import Client
    from rich.table import Table

    from app.fleet.simulate import FleetRun, Person
    from app.learning import Mission

__all__ = ["fleet"]

fleet = Typer(
    help="Simulated fleets: robots and people played against a live service.", no_args_is_help=True
)

TOLERANCE = 1e-9  # the robots' tally and the service's stats are the same sums


def _fmt(name: str, value: float | None) -> str:
    if value is None:
        return "-"
    if name in ("episodes", "missions"):
        return str(int(value))
    if name == "total_reward":
        return f"{value:.1f}"
    return f"{value:.3f}"


def _table(title: str, rows: dict[str, dict[str, Any]]) -> Table:
    from rich.table import Table

    from app.fleet.simulate import METRICS

    table = Table(title=title, title_justify="left")
    table.add_column("user", no_wrap=True, min_width=max(map(len, rows), default=4))
    heads = {
        "episodes": "episodes",
        "missions": "missions",
        "interaction_rate": "interaction",
        "success_rate": "success",
        "queries_per_mission": "queries/mission",
        "total_reward": "cum. reward",
    }
    for name in METRICS:
        table.add_column(heads[name], justify="right")
    for i, (user, stats) in enumerate(rows.items()):
        if i == len(rows) - 1:
            table.add_section()
        table.add_row(user, *(_fmt(k, stats.get(k)) for k in METRICS))
    return table


def _differences(service: dict[str, Any], local: dict[str, float | None]) -> list[str]:
    from app.fleet.simulate import METRICS

    found = []
    for k in METRICS:
        a, b = service.get(k), local.get(k)
        same = (a is None and b is None) or (
            a is not None and b is not None and math.isclose(a, b, rel_tol=0, abs_tol=TOLERANCE)
        )
        if not same:
            found.append(f"{k}: service {a}, robots {b}")
    return found


def _plot(path: Path, stats: dict[str, dict[str, Any]], change_at: int | None, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=120)
    for user, s in stats.items():
        curve = s["cumulative_reward"]
        ax.plot(range(len(curve)), curve, label=user, linewidth=1.4)
    if change_at is not None:
        ax.axvline(change_at, color="grey", linestyle="--", linewidth=1)
        ax.annotate(
            "needs change",
            (change_at, ax.get_ylim()[1]),
            textcoords="offset points",
            xytext=(4, -12),
            fontsize=8,
            color="grey",
        )
    ax.set_xlabel("episode")
    ax.set_ylabel("cumulative reward")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncols=2)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


@fleet.command("simulate")
def simulate(
    key: Annotated[
        str | None,
        typer.Option(
            envvar="ATTUNE_KEY",
            show_default=False,
            help="A robot (or staff or admin) API key (required; staff or admin with --mission, "
            "and to count the changes told to staff).",
        ),
    ] = None,
    url: Annotated[
        str, typer.Option(envvar="ATTUNE_URL", help="The service's base URL.")
    ] = "http://127.0.0.1:8000",
    robots: Annotated[int, typer.Option(min=1, max=64, help="Concurrent robots.")] = 4,
    users: Annotated[int, typer.Option(min=1, max=1000, help="Simulated people.")] = 6,
    events: Annotated[int, typer.Option(min=1, help="Events per person.")] = 200,
    change_at: Annotated[
        int | None,
        typer.Option(
            show_default=False,
            help="Event at which every person's needs change (about half of "
            "their rules move), as in the paper's second experiment. Default: no change.",
        ),
    ] = None,
    mission_file: Annotated[
        Path | None,
        typer.Option(
            "--mission",
            metavar="FILE",
            show_default=False,
            dir_okay=False,
            help=(
                "Before simulating, make the mission in FILE (JSON, like "
                "docs/examples/care-home-mission.json) the mission of the key's fleet, with a "
                "change_id derived from its content (running again with the same FILE changes "
                "nothing); the people are then drawn from it. Needs a staff or admin key. Every "
                "model of the fleet is carried to it and the fleet's open episodes are "
                "interrupted. Default: simulate the fleet's mission in force."
            ),
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seeds the people, their events and reactions.")] = 0,
    learner: Annotated[
        str,
        typer.Option(
            help="The learner the people are created with: dts-routine, dts-adapt, hri, dts, rmax "
            "or qlearning."
        ),
    ] = "dts-routine",
    prefix: Annotated[
        str | None,
        typer.Option(
            show_default=False,
            help="User ids are PREFIX-u1, PREFIX-u2, ... Default: fleet-SEED-"
            "<random>, so that runs never reuse each other's users.",
        ),
    ] = None,
    plot: Annotated[
        Path | None,
        typer.Option(
            show_default=False, help="Write a PNG of each person's cumulative reward here."
        ),
    ] = None,
    json_output: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the metrics (per user and overall, as the service reports them) "
            "as JSON on stdout instead of tables.",
        ),
    ] = False,
    progress: Annotated[
        bool, typer.Option("--progress/--no-progress", help="Show a progress bar.")
    ] = True,
    timeout: Annotated[float, typer.Option(min=0.1, help="Seconds per request.")] = 30.0,
    deadline: Annotated[
        float, typer.Option(min=1, help="Give up after this many seconds.")
    ] = 3600.0,
) -> None:
    """Simulated robots serve simulated people through the service at --url.

    Each robot is a thread with its own client; a person's events are played in order by
    whichever robot is free. The people are drawn from the fleet's mission in force, or from
    the one in --mission FILE, which is set first. At the end the paper's metrics (interaction
    rate, success rate, queries per mission, cumulative reward) are read back from the
    service's stats endpoint, per user and overall, and checked against the robots' own
    tally. With a staff or admin key, each person's changes told to staff are read back too
    and counted against the changes their needs really went through (caught, how late, false
    alarms, and the two detection targets); a robot key may not read them, which is said in
    one line. Exit code 1 if the stats differ or the run failed, 2 if the service cannot be
    used or FILE is not a mission.
    """
    require("attune_client", "fleet", "attune fleet")
    if not key:  # checked here, after the extra: what to install comes first
        sys.stderr.write("attune fleet simulate needs an API key: pass --key or set ATTUNE_KEY.\n")
        raise typer.Exit(2)
    if plot is not None:
        require("matplotlib", "fleet", "attune fleet simulate --plot")

    from attune_client import APIConnectionError, APIStatusError, Client
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from app.fleet.simulate import FleetError, PlayedEpisode, make_people, run_fleet
    from app.learning import Mission, MissionError, load_mission, space_for

    err = stderr_console()

    wanted: dict[str, Any] | None = None
    if mission_file is not None:
        try:  # the file is checked here, before anything is sent
            wanted = load_mission(mission_file).to_dict()
        except MissionError as exc:
            err.print(f"[red]--mission:[/red] {exc}")
            raise typer.Exit(2) from None

    prefix = prefix or f"fleet-{seed}-{secrets.token_hex(3)}"

    def client(robot_id: str | None = None) -> Client:
        return Client(
            url,
            key,
            timeout=timeout,
            headers={"User-Agent": f"attune-fleet/{robot_id}"} if robot_id else None,
        )

    try:
        with client() as setup:
            in_force = setup.mission()
            if wanted is not None:
                fleet_name = in_force.fleet or "default"
                changed = setup.set_mission(fleet_name, wanted)
                err.print(_mission_change_line(changed, mission_file, fleet_name))
                in_force = setup.mission()
                if in_force.fingerprint != changed.fingerprint:
                    err.print(
                        f"[red]The fleet's mission is not the one in {mission_file}:"
                        f"[/red] its change_id was used before, for a mission the fleet "
                        f"had from version {changed.version}. Set it with a new "
                        f"change_id (PUT /v1/admin/fleets/{fleet_name}/mission), then "
                        "run without --mission."
                    )
                    raise typer.Exit(2)
            mission = Mission.from_dict(in_force.document(), source=f"{url}/v1/mission")
            space = space_for(mission)
            people = make_people(
                mission, users=users, events=events, change_at=change_at, seed=seed, prefix=prefix
            )
            for person in people:
                setup.put_user(
                    person.user_id,
                    display_name=f"Simulated person {person.user_id}",
                    learner={"algorithm": learner},
                )
    except APIConnectionError as exc:
        err.print(f"[red]No service answers at {url}:[/red] {exc}")
        raise typer.Exit(2) from None
    except APIStatusError as exc:
        err.print(f"[red]The service refused ({exc.status_code} {exc.error}):[/red] {exc.detail}")
        raise typer.Exit(2) from None
    except (MissionError, ValueError) as exc:
        err.print(f"[red]Cannot simulate:[/red] {exc}")
        raise typer.Exit(2) from None

    total = users * events
    err.print(
        f"Mission {mission.name!r}: {len(mission.situations)} situations, "
        f"{len(mission.time_slots)} time slots, {len(mission.services)} services."
    )
    err.print(
        f"{robots} robots, {users} people ({prefix}-u1..u{users}), {events} events each"
        + (f", needs change at event {change_at}" if change_at is not None else "")
        + f", learner {learner}, seed {seed}, against {url}"
    )
    bar = Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        disable=not progress,
    )
    try:
        with bar:
            task = bar.add_task("episodes", total=total)

            def advance(_: PlayedEpisode) -> None:
                bar.advance(task)

            run = run_fleet(
                client, space, people, robots=robots, on_episode=advance, deadline_s=deadline
            )
    except FleetError as exc:
        err.print(f"[red]The fleet stopped:[/red] {exc}")
        raise typer.Exit(1) from None
    err.print(
        f"{run.played} episodes, {run.requests} requests in {run.elapsed_s:.1f} s "
        f"({run.requests / max(run.elapsed_s, 1e-9):.0f} requests/s)."
    )

    with client() as reader:
        stats = {p.user_id: reader.get_stats(p.user_id).model_dump() for p in people}
        late = None
        if change_at is not None:
            late = {
                p.user_id: reader.get_stats(p.user_id, last=events - change_at).model_dump()
                for p in people
            }
        changes = _count_changes(reader, mission, people, changed=change_at is not None)
    if not changes["counted"]:
        err.print(f"Changes were not counted: {changes['why']}", markup=False)
    _report(run, stats, late, changes, change_at, events, plot, json_output, learner)


def _count_changes(
    reader: Client, mission: Mission, people: list[Person], *, changed: bool
) -> dict[str, Any]:
    """Each person's changes told to staff, read through ``reader`` and counted against the
    person's true changes (``app.fleet.detection``); ``counted`` False, with ``why``, when the
    key may not read them (a robot key) or the service refuses to list them."""
    from attune_client import APIStatusError

    from app.fleet.detection import count_changes, detection_summary

    try:
        recorded = {p.user_id: list(reader.iter_changes(p.user_id, page_size=500)) for p in people}
    except APIStatusError as exc:
        refused = f"{exc.status_code} {exc.error}: {exc.detail}"
        if exc.status_code == 403:
            why = f"this key may not read them; a staff or admin key of the fleet may ({refused})"
        else:
            why = f"the service refused to list them ({refused})"
        return {"counted": False, "why": why}
    return detection_summary(count_changes(mission, people, recorded), changed=changed)


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f}%"


def _changes_table(changes: dict[str, Any]) -> Table:
    """The changes counted against the true ones, then the two targets, met or missed."""
    from rich.table import Table

    table = Table(
        title="Changes told to staff, counted against the people's true changes",
        title_justify="left",
    )
    table.add_column("detection", no_wrap=True)
    table.add_column("figure", justify="right", no_wrap=True)
    true = changes["true_changes"]
    late = (
        "-"
        if changes["median_events_late"] is None
        else f"{changes['median_events_late']:g} / {changes['max_events_late']}"
    )
    rate = changes["false_alarms_per_person_month"]
    rows = [
        ("true changes", str(true)),
        ("caught", f"{changes['caught']} ({_percent(changes['caught_share'])})"),
        (
            f"caught within {changes['within_visits']} visits of the changed context",
            f"{changes['caught_within']} ({_percent(changes['caught_within_share'])})",
        ),
        ("missed", str(changes["missed"])),
        ("events late (median / max)", late),
        ("false alarms", str(changes["false_alarms"])),
        (
            f"false alarms per person per {changes['events_per_month']} events",
            "-" if rate is None else f"{rate:.2f}",
        ),
        ("changes recorded", str(changes["recorded"])),
    ]
    for name, figure in rows:
        table.add_row(name, figure)
    table.add_section()
    for target in changes["targets"]:
        if target["met"] is None:
            verdict = f"not checked: {target['why']}"
        else:
            value = target["value"]
            shown = _percent(value) if target["name"] == "caught_within" else f"{value:.2f}"
            verdict = f"{shown}: {'met' if target['met'] else 'MISSED'}"
        table.add_row(f"target: {target['target']}", verdict)
    return table


def _mission_change_line(changed: Any, path: Path | None, fleet_name: str) -> str:
    """What setting --mission did, in one line."""
    if changed.replayed:
        return (
            f"The mission in {path} was set before (version {changed.version} of fleet "
            f"{fleet_name!r}); nothing changed."
        )
    if not changed.changed:
        return (
            f"Fleet {fleet_name!r} already has the mission in {path} (version {changed.version})."
        )
    return (
        f"Fleet {fleet_name!r} now has the mission in {path}: version {changed.version}, "
        f"{changed.users_moved} models carried to it, {changed.episodes_interrupted} open "
        "episodes interrupted."
    )


def _report(
    run: FleetRun,
    stats: dict[str, dict[str, Any]],
    late: dict[str, dict[str, Any]] | None,
    changes: dict[str, Any],
    change_at: int | None,
    events: int,
    plot: Path | None,
    json_output: bool,
    learner: str,
) -> None:
    from app.fleet.simulate import local_stats, overall_stats

    out, err = stdout_console(), stderr_console()
    tables = []
    rows: dict[str, dict[str, Any]] = {**stats, "all": overall_stats(list(stats.values()))}
    tables.append(_table("Metrics from the service's stats endpoint (docs/method.md §10)", rows))
    document: dict[str, Any] = {"users": stats, "overall": rows["all"]}
    if late is not None and change_at is not None:
        late_rows: dict[str, dict[str, Any]] = {**late, "all": overall_stats(list(late.values()))}
        tables.append(
            _table(
                f"Since the change: the last {events - change_at} episodes of each person",
                late_rows,
            )
        )
        document["since_change"] = {"users": late, "overall": late_rows["all"]}
    document["changes"] = changes
    if changes["counted"]:
        tables.append(_changes_table(changes))
    if json_output:
        print_json(document)
    else:
        for table in tables:
            out.print(table)

    mismatches = []
    for user_id, played in run.episodes.items():
        for line in _differences(stats[user_id], local_stats(played)):
            mismatches.append(f"{user_id} {line}")
    if mismatches:
        err.print("[red]The service's stats differ from what the robots saw:[/red]")
        for line in mismatches:
            err.print(f"  {line}")
    else:
        err.print("The service's stats equal the robots' own tally for every user.")
    if plot is not None:
        _plot(
            plot, stats, change_at, f"Cumulative reward per person ({learner}, {run.robots} robots)"
        )
        err.print(f"Plot written to {plot}")
    if mismatches:
        raise typer.Exit(1)
