"""``attune retention run`` on both engines: it takes the retention lease, does nothing and
exits 3 while another run (the service's, another command's) holds it, and lets it go when it
is done."""

from __future__ import annotations

import datetime as dt
import json

from fastapi import FastAPI

from app.db.repositories import leases as leases_repo
from app.db.session import Database
from app.services import leases, retention
from app.services.context import Principal
from app.services.retention_runs import LEASE

from .conftest import Attune


def _window(app: FastAPI, days: int) -> None:
    staff = Principal("key_staff", "staff", "default")
    with app.state.db.transaction() as session:
        retention.set_history(session, app.state.ctx, staff, "default", days=days)


def test_nothing_to_do_without_a_window(attune: Attune) -> None:
    done = attune("retention", "run")
    assert done.exit_code == 0, done.output
    assert "No fleet has a history window: nothing to do" in done.stderr
    assert done.stdout == ""


def test_a_run_while_another_holds_the_lease_does_nothing_and_exits_3(
    attune: Attune, app: FastAPI, db: Database
) -> None:
    _window(app, 30)
    now = dt.datetime.now(dt.UTC)
    service = leases.take(db, LEASE, now=now, holder="web-1:4242:abcdef")
    held = attune("retention", "run", "--json")
    assert held.exit_code == 3, held.output
    assert held.stdout == ""
    when = f"{now:%Y-%m-%d %H:%M:%S} UTC"
    assert held.stderr.strip() == (
        f"Another retention run holds the lease (web-1:4242:abcdef, since {when}, until "
        f"{now + leases.TTL:%Y-%m-%d %H:%M:%S} UTC unless it renews it): nothing was done. "
        "Run again once it is over."
    )
    service.release(dt.datetime.now(dt.UTC))
    done = attune("retention", "run", "--json")
    assert done.exit_code == 0, done.output
    report = json.loads(done.stdout)
    assert [f["fleet"] for f in report["fleets"]] == ["default"]
    with db.transaction(write=False) as session:
        lease = leases_repo.get(session, LEASE)
    assert lease is not None
    assert lease.holder != "web-1:4242:abcdef"
    assert lease.expires_at <= dt.datetime.now(dt.UTC), "the command let the lease go"
