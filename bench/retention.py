"""Retention at scale: robots' latency while ``attune retention run`` removes a million old
episodes, and what a window saves on disk.

    .venv/bin/python bench/retention.py                                  # both engines, 1,000,000
    .venv/bin/python bench/retention.py --engine sqlite --episodes 50000 --storage-episodes 20000
    .venv/bin/python bench/retention.py --engine postgresql --delay 1    # the database a hop away
    .venv/bin/python bench/retention.py --engine postgresql --pooler pgbouncer
    .venv/bin/python bench/retention.py --engine sqlite --json > retention.json

Loopback only. Per engine, in one run:

**Storage** (``--storage-episodes``, default 100,000). A fresh database gets that many episodes
whose ages are spread evenly over ``--storage-days`` (default 120). Its size is read after the
fill, then after a VACUUM; then the fleet gets a ``--window-days`` window (default 30, through
``PUT /v1/admin/fleets/default/history``), ``attune retention run`` folds and removes what is
older, and the size is read after the run and after a VACUUM (on PostgreSQL after a plain VACUUM,
which only makes the space reusable, and after VACUUM FULL, which gives it back). SQLite's size
is the database file plus its WAL after ``PRAGMA wal_checkpoint(TRUNCATE)``; PostgreSQL's is
``pg_database_size`` and the sum of ``pg_total_relation_size`` over the service's tables (with
their indexes and TOAST).

**Robots' latency** (``--episodes``, default 1,000,000). A fresh database gets that many
episodes, all older than the window (aged from ``--window-days`` + 1 to that + ``--storage-days``
days), and ``attune serve`` (1 worker on SQLite, 2 on PostgreSQL) serves ``--robots`` robots
that play episodes with the tests' person (``tests/support/people.py``): start an episode, report
each outcome until it closes, one request every ``--interval-ms`` at most per robot. Each robot
serves two people in turn: one whose old history the run folds and removes (people spread over
the fleet, so the run reaches them at different times), and one of its own with no old history.
The latency of every request is measured twice on the same database: for ``--baseline-seconds``
with no retention run ("baseline"), then for as long as ``attune retention run`` (a process of
its own, as cron runs it) takes to fold every person of the fleet and remove the old episodes
("during"). It prints p50, p99 and max of both and their ratio, the run's duration, CPU and what
its report counts, and checks that count against the database.

**Filling fast.** Twenty people (``--template-people``) play ``--template-episodes`` episodes
through the real API, with explicit feedback on some and staff corrections (one lifted) on two
of them. Their timestamps are then aged: every date and time column of every table that holds a
person's data is moved back, each value to its rank among the times of the rows that hang
on a person directly (episodes, mostly), so that the play (a minute or so) is spread evenly
over the age range, in the order it was played. Then they are
cloned in SQL (``INSERT ... SELECT`` in the database itself) under new people until the target
is reached. The clone reads the schema (``app.db.base.Base.metadata``): the tables that refer to
a person are those with a foreign key to ``users``, and those that refer to those tables, and so
on (episodes, their decisions and feedback, the model, its journal...); none is named here. A
clone's person gets a new id in the fleet (``-cN`` appended); integer ids the database assigns
are left to it; string ids (``ep_...``, ``dec_...``) get a fixed-width suffix per clone that
fits the column's length, and every foreign key to them the same suffix. Before cloning at
scale, one trial clone of each template person is rebuilt (``attune models rebuild``, which
replays the person's journal and redraws every decision): a template person whose clone does not
rebuild identically is not cloned (the clone is removed and the output says why). After the fill
a sample of cloned people is rebuilt again and read over HTTP (``GET /v1/users/{id}/model``).

``--delay MS`` (PostgreSQL) puts the database one network hop away for the service and the
retention run, through the delaying TCP proxy of ``bench/remote_db.py`` (``bench/delayproxy.py``);
``--pooler pgbouncer`` puts Debian's PgBouncer in transaction pooling between them and
PostgreSQL. The fill and the measurements go to the database directly.

Bounded: every request times out after 30 s, each robot stops after 2,000,000 requests
(``MAX_REQUESTS``) or at the end of its phase; a retention run longer than
``--max-run-minutes`` is stopped (it is safe to interrupt) and the output says so.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import datetime as dt
import json
import math
import os
import random
import resource
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402
from remote_db import round_trip_ms, start_proxy  # noqa: E402
from service import group_cpu_s, machine  # noqa: E402
from sqlalchemy import (  # noqa: E402
    Column,
    ColumnElement,
    Connection,
    DateTime,
    Integer,
    MetaData,
    String,
    Table,
    and_,
    bindparam,
    delete,
    func,
    insert,
    select,
    text,
    true,
    update,
)
from sqlalchemy.engine import make_url  # noqa: E402
from sqlalchemy.types import TypeDecorator  # noqa: E402

from app.db import models  # noqa: E402
from app.db.base import Base  # noqa: E402
from app.db.session import Database  # noqa: E402
from app.settings import Settings  # noqa: E402
from tests.support.commands import rebuild  # noqa: E402
from tests.support.episodes import event  # noqa: E402
from tests.support.live import (  # noqa: E402
    ATTUNE,
    PG_SERVER,
    LiveService,
    database_name,
    fresh_database,
    make_keys,
    postgres_database,
)
from tests.support.people import answer  # noqa: E402
from tests.support.pgbouncer import PgBouncerFailed  # noqa: E402
from tests.support.pgbouncer import launch as launch_pgbouncer  # noqa: E402

FLEET = "default"
REQUEST_TIMEOUT_S = 30.0
WARMUP_TIMEOUT_S = 120.0  # a robot's first start makes its person (the fleet's prior is read)
MAX_REQUESTS = 2_000_000  # per robot, whatever the phases' lengths
MAX_STEPS = 8  # a negotiation's decisions (tests/support/episodes.py)
SITUATIONS = ("arriving", "working", "stretching", "busy")
NEEDS: tuple[tuple[str, str] | None, ...] = (
    ("ProvideDrink", "tea"),
    ("ProvideDrink", "coffee"),
    ("BriefInformation", "news"),
    ("ArrangeSchedule", "today_agenda"),
    None,
)
UTC_OFFSETS = (-8, -3, 0, 2, 5, 9)  # the template's people live in several time zones
SAMPLE_CHECKED = 5  # cloned people rebuilt and read over HTTP after the fill and after the run
CHUNK_EPISODES = 50_000  # episodes cloned per INSERT ... SELECT (one transaction)
SUFFIX_DIGITS = "0123456789abcdefghijklmnopqrstuvwxyz"

_out_lock = threading.Lock()


def say(line: str) -> None:
    """A progress line, on stderr (stdout is for the report)."""
    with _out_lock:
        print(f"{time.strftime('%H:%M:%S')} {line}", file=sys.stderr, flush=True)


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return math.nan
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


# -- the schema: which tables hold a person's data ------------------------------------------------
def _is_string(column: Column[Any]) -> bool:
    kind = column.type.impl if isinstance(column.type, TypeDecorator) else column.type
    return isinstance(kind, String)


def _is_datetime(column: Column[Any]) -> bool:
    kind = column.type.impl if isinstance(column.type, TypeDecorator) else column.type
    return isinstance(kind, DateTime)


def _table(model: type[Base]) -> Table:
    """The table of a mapped class, as the metadata holds it."""
    return Base.metadata.tables[model.__tablename__]


class CloneRefused(RuntimeError):
    """The schema has a reference the clone cannot rewrite."""


@dataclass
class Schema:
    """The person tables, read from the metadata: ``users``, and every table that refers to it
    (through a chain of foreign keys), parents first, each with its chain to ``users``."""

    users: Table
    key: Column[Any]  # the person's id in its fleet: a clone gets a new one
    unique: list[Column[Any]]  # the users' unique constraint that holds the key
    tables: list[Table]
    paths: dict[str, list[tuple[str, Column[Any]]]]  # table -> [(its column, the parent's column)]
    string_ids: list[Column[Any]]  # string primary keys that get a per-clone suffix
    # integer keys the database assigns that another person table refers to: a clone's rows
    # get the template's id moved by a per-table stride times the clone's number
    int_ids: list[Column[Any]] = field(default_factory=list)

    @classmethod
    def read(cls, metadata: MetaData, users: Table, key: str) -> Schema:
        paths: dict[str, list[tuple[str, Column[Any]]]] = {}
        tables: list[Table] = []
        for table in metadata.sorted_tables:  # parents before children
            if table is users:
                continue
            fks = sorted(
                table.foreign_keys,
                key=lambda fk: (fk.column.table is not users, fk.target_fullname),
            )
            for fk in fks:
                parent = fk.column.table
                if parent is users:
                    paths[table.name] = [(fk.parent.name, fk.column)]
                elif parent.name in paths:
                    paths[table.name] = [(fk.parent.name, fk.column), *paths[parent.name]]
                else:
                    continue
                tables.append(table)
                break
        unique = next(
            (
                [users.c[c.name] for c in u.columns]
                for u in sorted(users.constraints, key=lambda c: str(c.name))
                if hasattr(u, "columns") and u is not users.primary_key and key in u.columns
            ),
            [users.c[key]],
        )
        schema = cls(users, users.c[key], unique, tables, paths, [])
        for table in tables:
            for column in table.primary_key.columns:
                if schema._refers(column) is None and _is_string(column):
                    schema.string_ids.append(column)
        for table in tables:
            for column in table.columns:
                ref = schema._refers(column)
                if (
                    ref is not None
                    and ref.table is not users
                    and not _is_string(ref)
                    and ref is ref.table.autoincrement_column
                    and all(ref is not c for c in schema.int_ids)
                ):
                    schema.int_ids.append(ref)
        for table in tables:
            schema.check(table)
        return schema

    def _refers(self, column: Column[Any]) -> Column[Any] | None:
        """The person table's column ``column`` refers to (None: none)."""
        person = {t.name for t in self.tables} | {self.users.name}
        for fk in column.foreign_keys:
            if fk.column.table.name in person:
                return fk.column
        return None

    def check(self, table: Table) -> None:
        for column in table.columns:
            ref = self._refers(column)
            if (
                ref is not None
                and ref.table is not self.users
                and not _is_string(ref)
                and all(ref is not c for c in self.int_ids)
            ):
                raise CloneRefused(
                    f"{table.name}.{column.name} refers to {ref.table.name}.{ref.name}, an "
                    "integer id the database assigns: a clone cannot know the new value"
                )
            if (
                ref is None
                and column.primary_key
                and column is not table.autoincrement_column
                and not _is_string(column)
            ):
                raise CloneRefused(
                    f"{table.name}.{column.name} is an integer key the database does not assign"
                )

    def describe(self) -> str:
        parts = []
        for table in self.tables:
            chain = " → ".join(
                [table.name] + [f"{parent.table.name}" for _, parent in self.paths[table.name]]
            )
            parts.append(chain)
        return "; ".join(parts)


