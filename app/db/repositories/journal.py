"""The model's journal: what changed a person's learner model, version by version.

Every entry is a record of its own kind with named fields (no column means one thing for one
kind and another for the next). A model version is one of:

- one ``update`` call: its :class:`Transition` entries (an outcome's steps);
- one :class:`Feedback` (explicit feedback taught on a step);
- one :class:`Correction` or :class:`Lift` (a staff correction put in force or lifted);
- one :class:`MissionMove` (the model carried to another version of the fleet's mission);
- one :class:`Reset` or :class:`Import` (the model started over: a reset, a new learner, an
  imported document): a *base*, where a rebuild starts, never replayed;

and a retention run leaves a :class:`Fold` at the version its fold moved the base to (also a
base: the journal up to it was folded into the model's stored base and removed).

Replaying the entries after the model's ``base_version`` onto its base gives the model; those
after ``state_version`` onto the stored snapshot give it too (``app.services.person_model``).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from sqlalchemy import bindparam, delete, insert, or_, select
from sqlalchemy.orm import Session

from ..models import JournalEntry
from ._rows import Prepared, conn, table

__all__ = [
    "BASE_KINDS",
    "Correction",
    "Entry",
    "Feedback",
    "Fold",
    "Import",
    "Lift",
    "MissionMove",
    "Reset",
    "Transition",
    "append",
    "delete_folded",
    "entries_between",
    "entries_since",
    "has_transition",
    "versions",
]


@dataclass(frozen=True, slots=True)
class Transition:
    """A step the learner was taught: in ``context``, from ``state`` by ``action`` to
    ``next_state`` with ``reward`` (and the person's ``signal``: a
    :class:`app.learning.Polarity` value), in the learner's episode ``episode``."""

    kind: ClassVar[str] = "transition"
    version: int
    mission_version: int  # whose layout the indices are in
    episode: int
    context: int
    state: int
    action: int
    reward: float
    next_state: int
    signal: int


@dataclass(frozen=True, slots=True)
class Feedback:
    """Explicit feedback taught on the step of ``episode`` that took ``action`` from ``state``
    in ``context``: ``reward`` more."""

    kind: ClassVar[str] = "feedback"
    version: int
    mission_version: int
    episode: int
    context: int
    state: int
    action: int
    reward: float


@dataclass(frozen=True, slots=True)
class Correction:
    """A staff correction put in force: the stored correction ``correction_pk``, made when
    the learner had seen ``since`` episodes, about ``context`` (0 if the mission has no such
    context any more)."""

    kind: ClassVar[str] = "correction"
    version: int
    mission_version: int
    correction_pk: int
    since: int
    context: int


@dataclass(frozen=True, slots=True)
class Lift:
    """A staff correction lifted (``correction_pk``, when the learner had seen ``since``
    episodes)."""

    kind: ClassVar[str] = "lift"
    version: int
    mission_version: int
    correction_pk: int
    since: int
    context: int


@dataclass(frozen=True, slots=True)
class MissionMove:
    """The model carried to version ``mission_version`` of its fleet's mission (what still
    applies kept, the rest dropped)."""

    kind: ClassVar[str] = "mission"
    version: int
    mission_version: int


@dataclass(frozen=True, slots=True)
class Reset:
    """The model started over as a fresh learner of ``algorithm`` (``cause``: ``"reset"``,
    staff forgot what was learned; ``"learner"``, staff chose another learner), keeping
    ``corrections_kept`` staff corrections in force; by ``actor`` (a key id, or ``"cli"``)."""

    kind: ClassVar[str] = "reset"
    version: int
    mission_version: int
    actor: str
    algorithm: str
    cause: str
    corrections_kept: int


@dataclass(frozen=True, slots=True)
class Import:
    """The model replaced by an imported learner document of ``algorithm`` that had seen
    ``episodes`` episodes; by ``actor``."""

    kind: ClassVar[str] = "import"
    version: int
    mission_version: int
    actor: str
    algorithm: str
    episodes: int


@dataclass(frozen=True, slots=True)
class Fold:
    """A retention run folded the journal up to ``version`` (and the person's episodes up to
    ``upto_seq``, received before ``kept_from``) into the model's base."""

    kind: ClassVar[str] = "fold"
    version: int
    mission_version: int
    upto_seq: int
    kept_from: dt.datetime


Entry = Transition | Feedback | Correction | Lift | MissionMove | Reset | Import | Fold
BASE_KINDS = frozenset({Reset.kind, Import.kind, Fold.kind})
_KINDS: dict[str, type[Any]] = {
    cls.kind: cls
    for cls in (Transition, Feedback, Correction, Lift, MissionMove, Reset, Import, Fold)
}
# The kinds whose fields are columns of their own; the bases' fields are in ``detail``.
_COLUMNS = (
    "episode",
    "context",
    "state",
    "action",
    "reward",
    "next_state",
    "signal",
    "correction_pk",
    "since",
)
_DETAIL: dict[str, tuple[str, ...]] = {
    Reset.kind: ("actor", "algorithm", "cause", "corrections_kept"),
    Import.kind: ("actor", "algorithm", "episodes"),
    Fold.kind: ("upto_seq", "kept_from"),
}

