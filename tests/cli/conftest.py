"""Fixtures of the command line's tests: a runner of ``attune`` in this process, on the shared
databases (``tests/support/fixtures.py``: every test that touches the database runs on SQLite
and on PostgreSQL), whose output is not a terminal (as in ``attune keys list | cat``)."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from typer.testing import CliRunner, Result

from app.cli import app

Attune = Callable[..., Result]


@pytest.fixture
def attune(database_url: str, empty_tables: None) -> Attune:
    """``attune(*args)``: the command line on the test's (empty) database; stdout and stderr
    apart, at 40 columns, so that anything still cut to the terminal's width shows."""

    def run(*args: str) -> Result:
        runner = CliRunner(env={"ATTUNE_DATABASE_URL": database_url, "COLUMNS": "40"})
        return runner.invoke(app, list(args))

    return run