# -- the clone ------------------------------------------------------------------------------------
def _suffix(n: int, width: int) -> str:
    digits = []
    for _ in range(width):
        n, d = divmod(n, len(SUFFIX_DIGITS))
        digits.append(SUFFIX_DIGITS[d])
    if n:
        raise CloneRefused(f"clone {n} does not fit in {width} characters")
    return "".join(reversed(digits))


class Cloner:
    """Copies template people under new people, in the database, a chunk of clones per
    ``INSERT ... SELECT`` of each person table."""

    def __init__(self, conn: Connection, schema: Schema) -> None:
        self.conn = conn
        self.schema = schema
        self.widths: dict[str, int] = {}  # "table.column" of a string id -> its suffix's width
        for column in schema.string_ids:
            longest = conn.execute(select(func.max(func.length(column)))).scalar() or 0
            length = getattr(column.type, "length", None) or (longest + 6)
            self.widths[self._name(column)] = min(6, length - int(longest))
        # an integer id referred to: clone n's rows take the template's id + stride * n
        self.strides: dict[str, int] = {
            self._name(c): int(conn.execute(select(func.max(c))).scalar() or 0) + 1
            for c in schema.int_ids
        }
        self.clones = Table(
            "bench_clones",
            MetaData(),
            Column("n", Integer, primary_key=True),
            Column("person", String(32)),
            *(Column(f"s{i}", String(8)) for i in range(len(schema.string_ids))),
            prefixes=["TEMPORARY"],
        )
        self.clones.create(conn)

    @staticmethod
    def _name(column: Column[Any]) -> str:
        return f"{column.table.name}.{column.name}"

    def capacity(self) -> int:
        """How many clones the string ids' room allows."""
        room = min(self.widths.values(), default=6)
        if room < 1:
            raise CloneRefused(
                "no room for a clone's suffix in "
                + ", ".join(k for k, w in self.widths.items() if w < 1)
            )
        return int(len(SUFFIX_DIGITS) ** room) - 1

    def _suffix_of(self, column: Column[Any]) -> ColumnElement[Any]:
        i = [self._name(c) for c in self.schema.string_ids].index(self._name(column))
        return self.clones.c[f"s{i}"]

    def clone(self, people: list[int], numbers: Sequence[int]) -> None:
        """Clone template people (their ``users`` row ids) once for each of ``numbers``."""
        s = self.schema
        rows = [
            {
                "n": n,
                "person": f"-c{n}",
                **{
                    f"s{i}": _suffix(n, self.widths[self._name(c)])
                    for i, c in enumerate(s.string_ids)
                },
            }
            for n in numbers
        ]
        self.conn.execute(insert(self.clones), rows)
        users, key, clones = s.users, s.key, self.clones
        pk = users.primary_key.columns.values()[0]
        cols = [c for c in users.columns if c is not users.autoincrement_column]
        values = [(c + clones.c.person) if c is key else c for c in cols]
        self.conn.execute(
            insert(users).from_select(
                [c.name for c in cols],
                select(*values).select_from(users.join(clones, true())).where(pk.in_(people)),
            )
        )
        for table in s.tables:
            self._table(table, people)
        self.conn.execute(delete(self.clones))
        if self.conn.dialect.name == "postgresql":  # ids given explicitly: move the sequences
            for column in s.int_ids:
                name = column.table.name
                self.conn.execute(
                    text(
                        f"SELECT setval(pg_get_serial_sequence('{name}', '{column.name}'), "
                        f"COALESCE((SELECT MAX({column.name}) FROM {name}), 0) + 1, false)"
                    )
                )

    def _table(self, table: Table, people: list[int]) -> None:
        s, clones = self.schema, self.clones
        joined: Any = table
        current: Any = table
        path = s.paths[table.name]
        for i, (child, parent) in enumerate(path):
            alias = parent.table.alias(f"p{i}")
            joined = joined.join(alias, current.c[child] == alias.c[parent.name])
            current = alias
        tpl = current  # the template person's users row
        joined = joined.join(clones, true())
        new = s.users.alias("clone")
        needs_user = any(
            (ref := s._refers(c)) is not None and ref.table is s.users for c in table.columns
        )
        if needs_user:
            joined = joined.join(
                new,
                and_(
                    *(
                        new.c[c.name]
                        == (tpl.c[c.name] + clones.c.person if c is s.key else tpl.c[c.name])
                        for c in s.unique
                    )
                ),
            )
        cols, values = [], []
        for column in table.columns:
            moved = self.strides.get(self._name(column))
            if column is table.autoincrement_column and moved is None:
                continue
            ref = s._refers(column)
            value: ColumnElement[Any]
            if moved is not None:  # an integer id that other rows refer to
                value = table.c[column.name] + moved * clones.c.n
            elif ref is not None and ref.table is s.users:
                value = new.c[ref.name]
            elif ref is not None and self._name(ref) in self.strides:
                value = table.c[column.name] + self.strides[self._name(ref)] * clones.c.n
            elif ref is not None:
                value = table.c[column.name] + self._suffix_of(ref)
            elif column.primary_key:
                value = table.c[column.name] + self._suffix_of(column)
            else:
                value = table.c[column.name]
            cols.append(column.name)
            values.append(value)
        pk = s.users.primary_key.columns.values()[0]
        # In the template's order: rows a version holds several of (a journal's steps) are
        # replayed in the order of their ids, which the database gives in this order.
        order = [clones.c.n, *table.primary_key.columns]
        self.conn.execute(
            insert(table).from_select(
                cols,
                select(*values)
                .select_from(joined)
                .where(tpl.c[pk.name].in_(people))
                .order_by(*order),
            )
        )


