"""The command line in the test's process: ``attune models rebuild``, as an operator runs it
against a database (the app's of a test, a live service's, a migrated release's).

``rebuild(database_url, user_id)`` runs the command itself (``app.cli``, through Typer's test
runner, with ``ATTUNE_DATABASE_URL`` and ``ATTUNE_SEED`` set as the service's) and returns its
exit code and its JSON summary line, so a test checks what the command says: ``identical``,
the writes and decisions replayed. ``rebuild_all(database_url)`` is ``--all``: every user of
every fleet, one JSON line each.
"""

from __future__ import annotations

import gc
import json
import warnings
from typing import Any, NamedTuple

__all__ = ["Rebuilt", "rebuild", "rebuild_all"]


class Rebuilt(NamedTuple):
    """What ``attune models rebuild`` said: its exit code (0 identical, 1 differs) and its JSON
    line (``fleet``, ``user_id``, ``version``, ``writes_replayed``, ``samples_replayed``,
    ``decisions_redrawn``, ``mismatched_decisions``, ``identical``)."""

    exit_code: int
    summary: dict[str, Any]


def rebuild(
    database_url: str,
    user_id: str,
    *,
    fleet: str | None = None,
    seed: int = 0,
    pooler: str = "none",
) -> Rebuilt:
    """``attune models rebuild USER_ID [--fleet FLEET]`` on the database at ``database_url``,
    with the deployment seed ``seed`` (the service's: the tests' services run with 0) and
    ``ATTUNE_DATABASE_POOLER=pooler`` (``transaction`` through PgBouncer)."""
    from typer.testing import CliRunner

    from app import cli

    where = [] if fleet is None else ["--fleet", fleet]
    result = CliRunner().invoke(
        cli.app,
        ["models", "rebuild", user_id, *where],
        env={
            "ATTUNE_DATABASE_URL": database_url,
            "ATTUNE_SEED": str(seed),
            "ATTUNE_DATABASE_POOLER": pooler,
        },
    )
    # The command leaves its engine's connections to the garbage collector (a process that ends
    # closes them); collect them here, quietly, rather than in whichever test runs next.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResourceWarning)
        gc.collect()
    lines = [line for line in result.stdout.splitlines() if line.startswith("{")]
    assert lines, (result.exit_code, result.output, result.exception)
    return Rebuilt(result.exit_code, json.loads(lines[-1]))


def rebuild_all(database_url: str, *, seed: int = 0) -> tuple[int, list[dict[str, Any]]]:
    """``attune models rebuild --all`` on the database at ``database_url``: its exit code (0
    when every model is identical) and its JSON lines, one per user."""
    from typer.testing import CliRunner

    from app import cli

    result = CliRunner().invoke(
        cli.app,
        ["models", "rebuild", "--all"],
        env={"ATTUNE_DATABASE_URL": database_url, "ATTUNE_SEED": str(seed)},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResourceWarning)
        gc.collect()
    lines = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    return result.exit_code, lines
