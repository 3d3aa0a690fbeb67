"""The offline outbox: outcome and feedback reports kept in a local SQLite file until the
service takes them.

The file holds two tables. ``outbox`` is the queue, in report order (``seq``, never reused);
``rejected`` keeps the reports the service refused for good, with its reason. The database runs
in WAL mode with ``synchronous=FULL``, so a report that was queued survives a crash or a power
loss of the robot.

Delivering the head of the queue happens inside ``BEGIN IMMEDIATE ... COMMIT``: the write lock
is held from reading the head until it is deleted, so two processes (or threads) on the same
file never send the same report at the same time, and the order holds across them. A report is
deleted only after the service acknowledged it; a crash in between rolls the transaction back
and the report is sent again, which the service answers as a replay.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from ._exceptions import OutboxError
from ._models import PendingReport, Queued, Rejection, ReportKind

__all__ = ["Outbox"]

_SCHEMA = (
    """CREATE TABLE IF NOT EXISTS outbox (
        seq INTEGER PRIMARY KEY AUTOINCREMENT,
        kind TEXT NOT NULL CHECK (kind IN ('outcome', 'feedback')),
        episode_id TEXT NOT NULL,
        key TEXT NOT NULL,
        body TEXT NOT NULL,
        queued_at TEXT NOT NULL,
        attempts INTEGER NOT NULL DEFAULT 0,
        last_error TEXT)""",
    "CREATE INDEX IF NOT EXISTS outbox_report ON outbox (kind, episode_id, key)",
    """CREATE TABLE IF NOT EXISTS rejected (
        seq INTEGER PRIMARY KEY,
        kind TEXT NOT NULL,
        episode_id TEXT NOT NULL,
        key TEXT NOT NULL,
        body TEXT NOT NULL,
        queued_at TEXT NOT NULL,
        attempts INTEGER NOT NULL,
        last_error TEXT,
        status_code INTEGER NOT NULL,
        error TEXT NOT NULL,
        detail TEXT NOT NULL,
        fields TEXT,
        request_id TEXT,
        rejected_at TEXT NOT NULL)""",
)
_COLUMNS = "seq, kind, episode_id, key, body, queued_at, attempts, last_error"
_SCHEMA_VERSION = 1
_SKIP_WAIT_MS = 200  # how long a delivery that may be skipped waits for another's write lock


def _now() -> str:
    return dt.datetime.now(dt.UTC).isoformat()


def _report(row: tuple[Any, ...]) -> PendingReport:
    seq, kind, episode_id, key, body, queued_at, attempts, last_error = row[:8]
    return PendingReport(
        seq=seq,
        kind=kind,
        episode_id=episode_id,
        key=key,
        body=json.loads(body),
        queued_at=dt.datetime.fromisoformat(queued_at),
        attempts=attempts,
        last_error=last_error,
    )


def _why(path: str, exc: sqlite3.Error) -> str:
    """Why SQLite could not open or set up ``path``, in words a robot's operator can act on."""
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        return "that is a folder; give the path of a file in it"
    if not os.path.exists(folder):
        return f"its folder {folder} does not exist (the client does not create folders)"
    if not os.path.isdir(folder):
        return f"{folder} is not a folder"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"its folder {folder} is not writable (the outbox keeps journal files beside it)"
    if os.path.exists(path) and not os.access(path, os.R_OK | os.W_OK):
        return "the file is not readable and writable"
    return f"SQLite says: {exc}"


