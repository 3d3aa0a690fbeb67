"""The harness of the migration tests: the previous release, served as it was, fills a database
through its API; this code upgrades it, and the test compares.

- ``release_code(previous_release(MIGRATION, ...), folder)``: the previous release's ``app`` and
  ``migrations`` taken from git (the commit before the one that added a migration, or the
  change's first files).
- ``filled(engine, code, folder, fill=..., view=..., rows=..., at=BEFORE)``: a fresh database
  of ``engine``, ``attune serve`` of that code on it (:class:`OldService`), ``fill(old)`` to
  make what a deployment holds through its API, then what its API shows (``view``, with the
  admin key ``fill`` made) and the rows of its tables (``rows``), once its schema is checked to
  be at ``at``: a :class:`Filled`, for the test to upgrade and compare.
- For ``fill``: :func:`clients` (keys made with the old command line, and a client for each),
  :func:`history` (episodes played by a cooperative person, :func:`run_episode`, with feedback
  after every fourth), :func:`leave_open` (an episode left open).
- For the comparisons: :func:`table_rows`, :func:`scalars`, :func:`revision`, :func:`without`.
"""

from __future__ import annotations

import copy
import datetime as dt
import os
import signal
import subprocess
import sys
import tarfile
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any, NamedTuple

import httpx
from sqlalchemy import create_engine, inspect, text

from tests.support import episodes
from tests.support.live import free_port, fresh_database

__all__ = [
    "REPO",
    "Filled",
    "OldService",
    "clients",
    "comparable_model",
    "filled",
    "history",
    "leave_open",
    "person",
    "previous_release",
    "run_episode",
    "release_code",
    "revision",
    "scalars",
    "table_rows",
    "table_names",
    "without",
]

REPO = Path(__file__).resolve().parents[2]


