"""The ``attune`` command line.

One Typer app with a sub-app per area, each in its module of ``app.commands``: ``attune
experiment ...`` reproduces the paper's experiments and runs the studies built on them
(``experiment``); ``attune serve``, ``attune db ...``, ``attune keys ...``, ``attune models
...`` and ``attune missions ...`` run and administer the service (``serve``, ``db``, ``keys``,
``models``, ``missions``); ``attune fleet simulate`` plays simulated robots and people against a
running service (``fleet``); ``attune evaluate`` estimates, from a fleet's stored logs, what
other learners would have earned (``evaluate``).
"""

from __future__ import annotations

from typing import Annotated

import typer

from app.commands import db as db_commands
from app.commands import evaluate as evaluate_command
from app.commands import experiment as experiment_commands
from app.commands import fleet as fleet_commands
from app.commands import keys as keys_commands
from app.commands import missions as missions_commands
from app.commands import models as models_commands
from app.commands import people as people_commands
from app.commands import retention as retention_commands
from app.commands import serve as serve_command
from app.commands._help import MAX_WIDTH, Typer

__all__ = ["app", "main", "version"]

app = Typer(
    name="attune",
    help="Attune: preference learning for service robots. Learns what each person wants, and "
    "when, from their feedback.",
    no_args_is_help=True,
    add_completion=False,
    context_settings={"max_content_width": MAX_WIDTH},
)


def version() -> str:
    """The version of the installed ``attune`` distribution (``unknown`` when the code runs
    from a folder that was never installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as distribution_version

    try:
        return distribution_version("attune")
    except PackageNotFoundError:
        return "unknown"


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"attune {version()}")
        raise typer.Exit()


@app.callback()
def _options(
    show_version: Annotated[
        bool,
        typer.Option(
            "--version",
            callback=_print_version,
            is_eager=True,
            help="Print the version (attune X.Y.Z) and exit.",
        ),
    ] = False,
) -> None:
    """Options of ``attune`` itself, before the command."""


app.add_typer(experiment_commands.experiment, name="experiment")
app.command("serve")(serve_command.serve)
app.command("evaluate")(evaluate_command.evaluate)
app.add_typer(db_commands.db, name="db")
app.add_typer(keys_commands.keys, name="keys")
app.add_typer(models_commands.models, name="models")
app.add_typer(missions_commands.missions, name="missions")
app.add_typer(fleet_commands.fleet, name="fleet")
app.add_typer(retention_commands.retention, name="retention")
app.add_typer(people_commands.people, name="people")


def main() -> None:
    """Entry point of the ``attune`` console script."""
    app()