def age(conn: Connection, schema: Schema, ages: tuple[float, float]) -> int:
    """Move every date and time of every person table back, spread evenly over ``ages`` days
    before now: each value goes to its rank among those of the tables that refer to ``users``
    directly (the template's play, whatever its pace), the oldest to ``ages[1]`` days ago, the
    newest to ``ages[0]``. The order of any two values is kept. A table whose rows the model's
    journal refers to (a staff correction) is left as it was: a replay reads its times (a
    correction's rule keeps when it was made). The rows changed."""
    now = dt.datetime.now(dt.UTC)
    oldest, newest = now - dt.timedelta(days=ages[1]), now - dt.timedelta(days=ages[0])
    found: list[tuple[Table, list[Column[Any]], list[Column[Any]], list[Any]]] = []
    replayed = {c.table.name for c in schema.int_ids}
    for table in [schema.users, *schema.tables]:
        if table.name in replayed:
            continue
        stamps = [c for c in table.columns if _is_datetime(c)]
        if stamps:
            keys = list(table.primary_key.columns)
            found.append((table, keys, stamps, list(conn.execute(select(*keys, *stamps)))))
    # Evenly by the rows that hang on a person directly (episodes, mostly): a table further
    # down (a decision) has as many rows per episode as the negotiation took.
    direct = [f for f in found if len(schema.paths.get(f[0].name, [])) == 1] or found
    points = sorted(
        v for _, keys, _, rows in direct for row in rows for v in row[len(keys) :] if v is not None
    )
    last = max(len(points) - 1, 1)

    def moved(value: dt.datetime | None) -> dt.datetime | None:
        if value is None:
            return None
        rank = (bisect.bisect_left(points, value) + bisect.bisect_right(points, value) - 1) / 2
        return oldest + (newest - oldest) * (min(max(rank, 0.0), last) / last)

    changed = 0
    for table, keys, stamps, rows in found:
        if not rows:
            continue
        stmt = (
            update(table)
            .where(and_(*(k == bindparam(f"k_{k.name}") for k in keys)))
            .values({c.name: bindparam(f"v_{c.name}", type_=c.type) for c in stamps})
        )
        params = [
            {
                **{f"k_{k.name}": row[i] for i, k in enumerate(keys)},
                **{f"v_{c.name}": moved(row[len(keys) + j]) for j, c in enumerate(stamps)},
            }
            for row in rows
        ]
        conn.execute(stmt, params)
        changed += len(rows)
    return changed


# -- the template: people playing through the real API -------------------------------------------
def _now_at(offset_hours: int) -> str:
    zone = dt.timezone(dt.timedelta(hours=offset_hours))
    return dt.datetime.now(zone).isoformat(timespec="milliseconds")


@dataclass
class Template:
    people: list[str]
    episodes: int
    requests: int
    seconds: float
    corrections: int
    feedback: int