def _git(*args: str) -> str:
    return subprocess.run(
        ["git", *args], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.strip()


def previous_release(*paths: str) -> str:
    """The commit before the first that added any of ``paths`` (a change's migration and the
    first files of that change), HEAD while none is committed."""
    added = _git("log", "--diff-filter=A", "--format=%H", "--", *paths).splitlines()
    return f"{added[-1]}^" if added else "HEAD"


class OldService:
    """``attune serve`` of the previous release, on ``url`` (its own code first on the path)."""

    def __init__(self, code: Path, url: str, log: Path) -> None:
        self.code, self.url, self.log = code, url, log
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.env = {
            **os.environ,
            "ATTUNE_DATABASE_URL": url,
            "ATTUNE_SEED": "0",
            "ATTUNE_LOG_LEVEL": "warning",
            "PYTHONPATH": str(code),
        }
        self.process: subprocess.Popen[bytes] | None = None

    def attune(self, *args: str) -> str:
        done = subprocess.run(
            [
                sys.executable,
                "-c",
                "import sys; from app.cli import main; sys.argv[0] = 'attune'; main()",
                *args,
            ],
            cwd=self.code,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        assert done.returncode == 0, done.stderr
        return done.stdout

    def __enter__(self) -> OldService:
        with open(self.log, "wb") as out:
            self.process = subprocess.Popen(
                [
                    sys.executable,
                    "-c",
                    "import sys; from app.cli import main; sys.argv[0] = 'attune'; main()",
                    "serve",
                    "--port",
                    str(self.port),
                ],
                cwd=self.code,
                env=self.env,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        deadline = time.monotonic() + 90
        while True:
            assert self.process.poll() is None, self.log.read_text()
            try:
                if httpx.get(f"{self.base}/readyz", timeout=2).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, self.log.read_text()
            time.sleep(0.2)

    def __exit__(self, *exc: object) -> None:
        assert self.process is not None
        os.killpg(self.process.pid, signal.SIGTERM)
        self.process.wait(timeout=30)


DETAIL = {"ProvideDrink": "tea", "BriefInformation": "news", "ArrangeSchedule": "today_agenda"}
SITUATIONS = ("arriving", "working", "stretching")


def person(n: int) -> episodes.Person:
    """The cooperative person of episode ``n``: asks for a drink when the robot waits (two
    times in three), wants the news when asked which service, names a service's first detail,
    and says yes but to one offer in five."""

    def answers(decision: dict[str, Any]) -> dict[str, Any]:
        kind = decision["action"]["kind"]
        if kind == "pass":
            return (
                {"response": "human_request", "service": "ProvideDrink"}
                if n % 3
                else {"response": "none"}
            )
        if kind == "query_type":
            return {"response": "answered", "service": "BriefInformation"}
        if kind == "query_detail":
            return {"response": "answered", "detail": DETAIL[decision["action"]["service"]]}
        return {"response": "rejected" if n % 5 == 4 else "accepted"}

    return answers


def run_episode(api: httpx.Client, user: str, event: str, n: int) -> str:
    """Episode ``n`` of ``user`` played to its end by ``person(n)`` (its time and situation
    vary with ``n``); its id."""
    hour = (7, 12, 15, 19)[n % 4]
    played = episodes.play(
        api,
        user,
        event,
        person(n),
        occurred_at=f"2026-11-{1 + n % 28:02d}T{hour:02d}:10:00+08:00",
        situation=SITUATIONS[n % 3],
        robot_id="r1",
    )
    return played.episode_id


def history(api: httpx.Client, user: str, count: int, n: int) -> int:
    """``count`` episodes of ``user``, numbered from ``n`` (:func:`run_episode`; event ids
    ``USER-eN``), and positive feedback after every fourth episode of the fill; the next number."""
    for _ in range(count):
        episode_id = run_episode(api, user, f"{user}-e{n}", n)
        n += 1
        if n % 4 == 0:
            r = api.post(
                f"/v1/episodes/{episode_id}/feedback",
                json={"feedback_id": f"fb-{n}", "feedback": "positive"},
            )
            assert r.status_code == 200, r.text
    return n


def leave_open(api: httpx.Client, user: str, situation: str = "stretching") -> dict[str, Any]:
    """An episode of ``user`` that nobody answers (event ``left-open``): the previous release's
    answer to it (its id and first decision), for the test to finish after the upgrade."""
    r = api.post(
        f"/v1/users/{user}/episodes",
        json={
            "event_id": "left-open",
            "occurred_at": "2026-11-20T15:10:00+08:00",
            "situation": situation,
            "initiator": "robot",
        },
    )
    assert r.status_code == 201, r.text
    opened: dict[str, Any] = r.json()
    return opened


@contextmanager
def clients(
    old: OldService, keys: Mapping[str, tuple[str, str | None]]
) -> Iterator[tuple[dict[str, str], dict[str, httpx.Client]]]:
    """For each name of ``keys``, a key of (role, fleet or None: the default) made with the old
    command line, and a client of the old service with it: (the secrets, the clients), the
    clients closed at the end."""
    secrets = {}
    for name, (role, fleet) in keys.items():
        where = [] if fleet is None else ["--fleet", fleet]
        secrets[name] = old.attune("keys", "create", "--role", role, *where).split()[-1]
    with ExitStack() as stack:
        made = {
            name: stack.enter_context(
                httpx.Client(
                    base_url=old.base, timeout=30, headers={"Authorization": f"Bearer {secret}"}
                )
            )
            for name, secret in secrets.items()
        }
        yield secrets, made


class Filled(NamedTuple):
    """A database at the previous release's head, filled through its API: its URL, what
    ``fill`` returned (``keys`` among it), what the API showed (``before``), the tables the
    previous release had and their rows."""

    url: str
    names: dict[str, Any]
    before: dict[str, Any]
    tables: list[str]
    rows: dict[str, list[tuple[Any, ...]]]


@contextmanager
def filled(
    engine: str,
    code: Path,
    folder: Path,
    *,
    fill: Callable[[OldService], dict[str, Any]],
    view: Callable[[httpx.Client], dict[str, Any]],
    rows: Callable[[str, list[str]], dict[str, list[tuple[Any, ...]]]],
    at: str,
) -> Iterator[Filled]:
    """A fresh database of ``engine`` (``sqlite``, ``postgresql``) filled by the previous
    release in ``code`` (see the module); dropped at the end."""
    from app.settings import Settings

    with fresh_database(engine, folder) as url:
        url = Settings(database_url=url, _env_file=None).database_url  # type: ignore[call-arg]
        with OldService(code, url, folder / "old.log") as old:
            names = fill(old)
            with httpx.Client(
                base_url=old.base,
                timeout=30,
                headers={"Authorization": f"Bearer {names['keys']['admin']}"},
            ) as admin:
                before = view(admin)
        assert revision(url) == at
        tables = table_names(url)
        yield Filled(url, names, before, tables, rows(url, tables))


def release_code(commit: str, folder: Path) -> Path:
    """``app`` and ``migrations`` of ``commit``, extracted into ``folder``."""
    archive = folder / "release.tar"
    subprocess.run(
        ["git", "archive", "--format=tar", "-o", str(archive), commit, "app", "migrations"],
        cwd=REPO,
        check=True,
    )
    with tarfile.open(archive) as tar:
        tar.extractall(folder, filter="data")
    assert (folder / "migrations" / "versions").is_dir()
    return folder


Row = dict[str, Any]


def table_rows(
    url: str,
    tables: Iterable[str],
    *,
    leave_out: Iterable[str] = (),
    rewrite: Callable[[str, Row], None] | None = None,
) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of ``tables`` as sorted (column, value) pairs, the rows sorted, for comparing
    a database before and after a migration: the columns ``leave_out`` names (a later
    release's) are left out, times are compared without their zone (the engines give them
    differently), and ``rewrite(table, row)`` may change a row in place first. A table a later
    release renamed and reshaped (``samples``, now ``journal``) is read in its old form."""
    skip = set(leave_out)
    engine = create_engine(url)
    out: dict[str, list[tuple[Any, ...]]] = {}
    try:
        with engine.connect() as conn:
            stored = set(inspect(conn).get_table_names())
            for table in tables:
                rows = []
                if table == "samples" and "samples" not in stored and "journal" in stored:
                    found_rows = _samples_of_journal(conn)
                else:
                    found_rows = [
                        dict(r) for r in conn.execute(text(f"SELECT * FROM {table}")).mappings()
                    ]
                for found in found_rows:
                    row = {k: v for k, v in found.items() if k not in skip}
                    if rewrite is not None:
                        rewrite(table, row)
                    rows.append(tuple(sorted((k, _plain(v)) for k, v in row.items())))
                out[table] = sorted(rows, key=repr)
    finally:
        engine.dispose()
    return out


def _samples_of_journal(conn: Any) -> list[dict[str, Any]]:
    """The rows of ``journal`` in the form ``samples`` had before the journal was typed (what
    its migration's downgrade writes back; its new kinds had no place there)."""
    out = []
    for row in conn.execute(
        text("SELECT * FROM journal WHERE kind NOT IN ('reset', 'import', 'fold')")
    ).mappings():
        correction = row["kind"] in ("correction", "lift")
        out.append(
            {
                "id": row["id"],
                "user_pk": row["user_pk"],
                "version": row["version"],
                "kind": row["kind"],
                "episode": row["since"] if correction else row["episode"] or 0,
                "context": row["context"] or 0,
                "state": row["state"] or 0,
                "action": row["correction_pk"] if correction else row["action"] or 0,
                "reward": row["reward"] or 0.0,
                "next_state": row["next_state"],
                "signal": row["signal"] or 0,
                "mission_version": row["mission_version"],
            }
        )
    return out


def _plain(value: Any) -> Any:
    if isinstance(value, dt.datetime):
        return value.replace(tzinfo=None).isoformat()
    return value


def scalars(url: str, sql: str) -> list[Any]:
    """The first column of ``sql``'s rows on the database at ``url``."""
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            return list(conn.execute(text(sql)).scalars().all())
    finally:
        engine.dispose()


# Tables a later release renamed: their name in the releases before.
RENAMED_SINCE = {"journal": "samples"}


def table_names(url: str, *, as_stored: bool = False) -> list[str]:
    """The tables of the database at ``url`` (its schema's), sorted, without Alembic's own;
    a table a later release renamed under the name the earlier releases gave it (unless
    ``as_stored``)."""
    engine = create_engine(url)
    try:
        names = [t for t in inspect(engine).get_table_names() if t != "alembic_version"]
    finally:
        engine.dispose()
    return sorted(names if as_stored else [RENAMED_SINCE.get(t, t) for t in names])


def without(doc: dict[str, Any], *names: str) -> dict[str, Any]:
    """``doc`` without the fields ``names`` (a later release's, for comparing with the API of
    the previous one)."""
    return {k: v for k, v in doc.items() if k not in names}


LATER_FIELDS = {"profile": ("rollout",)}
"""Fields a later release added to a read (``GET .../profile``'s ``rollout``, the person's arm in a
rollout): left out when a test compares what a release before it showed with what a newer one
shows."""


def later_fields_out(what: str, doc: Any) -> Any:
    """``doc``, read from ``GET /v1/users/{id}/{what}``, without the fields later releases added."""
    names = LATER_FIELDS.get(what, ())
    return without(doc, *names) if names and isinstance(doc, dict) else doc


def revision(url: str) -> str | None:
    """The database's Alembic revision."""
    from app.db import migrate

    engine = create_engine(url)
    try:
        return migrate.current_revision(engine)
    finally:
        engine.dispose()


def comparable_model(
    model: dict[str, Any], unavailable: tuple[str, ...] = ("busy",)
) -> dict[str, Any]:
    """A model view of ``GET /v1/users/{id}/model`` as an earlier release can show it too: the
    robot's choice when it notices the person in a do-not-disturb situation (``unavailable``, the
    office mission's ``busy``) is a rule of later releases, not the learner's, so the OBSERVE
    probabilities there are left out."""
    out = copy.deepcopy(model)
    for context in out.get("contexts", []):
        if context["situation"] not in unavailable:
            continue
        for state in context["states"]:
            if state["state"] != "OBSERVE":
                continue
            for action in state["actions"]:
                action.pop("p")
    return out


# Fields the API added after a release: a view read from that release lacks them.
ADDED_SINCE = {"stats": ("history_from",)}


def stats(api: Any, user_id: str, params: Any = None) -> dict[str, Any]:
    """``GET /v1/users/{id}/stats`` without the fields added since the releases compared."""
    doc: dict[str, Any] = api.get(f"/v1/users/{user_id}/stats", params=params).json()
    for name in ADDED_SINCE["stats"]:
        doc.pop(name, None)
    return doc
