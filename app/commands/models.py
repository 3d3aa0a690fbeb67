"""``attune models rebuild``: a user's model replayed from the history and compared with the
stored one."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from app.errors import AppError, NotFound

from ._setup import load_settings, open_database, tell

__all__ = ["models"]

models = typer.Typer(help="Users' learned models.", no_args_is_help=True)


@models.command("rebuild")
def models_rebuild(
    user_id: Annotated[str, typer.Argument(help="The user whose model to rebuild.")],
    save: Annotated[bool, typer.Option(help="Store the rebuilt model when it differs.")] = False,
) -> None:
    """Replay USER_ID's history into a fresh learner, redrawing every decision from the same seed
    stream, and compare with the stored model. Exit 0 when identical, 1 when not."""
    from app.services import audit
    from app.services.context import ServiceContext
    from app.services.models import rebuild_model

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    try:
        with open_database(settings) as database, database.transaction() as session:
            report = rebuild_model(session, ctx, audit.CLI, user_id, save=save)
    except NotFound:  # the command line sees every fleet: the user is not in the database
        tell(f"No user {user_id!r} in this database.", "red")
        raise typer.Exit(2) from None
    except AppError as exc:
        tell(exc.detail, "red")
        raise typer.Exit(2) from None
    summary = {
        "user_id": user_id, "version": report.version, "writes_replayed": report.writes,
        "samples_replayed": report.samples, "decisions_redrawn": report.decisions,
        "mismatched_decisions": report.mismatched_decisions, "identical": report.identical,
    }
    typer.echo(json.dumps(summary))
    if not report.identical:
        tell("The rebuilt model differs from the stored one."
             + (" Stored the rebuilt model." if save else ""), "red")
        raise typer.Exit(1)
    tell(f"Rebuilt {user_id}: identical to the stored model (version {report.version}).")