def play_template(
    url: str, robot_keys: list[str], staff_key: str, people: int, episodes: int, seed: int
) -> Template:
    """``people`` people play ``episodes`` episodes (in all) through the service at ``url``:
    one thread per robot key, each with its own people; explicit feedback on every 7th
    episode; two staff corrections on each of the first two people, one of them lifted."""
    names = [f"tpl-{i:03d}" for i in range(people)]
    per = [episodes // people + (1 if i < episodes % people else 0) for i in range(people)]
    counts = {"requests": 0, "feedback": 0, "corrections": 0}
    lock = threading.Lock()
    errors: list[BaseException] = []
    began = time.monotonic()

    def staff_corrections(client: httpx.Client, person: str) -> None:
        for cid, situation in (("c1", "stretching"), ("c2", "working")):
            r = client.post(
                f"/v1/users/{person}/corrections",
                json={
                    "correction_id": f"{person}-{cid}",
                    "time_slot": "afternoon",
                    "situation": situation,
                    "kind": "prefers",
                    "service": "ProvideDrink",
                    "detail": "tea",
                },
            )
            assert r.status_code == 201, r.text
        r = client.delete(f"/v1/users/{person}/corrections/{person}-c2")
        assert r.status_code in (200, 204), r.text
        with lock:
            counts["corrections"] += 2

    def robot(index: int) -> None:
        rng = random.Random(seed * 1000 + index)
        mine = list(range(index, people, len(robot_keys)))
        headers = {"Authorization": f"Bearer {robot_keys[index]}"}
        staff_headers = {"Authorization": f"Bearer {staff_key}"}
        sent = 0
        try:
            with (
                httpx.Client(base_url=url, headers=headers, timeout=REQUEST_TIMEOUT_S) as client,
                httpx.Client(
                    base_url=url, headers=staff_headers, timeout=REQUEST_TIMEOUT_S
                ) as staff,
            ):
                for round_ in range(max(per)):
                    for p in mine:
                        if round_ >= per[p]:
                            continue
                        person = names[p]
                        if p < 2 and round_ == per[p] // 3:
                            staff_corrections(staff, person)
                        need = NEEDS[(p + round_ // 10) % len(NEEDS)]
                        body = event(
                            f"tpl-{p}-{round_}",
                            situation=rng.choice(SITUATIONS),
                            occurred_at=_now_at(rng.choice(UTC_OFFSETS)),
                            robot_id=f"tpl-robot-{index}",
                        )
                        r = client.post(f"/v1/users/{person}/episodes", json=body)
                        sent += 1
                        assert r.status_code == 201, r.text
                        started = r.json()
                        decision = started["decision"]
                        steps = 0
                        while decision is not None:
                            assert steps < MAX_STEPS, "an episode longer than a negotiation"
                            said = answer(
                                decision["action"],
                                need=need,
                                rng=rng,
                                yes=0.85,
                                asks=0.8,
                                precise=0.3,
                                smiles=0.2,
                            )
                            r = client.post(
                                f"/v1/episodes/{started['episode_id']}/outcomes",
                                json={"decision_id": decision["decision_id"], **said},
                            )
                            sent += 1
                            assert r.status_code == 200, r.text
                            decision = r.json()["decision"]
                            steps += 1
                        if round_ % 7 == 3:
                            r = client.post(
                                f"/v1/episodes/{started['episode_id']}/feedback",
                                json={
                                    "feedback_id": f"fb-{round_}",
                                    "feedback": rng.choice(("positive", "negative")),
                                },
                            )
                            sent += 1
                            assert r.status_code == 200, r.text
                            with lock:
                                counts["feedback"] += 1
        except BaseException as exc:  # reported in the caller's thread
            errors.append(exc)
        with lock:
            counts["requests"] += sent

    threads = [threading.Thread(target=robot, args=(i,)) for i in range(len(robot_keys))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return Template(
        people=names,
        episodes=episodes,
        requests=counts["requests"],
        seconds=time.monotonic() - began,
        corrections=counts["corrections"],
        feedback=counts["feedback"],
    )


# -- one database, filled -------------------------------------------------------------------------
@dataclass
class Fill:
    """What a fill made."""

    target: int
    episodes: int  # in the database at the end of the fill
    people: int
    template_people: int
    template_episodes: int
    template_seconds: float
    cloned_people: list[str]  # ids of the clones made
    not_cloned: dict[str, str]  # template person -> why its trial clone was refused
    ages_days: tuple[float, float]
    clone_seconds: float
    schema: str
    rows: dict[str, int] = field(default_factory=dict)  # rows per person table at the end


def _counts(conn: Connection, schema: Schema) -> dict[str, int]:
    return {
        t.name: int(conn.execute(select(func.count()).select_from(t)).scalar() or 0)
        for t in [schema.users, *schema.tables]
    }


def _rebuilds(direct_url: str, user_id: str) -> str | None:
    """None when the person's model rebuilds identically from its journal; else why not."""
    try:
        found = rebuild(direct_url, user_id, fleet=FLEET)
    except AssertionError as exc:  # no JSON line: the command failed
        detail = exc.args[0] if exc.args else exc
        if isinstance(detail, tuple) and len(detail) == 3:
            return f"rebuild failed: {detail[2]!r}"
        return f"rebuild failed: {detail}"
    if found.exit_code != 0 or not found.summary.get("identical"):
        return f"rebuild differs: {found.summary}"
    return None


def fill(
    args: argparse.Namespace,
    service: LiveService,
    direct_url: str,
    target: int,
    ages: tuple[float, float],
) -> Fill:
    """Template people through the API, aged, then cloned in SQL up to ``target`` episodes."""
    schema = Schema.read(Base.metadata, _table(models.User), "user_id")
    robot_keys = make_keys(direct_url, args.template_robots, "robot", FLEET)
    staff_key = make_keys(direct_url, 1, "staff", FLEET)[0]
    template_episodes = min(args.template_episodes, target)
    say(
        f"  template: {args.template_people} people play {template_episodes:,} episodes through "
        f"the API ({args.template_robots} robots)"
    )
    tpl = play_template(
        service.url,
        robot_keys,
        staff_key,
        args.template_people,
        template_episodes,
        args.seed,
    )
    say(
        f"  template played in {tpl.seconds:.1f} s ({tpl.requests:,} requests, "
        f"{tpl.feedback} feedback, {tpl.corrections} corrections)"
    )
    db = Database(Settings(database_url=direct_url, _env_file=None))  # type: ignore[call-arg]
    began = time.monotonic()
    try:
        with db.engine.connect() as conn:
            aged = age(conn, schema, ages)
            conn.commit()
            say(f"  aged {aged:,} rows over {ages[0]:g} to {ages[1]:g} days ago")
            cloner = Cloner(conn, schema)
            conn.commit()
            users, key = schema.users, schema.key
            pk = users.primary_key.columns.values()[0]
            ep = _table(models.Episode)
            per_person: dict[str, int] = dict(
                conn.execute(
                    select(users.c[key.name], func.count(ep.c.id))
                    .select_from(users.join(ep, ep.c.user_pk == pk))
                    .group_by(users.c[key.name])
                ).all()
            )
            ids = dict(conn.execute(select(users.c[key.name], pk)).all())
            total = sum(per_person.values())
            cloned: list[str] = []
            refused: dict[str, str] = {}
            clonable = [p for p in tpl.people if per_person.get(p)]
            if total < target:
                # One trial clone of everyone, rebuilt: those that do not rebuild are removed.
                cloner.clone([ids[p] for p in clonable], [1])
                conn.commit()
                for person in clonable:
                    why = _rebuilds(direct_url, f"{person}-c1")
                    if why is not None:
                        refused[person] = why
                if refused:
                    conn.execute(
                        delete(users).where(users.c[key.name].in_([f"{p}-c1" for p in refused]))
                    )
                    conn.commit()
                    say(
                        "  not cloned (their trial clone does not rebuild): "
                        + ", ".join(f"{p} ({why[:160]})" for p, why in refused.items())
                    )
                clonable = [p for p in clonable if p not in refused]
                if not clonable:
                    raise CloneRefused("no template person's clone rebuilds: nothing to clone")
                cloned += [f"{p}-c1" for p in clonable]
                total += sum(per_person[p] for p in clonable)
            block = sum(per_person[p] for p in clonable)
            full = max(0, (target - total) // block)
            if 1 + full + 1 > cloner.capacity():
                raise CloneRefused(f"{full + 2} clones do not fit the ids' room")
            per_chunk = max(1, CHUNK_EPISODES // block)
            n = 2
            last_line = time.monotonic()
            while n < 2 + full:
                numbers = list(range(n, min(2 + full, n + per_chunk)))
                cloner.clone([ids[p] for p in clonable], numbers)
                conn.commit()
                total += block * len(numbers)
                cloned += [f"{p}-c{k}" for k in numbers for p in clonable]
                n = numbers[-1] + 1
                if time.monotonic() - last_line > 10 or n >= 2 + full:
                    rate = (total - tpl.episodes) / max(time.monotonic() - began, 1e-9)
                    say(f"  cloned: {total:,} / {target:,} episodes ({rate:,.0f} a second)")
                    last_line = time.monotonic()
            if total < target:  # the rest: the first people of one more clone
                part: list[str] = []
                for p in clonable:
                    if total >= target:
                        break
                    part.append(p)
                    total += per_person[p]
                cloner.clone([ids[p] for p in part], [n])
                conn.commit()
                cloned += [f"{p}-c{n}" for p in part]
            rows = _counts(conn, schema)
            conn.commit()
    finally:
        db.dispose()
    seconds = time.monotonic() - began
    say(
        f"  filled: {rows[ep.name]:,} episodes of {rows[schema.users.name]:,} people "
        f"in {seconds:.1f} s"
    )
    return Fill(
        target=target,
        episodes=rows[ep.name],
        people=rows[schema.users.name],
        template_people=len(tpl.people),
        template_episodes=tpl.episodes,
        template_seconds=tpl.seconds,
        cloned_people=cloned,
        not_cloned=refused,
        ages_days=ages,
        clone_seconds=seconds,
        schema=schema.describe(),
        rows=rows,
    )


# -- sizes ----------------------------------------------------------------------------------------
def _sqlite_path(url: str) -> Path:
    database = make_url(url).database
    assert database, url
    return Path(database)


def _autocommit(url: str) -> Any:
    """A connection outside any transaction (VACUUM, checkpoints), closed after."""
    import psycopg

    return psycopg.connect(url.replace("postgresql+psycopg://", "postgresql://"), autocommit=True)


def size(engine: str, url: str) -> dict[str, int]:
    """The database's size: SQLite's file plus its WAL after a checkpoint; PostgreSQL's
    ``pg_database_size`` and the sum of ``pg_total_relation_size`` of the service's tables."""
    if engine == "sqlite":
        import sqlite3

        path = _sqlite_path(url)
        with contextlib.closing(sqlite3.connect(path)) as conn:
            conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            free = int(conn.execute("PRAGMA freelist_count").fetchone()[0])
            page = int(conn.execute("PRAGMA page_size").fetchone()[0])
        wal = Path(f"{path}-wal")
        return {
            "bytes": path.stat().st_size + (wal.stat().st_size if wal.exists() else 0),
            "free_bytes": free * page,
        }
    names = [t.name for t in Base.metadata.sorted_tables]
    with _autocommit(url) as conn:
        database = conn.execute("SELECT pg_database_size(current_database())").fetchone()[0]
        tables = conn.execute(
            "SELECT coalesce(sum(pg_total_relation_size(c.oid)), 0) FROM pg_class c "
            "JOIN pg_namespace n ON n.oid = c.relnamespace "
            "WHERE n.nspname = current_schema() AND c.relkind = 'r' AND c.relname = ANY(%s)",
            (names,),
        ).fetchone()[0]
    return {"bytes": int(database), "tables_bytes": int(tables)}


def vacuum(engine: str, url: str, full: bool = False) -> None:
    if engine == "sqlite":
        import sqlite3

        with contextlib.closing(sqlite3.connect(_sqlite_path(url), timeout=60)) as conn:
            conn.execute("VACUUM")
        return
    with _autocommit(url) as conn:
        conn.execute("VACUUM FULL ANALYZE" if full else "VACUUM ANALYZE")
        # The fill's gigabytes are written out now, not by a checkpoint in a measured window.
        conn.execute("CHECKPOINT")


def count_episodes(url: str, before: dt.datetime | None = None) -> int:
    db = Database(Settings(database_url=url, _env_file=None))  # type: ignore[call-arg]
    ep = _table(models.Episode)
    try:
        with db.engine.connect() as conn:
            stmt = select(func.count()).select_from(ep)
            if before is not None:
                stmt = stmt.where(ep.c.created_at < before)
            return int(conn.execute(stmt).scalar() or 0)
    finally:
        db.dispose()


def count_rows(url: str, table: Table) -> int:
    db = Database(Settings(database_url=url, _env_file=None))  # type: ignore[call-arg]
    try:
        with db.engine.connect() as conn:
            return int(conn.execute(select(func.count()).select_from(table)).scalar() or 0)
    finally:
        db.dispose()


# -- robots ---------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Sent:
    at: float  # time.monotonic() when sent
    ms: float
    status: int  # 0: no answer (a timeout or a dropped connection)
    kind: str  # start | outcome
    group: str  # folded | other


class Robot(threading.Thread):
    """Plays episodes for its people in turn, one request every ``interval`` s at most, until
    ``stop`` is set (or ``MAX_REQUESTS``); every request's latency is kept."""

    def __init__(
        self,
        index: int,
        url: str,
        key: str,
        people: list[tuple[str, str]],
        interval: float,
        stop: threading.Event,
        seed: int,
    ) -> None:
        super().__init__(daemon=True, name=f"robot-{index}")
        self.index, self.url, self.key, self.people = index, url, key, people
        self.interval, self.stop = interval, stop
        self.rng = random.Random(seed * 7919 + index)
        self.sent: list[Sent] = []
        self.started = 0  # episodes started (201)
        self.warm = threading.Event()  # set once each of its people has played an episode
        self._next = 0.0
        self.failure: BaseException | None = None

    def _post(
        self, client: httpx.Client, path: str, body: dict[str, Any], kind: str, group: str
    ) -> tuple[int, Any]:
        wait = self._next - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        at = time.monotonic()
        self._next = at + self.interval
        status, doc = 0, None
        timeout = REQUEST_TIMEOUT_S if self.warm.is_set() else WARMUP_TIMEOUT_S
        try:
            r = client.post(path, json=body, timeout=timeout)
            status = r.status_code
            if status < 300:
                doc = r.json()
        except httpx.TransportError:
            pass
        self.sent.append(Sent(at, (time.monotonic() - at) * 1000, status, kind, group))
        return status, doc

    def run(self) -> None:
        headers = {"Authorization": f"Bearer {self.key}"}
        n = 0
        try:
            with httpx.Client(base_url=self.url, headers=headers) as client:
                while not self.stop.is_set() and len(self.sent) < MAX_REQUESTS:
                    person, group = self.people[n % len(self.people)]
                    n += 1
                    if n > len(self.people):
                        self.warm.set()
                    need = NEEDS[self.rng.randrange(len(NEEDS))]
                    body = event(
                        f"bench-{self.index}-{n}",
                        situation=self.rng.choice(SITUATIONS),
                        occurred_at=_now_at(self.rng.choice(UTC_OFFSETS)),
                        robot_id=f"bench-robot-{self.index}",
                    )
                    status, started = self._post(
                        client, f"/v1/users/{person}/episodes", body, "start", group
                    )
                    if status not in (200, 201) or started is None:
                        continue
                    self.started += status == 201
                    decision = started["decision"]
                    steps = 0
                    while decision is not None and steps < MAX_STEPS and not self.stop.is_set():
                        said = answer(
                            decision["action"],
                            need=need,
                            rng=self.rng,
                            yes=0.8,
                            asks=0.8,
                            smiles=0.1,
                        )
                        status, got = self._post(
                            client,
                            f"/v1/episodes/{started['episode_id']}/outcomes",
                            {"decision_id": decision["decision_id"], **said},
                            "outcome",
                            group,
                        )
                        if status != 200 or got is None:
                            break
                        decision = got["decision"]
                        steps += 1
        except BaseException as exc:  # reported by the caller
            self.failure = exc
        finally:
            self.warm.set()


@dataclass
class Latency:
    requests: int
    seconds: float
    rps: float
    p50_ms: float
    p99_ms: float
    max_ms: float
    errors: int  # answered 5xx/4xx or not at all


def latency(sent: Sequence[Sent], start: float, end: float) -> Latency:
    window = [s for s in sent if start <= s.at < end]
    ms = [s.ms for s in window]
    seconds = max(end - start, 1e-9)
    return Latency(
        requests=len(window),
        seconds=seconds,
        rps=len(window) / seconds,
        p50_ms=percentile(ms, 0.50),
        p99_ms=percentile(ms, 0.99),
        max_ms=max(ms, default=math.nan),
        errors=sum(1 for s in window if not 200 <= s.status < 300),
    )


# -- the phases -----------------------------------------------------------------------------------
@dataclass
class Place:
    """Where the service and the retention run reach the database."""

    direct_url: str
    service_url: str
    env: dict[str, str]
    round_trip_ms: float | None = None
    note: str = ""


@contextlib.contextmanager
def place(engine: str, args: argparse.Namespace, folder: Path) -> Iterator[Place]:
    """A fresh database (``attune_bench_...`` on PostgreSQL, a file on SQLite) and the URL the
    service uses for it: through PgBouncer and the delay proxy when asked."""
    if engine == "sqlite":
        with fresh_database("sqlite", folder) as url:
            yield Place(url, url, {})
        return
    with contextlib.ExitStack() as stack:
        url = stack.enter_context(postgres_database(database_name("bench")))
        server = make_url(PG_SERVER)
        target = (server.host or "127.0.0.1", server.port or 5432)
        env: dict[str, str] = {}
        notes = []
        if args.pooler == "pgbouncer":
            target = ("127.0.0.1", stack.enter_context(launch_pgbouncer()).port)
            env["ATTUNE_DATABASE_POOLER"] = "transaction"
            notes.append("through PgBouncer (transaction pooling)")
        service_url = url
        rtt = None
        if args.delay is not None:
            budget = args.max_run_minutes * 60 + 6 * 3600
            proxy, port = start_proxy(args.delay, target, budget)
            stack.callback(_stop, proxy)
            name = make_url(url).database
            auth = server.username or "postgres"
            if server.password:
                auth += f":{server.password}"
            service_url = f"postgresql+psycopg://{auth}@127.0.0.1:{port}/{name}"
            rtt = round_trip_ms(f"postgresql://{auth}@127.0.0.1:{port}/{name}")
            notes.append(
                f"through the delay proxy, {args.delay:g} ms each way (SELECT 1 {rtt:.2f} ms)"
            )
        elif args.pooler == "pgbouncer":
            bouncer_url = make_url(url).set(host="127.0.0.1", port=target[1])
            service_url = bouncer_url.render_as_string(hide_password=False)
        yield Place(url, service_url, env, rtt, ", ".join(notes))


def _stop(proc: subprocess.Popen[Any]) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _workers(engine: str, args: argparse.Namespace) -> int:
    return int(args.workers or (1 if engine == "sqlite" else 2))


def _set_window(service: LiveService, staff_key: str, days: int) -> None:
    r = httpx.put(
        f"{service.url}/v1/admin/fleets/{FLEET}/history",
        json={"history_days": days},
        headers={"Authorization": f"Bearer {staff_key}"},
        timeout=REQUEST_TIMEOUT_S,
    )
    r.raise_for_status()


def _retention_command(args: argparse.Namespace) -> list[str]:
    command = [ATTUNE, "retention", "run", "--fleet", FLEET, "--json", "--no-progress"]
    if args.batch:
        command += ["--batch", str(args.batch)]
    return command


def _report_figures(report: dict[str, Any]) -> dict[str, Any]:
    fleet = report["fleets"][0] if report.get("fleets") else {}
    started = dt.datetime.fromisoformat(report["started_at"])
    finished = dt.datetime.fromisoformat(report["finished_at"])
    return {
        "seconds": (finished - started).total_seconds(),
        "people": fleet.get("people", 0),
        "folded": fleet.get("folded", 0),
        "skipped": len(fleet.get("skipped", [])),
        "episodes_removed": report["episodes_removed"],
        "journal_removed": report["journal_removed"],
        "kept_from": fleet.get("kept_from"),
    }


def _served(
    service: LiveService, staff_key: str, direct_url: str, people: list[str]
) -> dict[str, Any]:
    """Each person's model read over HTTP (200?) and rebuilt from its journal (identical?)."""
    headers = {"Authorization": f"Bearer {staff_key}"}
    read = 0
    for person in people:
        r = httpx.get(f"{service.url}/v1/users/{person}/model", headers=headers, timeout=60)
        read += r.status_code == 200
    rebuilt = {p: _rebuilds(direct_url, p) for p in people}
    return {
        "people": people,
        "model_read_200": read,
        "rebuilt_identical": sum(1 for why in rebuilt.values() if why is None),
        "problems": {p: why for p, why in rebuilt.items() if why is not None},
    }


def storage(engine: str, args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    say(f"{engine}: storage, {args.storage_episodes:,} episodes over {args.storage_days:g} days")
    with place(engine, args, folder) as where:
        with LiveService(
            where.service_url,
            workers=_workers(engine, args),
            env=where.env,
            log_path=folder / f"serve-{engine}-storage.log",
        ) as service:
            done = fill(
                args, service, where.direct_url, args.storage_episodes, (0.0, args.storage_days)
            )
            staff_key = make_keys(where.direct_url, 1, "staff", FLEET)[0]
            after_fill = size(engine, where.direct_url)
            vacuum(engine, where.direct_url)
            without = size(engine, where.direct_url)
            say(
                f"  size: {_mib(after_fill['bytes'])} after the fill, "
                f"{_mib(without['bytes'])} after VACUUM"
            )
            _set_window(service, staff_key, args.window_days)
            total_before = count_episodes(where.direct_url)
            began = time.monotonic()
            ran = service.attune(*_retention_command(args)[1:], timeout=args.max_run_minutes * 60)
            if ran.returncode != 0:
                raise RuntimeError(f"attune retention run failed:\n{ran.stdout}\n{ran.stderr}")
            wall = time.monotonic() - began
            report = _report_figures(json.loads(ran.stdout))
            total_after = count_episodes(where.direct_url)
            kept_from = dt.datetime.fromisoformat(report["kept_from"])
            left_old = count_episodes(where.direct_url, kept_from)
            after_run = size(engine, where.direct_url)
            vacuum(engine, where.direct_url)
            after_vacuum = size(engine, where.direct_url)
            full = None
            if engine == "postgresql":
                vacuum(engine, where.direct_url, full=True)
                full = size(engine, where.direct_url)
            say(
                f"  retention: {report['episodes_removed']:,} episodes removed in {wall:.1f} s; "
                f"size {after_run['bytes'] / 2**20:,.1f} MiB after the run, "
                f"{after_vacuum['bytes'] / 2**20:,.1f} MiB after VACUUM"
                + (f", {full['bytes'] / 2**20:,.1f} MiB after VACUUM FULL" if full else "")
            )
    return {
        "fill": _fill_json(done),
        "sizes": {
            "after_fill": after_fill,
            "after_vacuum": without,
            "after_run": after_run,
            "after_run_vacuum": after_vacuum,
            **({"after_run_vacuum_full": full} if full else {}),
        },
        "run": {**report, "wall_seconds": wall},
        "check": {
            "episodes_before": total_before,
            "episodes_after": total_after,
            "removed_by_count": total_before - total_after,
            "older_than_kept_from_left": left_old,
            "ok": report["episodes_removed"] == total_before - total_after and left_old == 0,
        },
    }


def _fill_json(done: Fill) -> dict[str, Any]:
    doc = asdict(done)
    doc["cloned_people"] = len(done.cloned_people)
    return doc


def robots_latency(engine: str, args: argparse.Namespace, folder: Path) -> dict[str, Any]:
    say(f"{engine}: robots' latency, a run that removes {args.episodes:,} old episodes")
    ages = (args.window_days + 1.0, args.window_days + 1.0 + args.storage_days)
    with place(engine, args, folder) as where:
        workers = _workers(engine, args)
        with LiveService(
            where.service_url,
            workers=workers,
            env=where.env,
            log_path=folder / f"serve-{engine}-latency.log",
        ) as service:
            done = fill(args, service, where.direct_url, args.episodes, ages)
            sizes = size(engine, where.direct_url)
            if engine == "postgresql":
                # What autovacuum would do after the fill, then a checkpoint (in vacuum()).
                vacuum(engine, where.direct_url)
            staff_key = make_keys(where.direct_url, 1, "staff", FLEET)[0]
            rng = random.Random(args.seed)
            sample = sorted(
                rng.sample(done.cloned_people, min(SAMPLE_CHECKED, len(done.cloned_people)))
            )
            before_checks = _served(service, staff_key, where.direct_url, sample)
            say(
                f"  cloned people checked: {before_checks['model_read_200']}/{len(sample)} models "
                f"read, {before_checks['rebuilt_identical']}/{len(sample)} rebuilt identical"
            )
            # Each robot: a person whose old history the run removes (spread over the fleet, so
            # the run reaches them at different times) and one with no old history.
            step = max(1, len(done.cloned_people) // max(args.robots, 1))
            folded = [
                done.cloned_people[min(i * step + step // 2, len(done.cloned_people) - 1)]
                for i in range(args.robots)
            ]
            keys = make_keys(where.direct_url, args.robots, "robot", FLEET)
            stop = threading.Event()
            robots = [
                Robot(
                    i,
                    service.url,
                    keys[i],
                    [(folded[i], "folded"), (f"bench-new-{i}", "other")],
                    args.interval_ms / 1000.0,
                    stop,
                    args.seed,
                )
                for i in range(args.robots)
            ]
            _set_window(service, staff_key, args.window_days)
            for robot in robots:
                robot.start()
            try:
                deadline = time.monotonic() + WARMUP_TIMEOUT_S * 2
                for robot in robots:
                    robot.warm.wait(max(0.0, deadline - time.monotonic()))
                time.sleep(args.warmup_seconds)
                say(
                    f"  baseline: {args.robots} robots for {args.baseline_seconds:g} s, "
                    "no retention run"
                )
                assert service.process is not None
                cpu0 = group_cpu_s(service.process.pid)
                base_start = time.monotonic()
                time.sleep(args.baseline_seconds)
                base_end = time.monotonic()
                cpu1 = group_cpu_s(service.process.pid)
                cutoff = dt.datetime.now(dt.UTC) - dt.timedelta(days=args.window_days)
                old_before = count_episodes(where.direct_url, cutoff)
                say(f"  retention run: {old_before:,} episodes older than {args.window_days} days")
                usage0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                run_start = time.monotonic()
                started_before = sum(r.started for r in robots)
                proc = subprocess.Popen(
                    _retention_command(args),
                    env=service.env,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE,
                    text=True,
                    start_new_session=True,
                )
                out_lines: list[str] = []
                err_lines: list[str] = []
                readers = [
                    threading.Thread(
                        target=lambda: out_lines.extend(proc.stdout or []), daemon=True
                    ),
                    threading.Thread(
                        target=lambda: err_lines.extend(proc.stderr or []), daemon=True
                    ),
                ]
                for t in readers:
                    t.start()
                interrupted = False
                last = time.monotonic()
                folds = _table(models.HistoryFold)
                while proc.poll() is None:
                    time.sleep(0.5)
                    now = time.monotonic()
                    if now - run_start > args.max_run_minutes * 60:
                        interrupted = True
                        _stop(proc)
                        break
                    if now - last >= args.progress_seconds:
                        last = now
                        so_far = latency([s for r in robots for s in r.sent], run_start, now)
                        say(
                            f"  … {now - run_start:,.0f} s: "
                            f"{count_rows(where.direct_url, folds):,} / "
                            f"{done.people:,} people folded; robots {so_far.rps:.0f} req/s, "
                            f"p50 {so_far.p50_ms:.1f} ms, p99 {so_far.p99_ms:.1f} ms"
                        )
                run_end = time.monotonic()
                cpu2 = group_cpu_s(service.process.pid)
                usage1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                for t in readers:
                    t.join(timeout=10)
                started_during = sum(r.started for r in robots) - started_before
            finally:
                stop.set()
                for robot in robots:
                    robot.join(timeout=REQUEST_TIMEOUT_S + 5)
            failures = [r.failure for r in robots if r.failure is not None]
            if failures:
                raise failures[0]
            if interrupted or proc.returncode != 0:
                raise RuntimeError(
                    "attune retention run "
                    + (
                        f"did not finish within {args.max_run_minutes} minutes (stopped)"
                        if interrupted
                        else f"failed ({proc.returncode})"
                    )
                    + ":\n"
                    + "".join(err_lines)[-4000:]
                )
            report = _report_figures(json.loads("".join(out_lines)))
            kept_from = dt.datetime.fromisoformat(report["kept_from"])
            left_old = count_episodes(where.direct_url, kept_from)
            after_checks = _served(service, staff_key, where.direct_url, sample)
            say(
                f"  after the run: {after_checks['model_read_200']}/{len(sample)} models read, "
                f"{after_checks['rebuilt_identical']}/{len(sample)} rebuilt identical"
            )
    sent = [s for r in robots for s in r.sent]
    base = latency(sent, base_start, base_end)
    during = latency(sent, run_start, run_end)
    by_group = {
        group: {
            "baseline": asdict(
                latency([s for s in sent if s.group == group], base_start, base_end)
            ),
            "during": asdict(latency([s for s in sent if s.group == group], run_start, run_end)),
        }
        for group in ("folded", "other")
    }
    run_cpu = (usage1.ru_utime - usage0.ru_utime) + (usage1.ru_stime - usage0.ru_stime)
    return {
        "place": where.note or "the database on this machine",
        "round_trip_ms": where.round_trip_ms,
        "workers": workers,
        "robots": args.robots,
        "interval_ms": args.interval_ms,
        "fill": _fill_json(done),
        "size_after_fill": sizes,
        "bytes_per_episode": sizes["bytes"] / max(done.episodes, 1),
        "baseline": asdict(base),
        "during": asdict(during),
        "by_group": by_group,
        "service_cpu_ms_per_request": {
            "baseline": (cpu1 - cpu0) * 1000 / max(base.requests, 1),
            "during": (cpu2 - cpu1) * 1000 / max(during.requests, 1),
        },
        "run": {
            **report,
            "wall_seconds": run_end - run_start,
            "cpu_seconds": run_cpu,
            "episodes_per_second": report["episodes_removed"] / max(run_end - run_start, 1e-9),
        },
        "check": {
            "old_episodes_before": old_before,
            "episodes_started_by_robots_during": started_during,
            "older_than_kept_from_left": left_old,
            "ok": report["episodes_removed"] == old_before and left_old == 0,
        },
        "served_before": before_checks,
        "served_after": after_checks,
    }


# -- the report -----------------------------------------------------------------------------------
def _mib(n: int | None) -> str:
    return "-" if n is None else f"{n / 2**20:,.1f} MiB"


def _ms(x: float) -> str:
    return "-" if math.isnan(x) else f"{x:,.1f}"


def _ratio(a: float, b: float) -> str:
    return "-" if math.isnan(a) or math.isnan(b) or not b else f"{a / b:.2f}×"


def render(doc: dict[str, Any]) -> str:
    lines: list[str] = []
    add = lines.append
    m = doc["machine"]
    add(
        f"Retention benchmark: {m['cpus']} CPUs ({m['cpu']}), {m['system']}, Python "
        f"{m['python']}; load average {m['load'][0]:.2f} before, {doc['load_after'][0]:.2f} "
        f"after; {doc['minutes']:.1f} min."
    )
    add(f"Command: {doc['command']}")
    for engine, parts in doc["engines"].items():
        add("")
        add(f"== {engine} ==")
        if "storage" in parts:
            st = parts["storage"]
            f = st["fill"]
            s = st["sizes"]
            n = f["episodes"]
            how = (
                "the database file + WAL after PRAGMA wal_checkpoint(TRUNCATE)"
                if engine == "sqlite"
                else "pg_database_size (the tables' pg_total_relation_size in brackets)"
            )
            add(
                f"Storage: {n:,} episodes of {f['people']:,} people, ages spread over "
                f"{f['ages_days'][0]:g}-{f['ages_days'][1]:g} days; sizes are {how}."
            )

            def show(label: str, sz: dict[str, int], episodes: int) -> None:
                extra = f" [{_mib(sz['tables_bytes'])}]" if "tables_bytes" in sz else ""
                free = (
                    f" ({_mib(sz['free_bytes'])} of it free pages)" if sz.get("free_bytes") else ""
                )
                add(
                    f"  {label:<46} {_mib(sz['bytes']):>14}{extra}{free}  "
                    f"{sz['bytes'] / max(episodes, 1):,.0f} B/episode kept"
                )

            kept = st["check"]["episodes_after"]
            show("no window: after the fill", s["after_fill"], n)
            show("no window: after VACUUM", s["after_vacuum"], n)
            show(f"{doc['window_days']}-day window: after the run", s["after_run"], kept)
            show(
                f"{doc['window_days']}-day window: after the run and VACUUM",
                s["after_run_vacuum"],
                kept,
            )
            if "after_run_vacuum_full" in s:
                show(
                    f"{doc['window_days']}-day window: after VACUUM FULL",
                    s["after_run_vacuum_full"],
                    kept,
                )
            r = st["run"]
            c = st["check"]
            final = s.get("after_run_vacuum_full", s["after_run_vacuum"])
            add(
                f"  the run removed {r['episodes_removed']:,} episodes and "
                f"{r['journal_removed']:,} journal entries of {r['people']:,} people in "
                f"{r['wall_seconds']:.1f} s; "
                f"{kept:,} episodes kept; the window's database is "
                f"{final['bytes'] / max(s['after_vacuum']['bytes'], 1):.2f} of the one without "
                f"(both vacuumed); check: removed = counted {c['removed_by_count']:,}, "
                f"{c['older_than_kept_from_left']} older than the window left: "
                + ("ok" if c["ok"] else "MISMATCH")
            )
        if "latency" in parts:
            la = parts["latency"]
            f = la["fill"]
            b, d = la["baseline"], la["during"]
            r = la["run"]
            add(
                f"Robots' latency: {la['robots']} robots (one request every "
                f"{la['interval_ms']:g} ms at most each), attune serve with {la['workers']} "
                f"worker(s), {la['place']}."
            )
            add(
                f"  the database: {f['episodes']:,} episodes of {f['people']:,} people, all "
                f"{f['ages_days'][0]:g}-{f['ages_days'][1]:g} days old "
                f"({f['template_people']} people played {f['template_episodes']:,} through the API "
                f"in {f['template_seconds']:.0f} s, cloned in SQL in {f['clone_seconds']:.0f} s); "
                f"{_mib(la['size_after_fill']['bytes'])}, "
                f"{la['bytes_per_episode']:,.0f} bytes per episode"
            )
            if f["not_cloned"]:
                add(
                    "  not cloned (their trial clone did not rebuild): "
                    + ", ".join(f"{p}: {why[:200]}" for p, why in f["not_cloned"].items())
                )
            add(
                "  each robot serves two people in turn: one whose old history the run folds and "
                "removes (spread over the fleet), and one of its own with no old history"
            )
            add(
                f"  {'':<22} {'requests':>9} {'req/s':>7} {'p50 ms':>8} {'p99 ms':>8} "
                f"{'max ms':>9} {'errors':>7}"
            )
            for label, x in (("baseline (no run)", b), ("during the run", d)):
                add(
                    f"  {label:<22} {x['requests']:>9,} {x['rps']:>7.1f} {_ms(x['p50_ms']):>8} "
                    f"{_ms(x['p99_ms']):>8} {_ms(x['max_ms']):>9} {x['errors']:>7}"
                )
            add(
                f"  {'during / baseline':<22} {'':>9} {_ratio(d['rps'], b['rps']):>7} "
                f"{_ratio(d['p50_ms'], b['p50_ms']):>8} {_ratio(d['p99_ms'], b['p99_ms']):>8} "
                f"{_ratio(d['max_ms'], b['max_ms']):>9}"
            )
            for group, label in (
                ("folded", "people being folded"),
                ("other", "people with no old history"),
            ):
                g = la["by_group"][group]
                add(
                    f"    {label}: p50 {_ms(g['baseline']['p50_ms'])} → "
                    f"{_ms(g['during']['p50_ms'])} ms, "
                    f"p99 {_ms(g['baseline']['p99_ms'])} → {_ms(g['during']['p99_ms'])} ms"
                )
            cpu = la["service_cpu_ms_per_request"]
            add(
                f"  the service's CPU per request: {cpu['baseline']:.2f} ms baseline, "
                f"{cpu['during']:.2f} ms during"
            )
            c = la["check"]
            add(
                f"  the run: {r['wall_seconds']:,.1f} s ({r['seconds']:,.1f} s by its report), "
                f"{r['cpu_seconds']:,.1f} s CPU, {r['episodes_removed']:,} episodes "
                f"({r['episodes_per_second']:,.0f} a second) and {r['journal_removed']:,} journal "
                f"entries removed, {r['people']:,} people walked, {r['folded']:,} folded, "
                f"{r['skipped']} changed under it"
            )
            add(
                f"  check: {c['old_episodes_before']:,} episodes older than the window before the "
                f"run, {r['episodes_removed']:,} removed, {c['older_than_kept_from_left']} left; "
                f"{c['episodes_started_by_robots_during']:,} started by the robots during it "
                "(kept): " + ("ok" if c["ok"] else "MISMATCH")
            )
            sb, sa = la["served_before"], la["served_after"]
            k = len(sb["people"])
            add(
                f"  cloned people ({', '.join(sb['people'])}): models read "
                f"{sb['model_read_200']}/{k} "
                f"and rebuilt identical {sb['rebuilt_identical']}/{k} after the fill; "
                f"{sa['model_read_200']}/{k} and {sa['rebuilt_identical']}/{k} after the run"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bench/retention.py",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--engine",
        choices=("sqlite", "postgresql", "both"),
        default="both",
        help="the database engine (default both, one after the other)",
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=1_000_000,
        help="old episodes the measured retention run removes (default 1,000,000)",
    )
    parser.add_argument(
        "--storage-episodes",
        type=int,
        default=100_000,
        help="episodes of the storage database (default 100,000)",
    )
    parser.add_argument(
        "--parts", default="storage,latency", help="storage, latency or both (default)"
    )
    parser.add_argument(
        "--window-days", type=int, default=30, help="the fleet's window (default 30)"
    )
    parser.add_argument(
        "--storage-days",
        type=float,
        default=120.0,
        help="days the episodes' ages are spread over (default 120)",
    )
    parser.add_argument(
        "--robots", type=int, default=8, help="robots during the latency part (default 8)"
    )
    parser.add_argument(
        "--interval-ms",
        type=float,
        default=100.0,
        help="a robot sends one request every this many ms at most (default 100)",
    )
    parser.add_argument(
        "--baseline-seconds", type=float, default=30.0, help="the baseline window (default 30)"
    )
    parser.add_argument(
        "--warmup-seconds",
        type=float,
        default=3.0,
        help="robots' load before the baseline (default 3)",
    )
    parser.add_argument(
        "--max-run-minutes",
        type=float,
        default=120.0,
        help="stop a retention run still going after this (default 120)",
    )
    parser.add_argument(
        "--batch",
        type=int,
        help="the run's --batch (default: the service's, ATTUNE_RETENTION_BATCH)",
    )
    parser.add_argument(
        "--workers", type=int, help="attune serve's workers (default 1 on SQLite, 2 on PostgreSQL)"
    )
    parser.add_argument(
        "--template-people",
        type=int,
        default=20,
        help="people who play through the API (default 20)",
    )
    parser.add_argument(
        "--template-episodes",
        type=int,
        default=2_000,
        help="episodes they play in all (default 2,000)",
    )
    parser.add_argument(
        "--template-robots", type=int, default=4, help="robots that play them (default 4)"
    )
    parser.add_argument(
        "--delay", type=float, help="PostgreSQL: ms each way between the service and the database"
    )
    parser.add_argument(
        "--pooler",
        choices=("none", "pgbouncer"),
        default="none",
        help="PostgreSQL: pgbouncer puts PgBouncer (transaction pooling) beside the database",
    )
    parser.add_argument(
        "--progress-seconds",
        type=float,
        default=30.0,
        help="a progress line this often during the run (default 30)",
    )
    parser.add_argument(
        "--seed", type=int, default=1, help="the people's and robots' draws (default 1)"
    )
    parser.add_argument(
        "--json", action="store_true", help="print one JSON document instead of the text"
    )
    args = parser.parse_args(argv)
    engines = ["sqlite", "postgresql"] if args.engine == "both" else [args.engine]
    parts = {p.strip() for p in args.parts.split(",") if p.strip()}
    if not parts or parts - {"storage", "latency"}:
        parser.error("--parts takes storage, latency or both")
    if (args.delay is not None or args.pooler != "none") and "sqlite" in engines:
        parser.error("--delay and --pooler are for --engine postgresql")
    if args.template_people < 2 or args.template_episodes < args.template_people:
        parser.error("--template-people must be at least 2, with at least one episode each")
    if min(args.episodes, args.storage_episodes) < args.template_episodes:
        parser.error("--episodes and --storage-episodes must be at least --template-episodes")
    if args.robots < 1 or args.interval_ms < 0:
        parser.error("--robots must be at least 1, --interval-ms at least 0")
    before = machine()
    began = time.monotonic()
    doc: dict[str, Any] = {
        "machine": before,
        "command": " ".join(["bench/retention.py", *(sys.argv[1:] if argv is None else argv)]),
        "window_days": args.window_days,
        "engines": {},
    }
    try:
        for engine in engines:
            found: dict[str, Any] = {}
            with tempfile.TemporaryDirectory(prefix="attune-retention-") as tmp:
                if "storage" in parts:
                    sub = Path(tmp) / "storage"
                    sub.mkdir()
                    found["storage"] = storage(engine, args, sub)
                if "latency" in parts:
                    sub = Path(tmp) / "latency"
                    sub.mkdir()
                    found["latency"] = robots_latency(engine, args, sub)
            doc["engines"][engine] = found
    except (PgBouncerFailed, CloneRefused) as failure:
        print(f"bench/retention.py: {failure}", file=sys.stderr)
        return 2
    doc["load_after"] = os.getloadavg()
    doc["minutes"] = (time.monotonic() - began) / 60
    if args.json:
        print(json.dumps(doc, indent=1, default=str))
    else:
        print(render(doc))
    checks = [part["check"]["ok"] for parts_ in doc["engines"].values() for part in parts_.values()]
    return 0 if all(checks) else 1


if __name__ == "__main__":
    sys.exit(main())
