"""No acknowledged write is lost or doubled: 32 robots against a real ``attune serve`` (SQLite
with 1 worker, PostgreSQL with 2), most of them on one hot user, with retries after lost
responses, duplicate sends and conflicting resends; then the history check. And the check can
fail: against a deliberately broken update path it reports the loss."""

from __future__ import annotations

import time

import httpx
import pytest
from sqlalchemy import create_engine, text

from app.db import migrate
from app.main import create_app
from app.services.person_model import PersonModel
from app.settings import Settings
from tests.support.fixtures import WorkerDatabases
from tests.support.live import LiveService, fresh_database, make_keys, serving

from .helpers import CASES, create_users, service_env
from .history import Workload, check_history

pytestmark = [pytest.mark.stress, pytest.mark.xdist_group("stress")]

CLIENTS = 32


@pytest.mark.parametrize(("engine", "workers"), CASES)
def test_no_acknowledged_write_lost_or_doubled(
    engine: str, workers: int, worker_databases: WorkerDatabases
) -> None:
    with (
        fresh_database(engine) as url,
        LiveService(
            url, workers=workers, env=service_env(engine, url, worker_databases)
        ) as service,
    ):
        keys = make_keys(url, CLIENTS)
        admin_key = make_keys(url, 1, role="admin")[0]
        with httpx.Client(
            base_url=service.url, timeout=60, headers={"Authorization": f"Bearer {admin_key}"}
        ) as api:
            workload = Workload(service.url, keys, episodes_per_client=5)
            initial = create_users(api, workload.all_users)
            began = time.monotonic()
            history = workload.run()
            driven = time.monotonic() - began
            findings = check_history(history, api, url, workload.all_users, initial, rebuild=True)
    replays = sum(a.replay for a in history.acks)
    print(
        f"\n{engine}/{workers}w: {len(history.acks)} acknowledgements ({replays} replays) "
        f"from {CLIENTS} robots in {driven:.1f} s"
    )
    assert findings == [], "\n".join(findings)
    assert replays >= 20  # the retries and duplicates did happen
    assert not history.unknown


def _in_process_run(url: str, *, clients: int = 8) -> tuple[list[str], Workload, str]:
    """A short run against the app in this process (so a test can patch it); the findings."""
    migrate.upgrade(url)
    settings = Settings(database_url=url, _env_file=None)  # type: ignore[call-arg]
    app = create_app(settings)
    keys = make_keys(url, clients)
    admin_key = make_keys(url, 1, role="admin")[0]
    try:
        with (
            serving(app) as base_url,
            httpx.Client(
                base_url=base_url, timeout=60, headers={"Authorization": f"Bearer {admin_key}"}
            ) as api,
        ):
            workload = Workload(base_url, keys, episodes_per_client=4, lost_response_rate=0.0)
            initial = create_users(api, workload.all_users)
            history = workload.run()
            return check_history(history, api, url, workload.all_users, initial), workload, base_url
    finally:
        app.state.db.dispose()


def test_the_check_reports_a_lost_model_update(monkeypatch: pytest.MonkeyPatch) -> None:
    """Break the update path: every 4th write is acknowledged, but its learning is not saved."""
    real = PersonModel.save  # what every write path calls
    calls = {"n": 0}

    def lossy_save(model: PersonModel) -> None:
        calls["n"] += 1
        if calls["n"] % 4 == 0:
            return  # the write's transitions never reach the model or the journal
        real(model)

    monkeypatch.setattr(PersonModel, "save", lossy_save)
    with fresh_database("sqlite") as url:
        findings, _, _ = _in_process_run(url)
    assert calls["n"] >= 8
    assert any("updates lost or doubled" in f for f in findings), findings
    assert any("journal holds" in f for f in findings), findings
    assert any("model visits differ from the history" in f for f in findings), findings


def test_the_check_reports_a_lost_acknowledged_write() -> None:
    """A clean run passes; then one acknowledged outcome and one episode vanish from storage."""
    with fresh_database("sqlite") as url:
        findings, workload, _ = _in_process_run(url)
        assert findings == [], "\n".join(findings)
        outcome = next(a for a in workload.history.acks if a.kind == "outcome")
        episode = next(
            a
            for a in workload.history.acks
            if a.kind == "episode"
            and a.response["episode_id"]
            not in {
                o.response["episode"]["episode_id"]
                for o in workload.history.acks
                if o.kind == "outcome" and o.key == outcome.key
            }
        )
        engine = create_engine(url)
        with engine.begin() as conn:
            conn.execute(
                text("UPDATE decisions SET response = NULL, outcome_hash = NULL WHERE id = :id"),
                {"id": outcome.key},
            )
            conn.execute(
                text("DELETE FROM episodes WHERE id = :id"), {"id": episode.response["episode_id"]}
            )
        engine.dispose()
        migrate_settings = Settings(database_url=url, _env_file=None)  # type: ignore[call-arg]
        app = create_app(migrate_settings)
        admin_key = make_keys(url, 1, role="admin")[0]
        try:
            with (
                serving(app) as base_url,
                httpx.Client(
                    base_url=base_url, timeout=60, headers={"Authorization": f"Bearer {admin_key}"}
                ) as api,
            ):
                after = check_history(
                    workload.history,
                    api,
                    url,
                    workload.all_users,
                    dict.fromkeys(workload.all_users, 0),
                )
        finally:
            app.state.db.dispose()
    assert any(f"outcome of {outcome.key} is not stored (lost)" in f for f in after), after
    assert any(
        f"{episode.key} ({episode.response['episode_id']}) is not stored (lost)" in f for f in after
    ), after
