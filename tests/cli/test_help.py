"""``attune --version``, and ``--help`` without the heavy imports.

Help must come fast, so building the command line and printing the help of every command
imports none of the libraries the commands use when they run (how fast it is, bench/cli.py
measures; here we check what it imports, which does not depend on the machine).
"""

from __future__ import annotations

import importlib.metadata
import json
import subprocess
import sys
from importlib.metadata import version

import pytest
from typer.testing import CliRunner

from app.cli import app

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

    done = CliRunner().invoke(app, ["experiment", "paper", "--help"], env={"COLUMNS": "300"})
    assert done.exit_code == 0
    assert f"one per CPU, {default_workers()} here" in done.stdout
