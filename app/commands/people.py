"""``attune people export`` and ``attune people import``: a person taken from one deployment
to another, history included (docs/api.md, "A person's export" and "A person's import")."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from app.errors import AppError

from ._help import Typer
from ._output import print_json, stdout_console
from ._setup import load_settings, open_database, tell

__all__ = ["people"]

people = Typer(
    help="A person's data, taken out of a deployment and put into another.", no_args_is_help=True
)

FleetOption = Annotated[str, typer.Option(help="The person's fleet.", show_default=True)]


@people.command("export")
def people_export(
    user_id: Annotated[str, typer.Argument(help="The person (their id in the fleet).")],
    fleet: FleetOption = "default",
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            help="Write the document to this file (default: standard output).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Everything stored about a person, as the API's GET /v1/users/{id}/export gives it: one
    JSON document, written as it is read (a page of episodes at a time), audited as an export
    by the command line."""
    from app.services import audit, subject
    from app.services.context import ServiceContext

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    with open_database(settings) as database:
        try:
            with database.transaction() as session:
                started = subject.begin_export(session, ctx, audit.CLI, user_id, fleet=fleet)
        except AppError as exc:
            tell(exc.detail, "red")
            raise typer.Exit(2) from None
        out = sys.stdout.buffer if output is None else output.open("wb")
        try:
            for piece in started.stream(database, ctx):
                out.write(piece)
        finally:
            if output is not None:
                out.close()
    if output is not None:
        tell(f"Exported {started.episodes:,} episodes of {fleet}/{user_id} to {output}.")


@people.command("import")
def people_import(
    file: Annotated[
        Path,
        typer.Argument(help="A person's export (attune.subject).", exists=True, dir_okay=False),
    ],
    fleet: FleetOption = "default",
    user_id: Annotated[
        str | None,
        typer.Option(
            "--user-id", help="Import under this id (default: the id they had).", show_default=False
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON document.")] = False,
) -> None:
    """Put a person back from their export (of this or another deployment) into a fleet:
    who they are, their learner and model, every episode with its decisions, answers and
    feedback, their corrections, their part in the prior, and what retention had folded. The
    fleet must have the missions their history ran under. One transaction: the person appears
    whole, or not at all; the document is read as a stream. Audited as user.import. Exit 2 with
    one sentence when it cannot be imported (the id exists: give --user-id)."""
    from app.services import audit
    from app.services.context import ServiceContext
    from app.services.subject_import import import_subject

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    with open_database(settings) as database, file.open("rb") as source:
        try:
            with database.transaction() as session:
                done = import_subject(session, ctx, audit.CLI, source, fleet=fleet, user_id=user_id)
        except AppError as exc:
            tell(exc.detail, "red")
            raise typer.Exit(2) from None
    if as_json:
        print_json(done.to_json())
        return
    stdout_console().print(
        f"Imported {done.fleet}/{done.user_id}: {done.episodes:,} episodes, "
        f"{done.decisions:,} decisions, {done.feedback:,} feedback, "
        f"{done.corrections} corrections; model version {done.model_version}."
    )