_journal = table(JournalEntry)
_READ = (_journal.c.kind, _journal.c.version, _journal.c.mission_version) + tuple(
    _journal.c[name] for name in (*_COLUMNS, "detail")
)
_INSERT = Prepared(insert(_journal), keyed=True)
_SINCE = Prepared(
    select(*_READ)
    .where(_journal.c.user_pk == bindparam("user_pk"), _journal.c.version > bindparam("version"))
    .order_by(_journal.c.version, _journal.c.id)
)


def _row(user_pk: int, entry: Entry) -> dict[str, Any]:
    """The columns of an entry (every column named, so that one statement inserts any mix)."""
    out: dict[str, Any] = dict.fromkeys(_COLUMNS)
    out.update(
        user_pk=user_pk,
        version=entry.version,
        kind=entry.kind,
        mission_version=entry.mission_version,
        detail=None,
    )
    fields = _DETAIL.get(entry.kind)
    if fields is None:
        for name in _COLUMNS:
            if hasattr(entry, name):
                out[name] = getattr(entry, name)
    else:
        detail = {name: getattr(entry, name) for name in fields}
        if isinstance(entry, Fold):
            detail["kept_from"] = entry.kept_from.astimezone(dt.UTC).isoformat()
        out["detail"] = detail
    return out


def _entry(row: Sequence[Any]) -> Entry:
    kind, version, mission_version = row[0], row[1], row[2]
    cls = _KINDS.get(kind)
    if cls is None:
        raise ValueError(f"journal entry of version {version} has an unknown kind {kind!r}")
    fields = _DETAIL.get(kind)
    if fields is None:
        given = dict(zip(_COLUMNS, row[3:-1], strict=True))
        named = {name: given[name] for name in cls.__dataclass_fields__ if name in given}
        entry: Entry = cls(version=version, mission_version=mission_version, **named)
        return entry
    detail = dict(row[-1] or {})
    if kind == Fold.kind:
        detail["kept_from"] = dt.datetime.fromisoformat(detail["kept_from"])
    made: Entry = cls(
        version=version, mission_version=mission_version, **{n: detail[n] for n in fields}
    )
    return made


def append(session: Session, user_pk: int, entries: Iterable[Entry]) -> None:
    """Add entries to the person's journal, in order."""
    rows = [_row(user_pk, e) for e in entries]
    if rows:
        _INSERT.run_many(session, rows)


def entries_since(session: Session, user_pk: int, version: int) -> list[Entry]:
    """The journal after ``version``, in the order it was written."""
    return [_entry(r) for r in _SINCE.all(session, {"user_pk": user_pk, "version": version})]


def entries_between(
    session: Session, user_pk: int, after: int, upto: int, *, page: int
) -> Iterator[Entry]:
    """The journal of versions in (``after``, ``upto``], in the order it was written, read
    ``page`` rows at a time (a long journal in bounded memory)."""
    c = conn(session)
    where = _journal.c.version > after
    while True:
        rows = c.execute(
            select(*_READ, _journal.c.id)
            .where(_journal.c.user_pk == user_pk, _journal.c.version <= upto, where)
            .order_by(_journal.c.version, _journal.c.id)
            .limit(page)
        ).all()
        for row in rows:
            yield _entry(row[:-1])
        if len(rows) < page:
            return
        last_version, last_id = rows[-1].version, rows[-1].id
        where = or_(
            _journal.c.version > last_version,
            (_journal.c.version == last_version) & (_journal.c.id > last_id),
        )


def versions(session: Session, user_pk: int) -> list[tuple[int, str]]:
    """(version, kind) of every version the journal holds, oldest first."""
    rows = conn(session).execute(
        select(_journal.c.version, _journal.c.kind)
        .where(_journal.c.user_pk == user_pk)
        .group_by(_journal.c.version, _journal.c.kind)
        .order_by(_journal.c.version)
    )
    return [(r[0], r[1]) for r in rows]


def has_transition(
    session: Session, user_pk: int, *, episode: int, action: int, after_version: int
) -> bool:
    """Whether the model taught after ``after_version`` holds ``action``'s step of the
    learner's ``episode``."""
    stmt = (
        select(_journal.c.id)
        .where(
            _journal.c.user_pk == user_pk,
            _journal.c.episode == episode,
            _journal.c.action == action,
            _journal.c.kind == Transition.kind,
            _journal.c.version > after_version,
        )
        .limit(1)
    )
    return conn(session).execute(stmt).first() is not None


def delete_folded(session: Session, user_pk: int, upto_version: int, *, limit: int) -> int:
    """Remove up to ``limit`` of the journal's entries of versions up to ``upto_version`` that
    a retention run folded (every kind but the fold's own entries): how many."""
    c = conn(session)
    ids = (
        select(_journal.c.id)
        .where(
            _journal.c.user_pk == user_pk,
            _journal.c.version <= upto_version,
            _journal.c.kind != Fold.kind,
        )
        .order_by(_journal.c.id)
        .limit(limit)
        .scalar_subquery()
    )
    return int(c.execute(delete(_journal).where(_journal.c.id.in_(ids))).rowcount or 0)


def replace_fold(session: Session, user_pk: int, fold: Fold) -> None:
    """The person's fold entry: ``fold`` instead of any earlier one (it covers them)."""
    conn(session).execute(
        delete(_journal).where(_journal.c.user_pk == user_pk, _journal.c.kind == Fold.kind)
    )
    append(session, user_pk, [fold])
