"""``attune retention run``: fold the history older than each fleet's window into the people's
models and remove it (docs/privacy.md, "How long it is kept")."""

from __future__ import annotations

import datetime as dt
from typing import Annotated

import typer

from ._help import Typer
from ._output import print_json, stderr_console, stdout_console
from ._setup import load_settings, open_database

__all__ = ["retention"]

retention = Typer(help="Raw history kept for each fleet's window only.", no_args_is_help=True)

HELD = 3
"""The exit status of a run that found another holding the retention lease (nothing done)."""


@retention.command("run")
def retention_run(
    fleet: Annotated[
        str | None,
        typer.Option(
            help="Only this fleet (default: every fleet with a window).", show_default=False
        ),
    ] = None,
    batch: Annotated[
        int | None,
        typer.Option(
            min=1,
            max=100_000,
            help="Episodes or journal entries removed per transaction "
            "(default: ATTUNE_RETENTION_BATCH).",
            show_default=False,
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON document.")] = False,
    progress: Annotated[
        bool, typer.Option(help="Show a progress bar of the people done (on stderr).")
    ] = True,
) -> None:
    """Run retention once, now: for every fleet that set a window (PUT
    /v1/admin/fleets/{fleet}/history), fold each person's episodes received before the window
    into their model's base and their profile, then remove those episodes (with their
    decisions, answers and feedback) and the model's journal up to that point, a batch at a
    time. Models, decisions and profiles stay exactly as they were. Safe to run while robots
    work, to interrupt and to run again (the next run finishes the job). Run it from cron, for
    example every night, or let the service run it (ATTUNE_RETENTION_AT). One run at a time:
    a run takes the deployment's retention lease first; while another run (the service's or
    another command's) holds it, this one does nothing, says so and exits with status 3."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from app.services.context import ServiceContext
    from app.services.leases import LeaseHeld, LeaseLost
    from app.services.retention_runs import run_held

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    err = stderr_console()
    bar = Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err,
        disable=not progress or as_json,
    )
    task = bar.add_task("people", total=None)

    def advance(in_fleet: str, _user: str) -> None:
        bar.update(task, advance=1, description=f"people of {in_fleet}")

    try:
        with open_database(settings) as database:
            try:  # the bar once the lease is held: a run that finds it taken shows none
                report = run_held(
                    database,
                    ctx,
                    fleet=fleet,
                    batch=batch,
                    progress=advance,
                    started=lambda _lease: bar.start(),
                )
            finally:
                bar.stop()
    except LeaseHeld as held:
        err.print(
            f"Another retention run holds the lease ({held.holding()}): nothing was done. "
            "Run again once it is over.",
            markup=False,
        )
        raise typer.Exit(HELD) from None
    except LeaseLost as lost:
        err.print(
            f"The run stopped: {lost}; that run goes on from where this one stopped.",
            markup=False,
        )
        raise typer.Exit(1) from None
    if as_json:
        print_json(report.to_json())
        return
    if not report.fleets:
        err.print(
            "No fleet has a history window"
            + (f" named {fleet!r}" if fleet else "")
            + ": nothing to do (set one on the console's History kept page, or with PUT "
            "/v1/admin/fleets/{fleet}/history)."
        )
        return
    table = Table(
        "fleet",
        "days",
        "history kept from",
        "people",
        "folded",
        "episodes removed",
        "journal entries removed",
    )
    for f in report.fleets:
        table.add_row(
            f.fleet,
            str(f.days),
            f.kept_from.astimezone(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            str(f.people),
            str(f.folded),
            f"{f.episodes_removed:,}",
            f"{f.journal_removed:,}",
        )
    stdout_console().print(table)
    assert report.finished_at is not None
    seconds = (report.finished_at - report.started_at).total_seconds()
    skipped = sum(len(f.skipped) for f in report.fleets)
    err.print(
        f"Removed {report.episodes_removed:,} episodes and {report.journal_removed:,} journal "
        f"entries in {seconds:.1f} s."
        + (f" {skipped} people changed during the run; the next run folds them." if skipped else "")
    )
