"""The service benchmark's floor (bench/floor.py): the statements it records are the service's
whole work on the database, so replaying them on a copy taken before leaves the copy as the
service left the original; the learner is timed; the service is left as it was."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine, text

from app.db.repositories import _rows
from app.learning.learners import base
from app.services.episodes import write
from tests.support.fixtures import engines
from tests.support.live import fresh_database

BENCH = Path(__file__).resolve().parents[2] / "bench"
pytestmark = pytest.mark.slow

# What the robots' writes change: the rows and the counters that must come out the same.
STATE = {
    "episodes": "SELECT count(*), coalesce(sum(total_reward), 0), "
                "sum(CASE WHEN status = 'closed' THEN 1 ELSE 0 END) FROM episodes",
    "decisions": "SELECT count(*), sum(CASE WHEN answered_at IS NULL THEN 0 ELSE 1 END), "
                 "coalesce(sum(action), 0) FROM decisions",
    "users": "SELECT user_id, episode_count, draws FROM users ORDER BY user_id",
    "models": "SELECT user_pk, version, state FROM learner_models ORDER BY user_pk",
    "samples": "SELECT count(*), coalesce(sum(reward), 0) FROM samples",
}


def _state(url: str) -> dict[str, Any]:
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            return {name: [tuple(row) for row in conn.execute(text(sql))]
                    for name, sql in STATE.items()}
    finally:
        engine.dispose()


@pytest.fixture(scope="module")
def bench_modules() -> Any:
    sys.path.insert(0, str(BENCH))
    try:
        import floor
        import service
        yield floor, service
    finally:
        sys.path.remove(str(BENCH))


@pytest.mark.parametrize("engine", engines())
def test_replay_is_the_services_work_and_the_learner_is_timed(
        engine: str, tmp_path: Path, bench_modules: Any) -> None:
    floor, service = bench_modules
    originals = (_rows.Prepared._execute, base.TabularLearner.select_action,
                 base.TabularLearner.update, vars(write)["rng_for"])
    with fresh_database(engine, tmp_path) as url:
        data = service.Data(url)
        try:
            found = floor.measure(engine, url, data, ["ann", "bob", "cyd"], 150,
                                  service.PG_SERVER.rstrip("/"), keep_copy=True)
        finally:
            data.close()
        assert found.copy is not None
        try:
            assert _state(found.copy) == _state(url)
            assert _state(url)["episodes"][0][0] > 3 * 2  # the recorded run's episodes are in
        finally:
            if engine == "sqlite":
                Path(found.copy.removeprefix("sqlite:///")).unlink()
            else:
                floor._drop_postgresql(service.PG_SERVER.rstrip("/"),
                                       found.copy.rsplit("/", 1)[1])
    assert found.requests >= 150
    assert 3 <= found.statements <= 20  # a write's handful, not a session's bookkeeping
    assert found.learner_ms > 0
    assert found.statements_ms > 0
    assert (_rows.Prepared._execute, base.TabularLearner.select_action,
            base.TabularLearner.update, vars(write)["rng_for"]) == originals
