"""``attune models rebuild`` and ``attune models snapshot``: users' models checked against their
history, and their learner states stored."""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer

from app.errors import AppError, NotFound

from ._help import Typer
from ._setup import load_settings, open_database, tell

__all__ = ["models"]

models = Typer(help="Users' learned models.", no_args_is_help=True)

UserArg = Annotated[
    str | None, typer.Argument(help="The user (its id in its fleet).", show_default=False)
]
FleetOption = Annotated[
    str | None,
    typer.Option(
        help="The user's fleet; needed only when the id is in several fleets.", show_default=False
    ),
]
AllOption = Annotated[bool, typer.Option("--all", help="Every user of every fleet.")]


def _targets(
    session: Any, user_id: str | None, fleet: str | None, every: bool
) -> list[tuple[str, str]]:
    """(fleet, user id) pairs the command is about; exit 2 with a sentence if none fits."""
    from app.services.models import every_user, fleets_with

    if every:
        if user_id is not None or fleet is not None:
            tell("Give a user, or --all, not both.", "red")
            raise typer.Exit(2)
        return every_user(session)
    if user_id is None:
        tell("Give a user id, or --all.", "red")
        raise typer.Exit(2)
    if fleet is not None:
        return [(fleet, user_id)]
    found = fleets_with(session, user_id)
    if not found:
        tell(f"No user {user_id!r} in this database.", "red")
        raise typer.Exit(2)
    if len(found) > 1:
        tell(f"User id {user_id!r} is in several fleets ({', '.join(found)}): pass --fleet.", "red")
        raise typer.Exit(2)
    return [(found[0], user_id)]


@models.command("rebuild")
def models_rebuild(
    user_id: UserArg = None,
    fleet: FleetOption = None,
    every: AllOption = False,
    save: Annotated[bool, typer.Option(help="Store the rebuilt model when it differs.")] = False,
) -> None:
    """Replay a user's history into a fresh learner (or the imported model it started from),
    redrawing every decision from the same seed stream, and compare with the stored model.
    Prints one JSON line per user. Exit 0 when every model is identical, 1 when one is not."""
    from app.services import audit
    from app.services.context import ServiceContext
    from app.services.models import rebuild_model

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    differ = 0
    with open_database(settings) as database:
        with database.transaction(write=False) as session:
            targets = _targets(session, user_id, fleet, every)
        for in_fleet, uid in targets:
            try:
                with database.transaction() as session:
                    report = rebuild_model(session, ctx, audit.CLI, uid, save=save, fleet=in_fleet)
            except NotFound:
                tell(f"No user {uid!r} in fleet {in_fleet!r}.", "red")
                raise typer.Exit(2) from None
            except AppError as exc:
                tell(exc.detail, "red")
                raise typer.Exit(2) from None
            typer.echo(
                json.dumps(
                    {
                        "fleet": in_fleet,
                        "user_id": uid,
                        "version": report.version,
                        "writes_replayed": report.writes,
                        "samples_replayed": report.samples,
                        "decisions_redrawn": report.decisions,
                        "mismatched_decisions": report.mismatched_decisions,
                        "identical": report.identical,
                    }
                )
            )
            if not report.identical:
                differ += 1
                tell(
                    f"{in_fleet}/{uid}: the rebuilt model differs from the stored one."
                    + (" Stored the rebuilt model." if save else ""),
                    "red",
                )
    if differ:
        raise typer.Exit(1)
    if len(targets) == 1:
        tell(f"Rebuilt {targets[0][1]}: identical to the stored model (version {report.version}).")
    else:
        tell(f"Rebuilt {len(targets)} users: every one identical to its stored model.")


@models.command("snapshot")
def models_snapshot(
    user_id: UserArg = None,
    fleet: FleetOption = None,
    every: AllOption = False,
) -> None:
    """Store users' learner states as of their current versions (the service stores them every
    ATTUNE_SNAPSHOT_EVERY versions and replays the journal since). Needed before downgrading
    the database below the revision that brought snapshots in. The models do not change."""
    from app.services import audit
    from app.services.context import ServiceContext
    from app.services.models import snapshot_model

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    stored = 0
    with open_database(settings) as database:
        with database.transaction(write=False) as session:
            targets = _targets(session, user_id, fleet, every)
        for in_fleet, uid in targets:
            with database.transaction() as session:
                stored += snapshot_model(session, ctx, audit.CLI, uid, fleet=in_fleet)
    tell(f"Stored {stored} learner state(s); {len(targets) - stored} were current already.")
