"""The retention benchmark (bench/retention.py): its clone follows whatever schema it reads (a
table added or renamed needs no change to it), and the whole script runs end to end with tiny
numbers on SQLite, so that it cannot rot unnoticed. No timing is checked."""

from __future__ import annotations

import datetime as dt
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import (
    Column,
    ForeignKey,
    Integer,
    MetaData,
    String,
    Table,
    UniqueConstraint,
    create_engine,
    event,
    func,
    select,
)

from app.db.types import UTCDateTime

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.fixture(scope="module")
def bench() -> Iterator[Any]:
    sys.path.insert(0, str(BENCH))
    try:
        import retention

        yield retention
    finally:
        sys.path.remove(str(BENCH))
        for name in ("retention", "remote_db", "service"):
            sys.modules.pop(name, None)


def _schema() -> tuple[MetaData, Table]:
    """A schema of its own: people, a journal under a name the service never used, and a chain
    of string ids (visits, their steps, notes on steps)."""
    md = MetaData()
    people = Table(
        "people",
        md,
        Column("id", Integer, primary_key=True, autoincrement=True),
        Column("fleet", String(20)),
        Column("handle", String(40)),
        Column("since", UTCDateTime()),
        UniqueConstraint("fleet", "handle"),
    )
    Table(
        "ledger_v2",
        md,
        Column("id", Integer, primary_key=True, autoincrement=True),
        Column("owner", ForeignKey("people.id", ondelete="CASCADE")),
        Column("amount", Integer),
    )
    Table(
        "visits",
        md,
        Column("id", String(12), primary_key=True),
        Column("person", ForeignKey("people.id", ondelete="CASCADE")),
        Column("at", UTCDateTime()),
    )
    Table(
        "steps",
        md,
        Column("id", String(7), primary_key=True),
        Column("visit", ForeignKey("visits.id", ondelete="CASCADE")),
        Column("n", Integer),
    )
    Table(
        "notes",
        md,
        Column("id", Integer, primary_key=True, autoincrement=True),
        Column("step", ForeignKey("steps.id", ondelete="CASCADE")),
        Column("text", String(20)),
    )
    Table("settings", md, Column("fleet", String(20), primary_key=True))  # no person's data
    return md, people


def test_the_clone_follows_the_schema_it_reads(bench: Any, tmp_path: Path) -> None:
    md, people = _schema()
    engine = create_engine(f"sqlite:///{tmp_path / 'clone.db'}")
    event.listen(engine, "connect", lambda c, _: c.execute("PRAGMA foreign_keys=ON"))
    md.create_all(engine)
    t = md.tables
    at = dt.datetime(2026, 12, 1, 10, tzinfo=dt.UTC)
    minute = dt.timedelta(minutes=1)
    with engine.begin() as conn:
        for p in (1, 2):
            conn.execute(
                people.insert().values(id=p, fleet="f", handle=f"h{p}", since=at + p * minute)
            )
            conn.execute(t["ledger_v2"].insert().values(owner=p, amount=p))
            for v in range(2):
                visit = f"v{p}{v}"
                when = at + (10 * p + v) * minute
                conn.execute(t["visits"].insert().values(id=visit, person=p, at=when))
                conn.execute(t["steps"].insert().values(id=f"s{p}{v}", visit=visit, n=v))
                conn.execute(t["notes"].insert().values(step=f"s{p}{v}", text="x"))
        conn.execute(t["settings"].insert().values(fleet="f"))

    schema = bench.Schema.read(md, people, "handle")
    assert [x.name for x in schema.tables] == ["ledger_v2", "visits", "steps", "notes"]
    assert [f"{c.table.name}.{c.name}" for c in schema.string_ids] == ["visits.id", "steps.id"]
    with engine.connect() as conn:
        moved = bench.age(conn, schema, (10.0, 20.0))
        cloner = bench.Cloner(conn, schema)
        assert cloner.widths == {"visits.id": 6, "steps.id": 4}  # at most 6, within the length
        cloner.clone([1], [1, 2])
        cloner.clone([2], [3])
        conn.commit()
        assert moved == 2 + 4  # the people's and the visits' times
        count = {n: conn.execute(select(func.count()).select_from(t[n])).scalar() for n in t}
        assert count == {
            "people": 5,
            "ledger_v2": 5,
            "visits": 10,
            "steps": 10,
            "notes": 10,
            "settings": 1,
        }
        clone = conn.execute(select(people).where(people.c.handle == "h1-c2")).one()
        visits = conn.execute(select(t["visits"]).where(t["visits"].c.person == clone.id)).all()
        assert sorted(v.id for v in visits) == ["v10000002", "v11000002"]
        steps = conn.execute(
            select(t["steps"].c.id).where(t["steps"].c.visit.in_([v.id for v in visits]))
        ).scalars()
        assert sorted(steps) == ["s100002", "s110002"]
        assert (
            conn.execute(select(t["ledger_v2"].c.amount).where(t["ledger_v2"].c.owner == clone.id))
        ).scalar_one() == 1
        # The visits' four times (the rows on a person directly) spread by rank over 10 to 20
        # days ago, in order; the clone's visits are copies of h1's, the first two; the
        # people's times, before them all, the oldest.
        now = dt.datetime.now(dt.UTC)
        days = sorted(round((now - v.at).total_seconds() / 86400, 3) for v in visits)
        assert days == [16.667, 20.0]
        since = round((now - clone.since).total_seconds() / 86400, 3)
        assert since == 20.0


@pytest.mark.live
def test_the_benchmark_runs_on_sqlite(tmp_path: Path) -> None:
    done = subprocess.run(
        [
            sys.executable,
            str(BENCH / "retention.py"),
            "--engine",
            "sqlite",
            "--episodes",
            "400",
            "--storage-episodes",
            "300",
            "--template-people",
            "4",
            "--template-episodes",
            "120",
            "--robots",
            "2",
            "--baseline-seconds",
            "2",
            "--warmup-seconds",
            "0.5",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    doc = json.loads(done.stdout)
    found = doc["engines"]["sqlite"]
    storage, latency = found["storage"], found["latency"]
    assert storage["check"]["ok"]
    assert storage["fill"]["episodes"] >= 300
    assert 0 < storage["run"]["episodes_removed"] < storage["fill"]["episodes"]
    assert storage["sizes"]["after_run_vacuum"]["bytes"] < storage["sizes"]["after_vacuum"]["bytes"]
    assert latency["check"]["ok"]
    assert latency["run"]["episodes_removed"] == latency["fill"]["episodes"] >= 400
    # The two people with staff corrections are not cloned: a journal entry names its
    # correction by row id, which a clone's correction does not keep.
    assert set(latency["fill"]["not_cloned"]) <= {"tpl-000", "tpl-001"}
    for checked in (latency["served_before"], latency["served_after"]):
        assert checked["model_read_200"] == checked["rebuilt_identical"] == len(checked["people"])
    assert latency["baseline"]["requests"] > 0
    assert latency["baseline"]["errors"] == latency["during"]["errors"] == 0