class Outbox:
    """A queue of reports in the SQLite file at ``path`` (created if absent; its folder must
    exist and be writable, else ``OutboxError``).

    The methods that write (``append``, ``begin`` ... ``commit``) are meant to be called by one
    thread at a time; the client serialises them with its own lock. ``entries``, ``rejected``
    and ``count`` read through a second connection and may be called from anywhere.
    """

    def __init__(self, path: str | os.PathLike[str], *, busy_timeout: float = 120.0) -> None:
        self.path = os.fspath(path)
        self._busy_ms = int(busy_timeout * 1000)
        self._read_lock = threading.Lock()
        self._in_transaction = False
        opened: list[sqlite3.Connection] = []
        try:
            opened.append(self._connect())
            opened.append(self._connect())
            self._writer, self._reader = opened
            with self._transaction():
                for statement in _SCHEMA:  # not executescript(), which would commit first
                    self._writer.execute(statement)
                self._writer.execute(f"PRAGMA user_version = {_SCHEMA_VERSION}")
        except sqlite3.Error as exc:
            for conn in opened:
                conn.close()
            raise OutboxError(
                f"Cannot open the outbox {self.path!r}: {_why(self.path, exc)}.", path=self.path
            ) from exc

    def _connect(self) -> sqlite3.Connection:
        conn = sqlite3.connect(
            self.path, timeout=self._busy_ms / 1000, isolation_level=None, check_same_thread=False
        )
        conn.execute("PRAGMA journal_mode = WAL")
        conn.execute("PRAGMA synchronous = FULL")
        return conn

    @contextmanager
    def _transaction(self) -> Iterator[None]:
        self._writer.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            self._writer.execute("ROLLBACK")
            raise
        self._writer.execute("COMMIT")

    def close(self) -> None:
        """Close the file (a transaction still open is rolled back)."""
        self._writer.close()
        self._reader.close()

    # -- queueing ----------------------------------------------------------------------------
    def append(
        self,
        kind: ReportKind,
        episode_id: str,
        key: str,
        body: bytes,
        *,
        attempts: int = 0,
        last_error: str | None = None,
    ) -> Queued:
        """Queue a report behind the others. The same report queued twice (same kind, episode,
        key and body) stays one entry."""
        text = body.decode()
        with self._transaction():
            row = self._writer.execute(
                "SELECT seq FROM outbox WHERE kind = ? AND episode_id = ? AND key = ? "
                "AND body = ? ORDER BY seq LIMIT 1",
                (kind, episode_id, key, text),
            ).fetchone()
            if row is not None:
                seq = row[0]
            else:
                cur = self._writer.execute(
                    "INSERT INTO outbox (kind, episode_id, key, body, queued_at, attempts, "
                    "last_error) VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (kind, episode_id, key, text, _now(), attempts, last_error),
                )
                seq = cur.lastrowid
            (position,) = self._writer.execute(
                "SELECT COUNT(*) FROM outbox WHERE seq <= ?", (seq,)
            ).fetchone()
        return Queued(kind=kind, episode_id=episode_id, key=key, position=position)

    # -- delivering (between begin() and commit() or rollback()) -------------------------------
    def begin(self, *, wait: bool) -> bool:
        """Take the write lock for delivering the head. With ``wait=False``, give up (and return
        False) if another process or thread is delivering at this moment."""
        if not wait:
            self._writer.execute(f"PRAGMA busy_timeout = {_SKIP_WAIT_MS}")
        try:
            self._writer.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            if wait or "locked" not in str(exc) and "busy" not in str(exc):
                raise
            return False
        finally:
            if not wait:
                self._writer.execute(f"PRAGMA busy_timeout = {self._busy_ms}")
        self._in_transaction = True
        return True

    def head(self) -> tuple[PendingReport, bytes] | None:
        """The oldest report and the exact body to send, or None when the queue is empty."""
        row = self._writer.execute(f"SELECT {_COLUMNS} FROM outbox ORDER BY seq LIMIT 1").fetchone()
        if row is None:
            return None
        return _report(row), str(row[4]).encode()

    def remove(self, seq: int) -> None:
        self._writer.execute("DELETE FROM outbox WHERE seq = ?", (seq,))

    def reject(self, entry: PendingReport, rejection: Rejection) -> None:
        """Move a report the service refused for good out of the queue, with the reason."""
        self._writer.execute(
            f"INSERT OR REPLACE INTO rejected ({_COLUMNS}, status_code, error, detail, fields, "
            "request_id, rejected_at) SELECT "
            f"{_COLUMNS}, ?, ?, ?, ?, ?, ? FROM outbox WHERE seq = ?",
            (
                rejection.status_code,
                rejection.error,
                rejection.detail,
                None if rejection.fields is None else json.dumps(rejection.fields),
                rejection.request_id,
                rejection.rejected_at.isoformat(),
                entry.seq,
            ),
        )
        self.remove(entry.seq)

    def note_failure(self, seq: int, error: str, attempts: int) -> None:
        """Count the failed requests of a delivery of a report that stays queued."""
        self._writer.execute(
            "UPDATE outbox SET attempts = attempts + ?, last_error = ? WHERE seq = ?",
            (attempts, error, seq),
        )

    def commit(self) -> None:
        self._in_transaction = False
        self._writer.execute("COMMIT")

    def rollback(self) -> None:
        if self._in_transaction:
            self._in_transaction = False
            self._writer.execute("ROLLBACK")

    # -- reading -------------------------------------------------------------------------------
    def count(self) -> int:
        """How many reports are queued."""
        with self._read_lock:
            (n,) = self._reader.execute("SELECT COUNT(*) FROM outbox").fetchone()
        return int(n)

    def entries(self) -> list[PendingReport]:
        """The queued reports, oldest first."""
        with self._read_lock:
            rows = self._reader.execute(f"SELECT {_COLUMNS} FROM outbox ORDER BY seq").fetchall()
        return [_report(row) for row in rows]

    def rejected(self) -> list[tuple[PendingReport, Rejection]]:
        """The reports the service refused for good, oldest first, with the reasons."""
        with self._read_lock:
            rows = self._reader.execute(
                f"SELECT {_COLUMNS}, status_code, error, detail, fields, request_id, "
                "rejected_at FROM rejected ORDER BY seq"
            ).fetchall()
        return [
            (
                _report(row),
                Rejection(
                    status_code=row[8],
                    error=row[9],
                    detail=row[10],
                    fields=None if row[11] is None else json.loads(row[11]),
                    request_id=row[12],
                    rejected_at=dt.datetime.fromisoformat(row[13]),
                ),
            )
            for row in rows
        ]
