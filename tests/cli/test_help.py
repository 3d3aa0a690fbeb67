"""``attune --version``, and ``--help``: without the heavy imports, and readable.

Help must come fast, so building the command line and printing the help of every command
imports none of the libraries the commands use when they run (how fast it is, bench/cli.py
measures; here we check what it imports, which does not depend on the machine).

The help of every command, at a normal terminal's width (80 and 120 columns), says what its
source says: each paragraph whole, wrapped only at spaces (never inside a path or an option's
name), no value shown for a flag (``--json <bool>``), nothing cut (``…``), no line wider than
the page but for a single long word.
"""

from __future__ import annotations

import importlib.metadata
import inspect
import json
import os
import subprocess
import sys
from collections.abc import Iterator
from importlib.metadata import version
from typing import Any

import pytest
import typer.main
from typer.testing import CliRunner

from app.cli import app
from app.commands._help import MAX_WIDTH

HEAVY = (
    "numpy",
    "sqlalchemy",
    "alembic",
    "fastapi",
    "starlette",
    "uvicorn",
    "matplotlib",
    "attune_client",
    "httpx",
    "psycopg",
    "prometheus_client",
    "jinja2",
    "app.learning",
    "app.db.session",
    "app.db.migrate",
    "app.settings",
    "app.services",
    "app.fleet",
    "app.experiments",
    "rich.progress",
)

# In a fresh interpreter: build the command line as the `attune` script does, print the help of
# every command, and list the heavy modules that got imported on the way.
WALK = f"""
import contextlib, io, json, sys
import typer.main
from app.cli import app

def paths(command, path=()):
    found = [path]
    if hasattr(command, "list_commands"):
        context = command.context_class(command, info_name="attune")
        for name in command.list_commands(context):
            found += paths(command.get_command(context, name), (*path, name))
    return found

helped = []
for path in paths(typer.main.get_command(app)):
    with contextlib.redirect_stdout(io.StringIO()) as out:
        try:
            app([*path, "--help"], prog_name="attune")
        except SystemExit as exit:
            assert exit.code == 0, (path, exit.code)
    assert "Usage: attune" in out.getvalue(), path
    helped.append(" ".join(path))
heavy = sorted(m for m in sys.modules if any(m == h or m.startswith(h + ".") for h in {HEAVY!r}))
print(json.dumps({{"helped": helped, "heavy": heavy}}))
"""


def test_version_is_the_installed_distributions() -> None:
    done = CliRunner().invoke(app, ["--version"])
    assert done.exit_code == 0
    assert done.stdout == f"attune {version('attune')}\n"


def test_version_when_the_code_was_never_installed(monkeypatch: pytest.MonkeyPatch) -> None:
    def not_installed(name: str) -> str:
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    done = CliRunner().invoke(app, ["--version"])
    assert done.exit_code == 0
    assert done.stdout == "attune unknown\n"


def test_help_of_every_command_imports_nothing_heavy() -> None:
    done = subprocess.run(
        [sys.executable, "-c", WALK], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert {
        "",
        "serve",
        "experiment paper",
        "experiment ablation",
        "experiment robustness",
        "db upgrade",
        "keys list",
        "keys revoke",
        "models rebuild",
        "fleet simulate",
    } <= set(report["helped"])
    assert report["heavy"] == []


def test_the_jobs_default_in_the_help_is_the_runners() -> None:
    from app.experiments.runner import default_workers

    done = CliRunner().invoke(app, ["experiment", "paper", "--help"], env={"COLUMNS": "80"})
    assert done.exit_code == 0
    assert f"one per CPU, {default_workers()} here" in " ".join(done.stdout.split())


def _commands(command: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], Any]]:
    """Every command and group under ``command`` (itself first), with its path."""
    yield path, command
    if hasattr(command, "list_commands"):
        context = command.context_class(command, info_name="attune")
        for name in command.list_commands(context):
            yield from _commands(command.get_command(context, name), (*path, name))


COMMANDS = list(_commands(typer.main.get_command(app)))


def _said(text: str | None) -> list[str]:
    """The paragraphs of a help text as its source has them, each on one line."""
    return [" ".join(p.split()) for p in inspect.cleandoc(text or "").split("\n\n") if p.strip()]


def _expected(path: tuple[str, ...], command: Any) -> list[str]:
    """What the page of ``command`` must say, whole: its paragraphs, each parameter's help (its
    own words, then the default or range Typer adds), and each subcommand's first paragraph."""
    context = command.context_class(command, info_name=" ".join(("attune", *path)))
    texts = _said(command.help)
    for param in command.get_params(context):
        record = param.get_help_record(context)
        if record is not None:
            texts.append(" ".join(record[1].split()))
    if hasattr(command, "list_commands"):
        for name in command.list_commands(context):
            texts += _said(command.get_command(context, name).help)[:1]
    return texts


# In a fresh interpreter whose terminal is COLUMNS wide (not the test runner, which forces its
# own width): the help page of every command, by path.
PAGES = """
import contextlib, io, json, sys
import typer.main
from app.cli import app

def paths(command, path=()):
    found = [path]
    if hasattr(command, "list_commands"):
        context = command.context_class(command, info_name="attune")
        for name in command.list_commands(context):
            found += paths(command.get_command(context, name), (*path, name))
    return found

pages = {}
for path in paths(typer.main.get_command(app)):
    with contextlib.redirect_stdout(io.StringIO()) as out:
        try:
            app([*path, "--help"], prog_name="attune")
        except SystemExit as exit:
            assert exit.code == 0, (path, exit.code)
    pages[" ".join(path)] = out.getvalue()
print(json.dumps(pages))
"""


@pytest.fixture(scope="module", params=[80, 120])
def pages(request: pytest.FixtureRequest) -> tuple[int, dict[str, str]]:
    """(the terminal's columns, the help page of every command at that width)."""
    columns: int = request.param
    done = subprocess.run(
        [sys.executable, "-c", PAGES],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "COLUMNS": str(columns)},
    )
    assert done.returncode == 0, done.stderr
    return columns, json.loads(done.stdout)


@pytest.mark.parametrize(
    ("path", "command"), COMMANDS, ids=[" ".join(p) or "attune" for p, _ in COMMANDS]
)
def test_help_says_what_the_source_says(
    pages: tuple[int, dict[str, str]], path: tuple[str, ...], command: Any
) -> None:
    columns, found = pages
    page = found[" ".join(path)]
    assert page.startswith(f"Usage: {' '.join(('attune', *path))} ")
    assert "<bool>" not in page  # a flag takes no value
    assert "…" not in page  # nothing cut
    width = min(columns, MAX_WIDTH) - 2  # Click's page: the terminal's width less 2
    for line in page.splitlines():
        assert len(line) <= width or len(line.split()) == 1, line
    flowing = " ".join(page.split())
    for text in _expected(path, command):
        assert text in flowing  # whole, wrapped only at spaces


def test_help_takes_the_terminals_width(pages: tuple[int, dict[str, str]]) -> None:
    columns, found = pages
    widest = max(len(line) for page in found.values() for line in page.splitlines())
    assert min(columns, MAX_WIDTH) - 12 < widest <= min(columns, MAX_WIDTH) - 2


def test_a_group_without_its_command_shows_its_help() -> None:
    done = CliRunner().invoke(app, ["experiment"], env={"COLUMNS": "80"})
    assert done.exit_code == 2  # a usage error, as Click has it
    assert "Usage: attune experiment [OPTIONS] COMMAND [ARGS]..." in done.output
    assert "claims-map" in done.output
