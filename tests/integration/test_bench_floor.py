"""The service benchmark's floor (bench/floor.py): the statements it records are the service's
whole work on the database, so replaying them on a copy taken before leaves the copy as the
service left the original, row for row; the learner is timed; the service is left as it was."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine, inspect, text

from app.db.repositories import _rows
from app.learning.learners import base
from app.services.episodes import write
from tests.support.fixtures import engines
from tests.support.live import fresh_database

BENCH = Path(__file__).resolve().parents[2] / "bench"
pytestmark = pytest.mark.slow


def _rows_of(url: str) -> dict[str, list[tuple[str, ...]]]:
    """Every row of every table, as text, in a stable order."""
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            tables = inspect(conn).get_table_names()
            return {
                t: sorted(
                    tuple(str(v) for v in row) for row in conn.execute(text(f'SELECT * FROM "{t}"'))
                )
                for t in tables
            }
    finally:
        engine.dispose()


def _hooks() -> tuple[Any, ...]:
    return (
        _rows.Prepared._execute,
        base.TabularLearner.select_action,
        base.TabularLearner.update,
        vars(write)["rng_for"],
        vars(write)["batch"],
    )


@pytest.fixture(scope="module")
def bench_modules() -> Iterator[tuple[Any, Any]]:
    sys.path.insert(0, str(BENCH))
    try:
        import floor
        import service

        yield floor, service
    finally:
        sys.path.remove(str(BENCH))
        for name in ("floor", "service"):
            sys.modules.pop(name, None)


@pytest.mark.parametrize("engine", engines())
def test_replay_is_the_services_work_and_the_learner_is_timed(
    engine: str, tmp_path: Path, bench_modules: tuple[Any, Any]
) -> None:
    floor, service = bench_modules
    pg_server = service.PG_SERVER.rstrip("/")
    hooks = _hooks()
    with fresh_database(engine, tmp_path) as url:
        data = service.Data(url)
        try:
            found = floor.measure(
                engine, url, data, ["ann", "bob", "cyd"], 150, pg_server, group=3, keep_copy=True
            )
        finally:
            data.close()
        assert found.copy is not None
        try:
            original, replayed = _rows_of(url), _rows_of(found.copy)
        finally:
            floor.remove_copy(found.copy, pg_server)
    assert replayed == original
    assert len(original["episodes"]) > 2 * 3  # the recorded run's episodes are in both
    assert found.requests >= 150
    assert 3 <= found.statements_per_request <= 20  # a write's handful
    assert found.learner_ms > 0
    assert found.statements_ms > 0
    assert _hooks() == hooks


@pytest.mark.parametrize("engine", engines())
def test_the_copy_is_removed(engine: str, tmp_path: Path, bench_modules: tuple[Any, Any]) -> None:
    floor, service = bench_modules
    with fresh_database(engine, tmp_path) as url:
        data = service.Data(url)
        try:
            found = floor.measure(engine, url, data, ["ann"], 5, service.PG_SERVER.rstrip("/"))
        finally:
            data.close()
        assert found.copy is None
        if engine == "sqlite":
            assert not list(Path(url.removeprefix("sqlite:///")).parent.glob("*-floor.db*"))
        else:
            import psycopg

            name = url.rsplit("/", 1)[1] + "_floor"
            with psycopg.connect(f"{service.PG_SERVER.rstrip('/')}/postgres") as conn:
                found_dbs = conn.execute(
                    "SELECT 1 FROM pg_database WHERE datname = %s", (name,)
                ).fetchall()
            assert found_dbs == []
