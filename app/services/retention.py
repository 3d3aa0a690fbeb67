"""Retention: a fleet's raw history kept for its window only, its people's models exact.

A fleet may set a window (``history_days``). A run, per person of such a fleet:

1. *Plans*, reading only: the oldest run of the person's episodes that are closed and were
   received before the window (episodes 1..S), and the model version V from which every kept
   episode's decisions were drawn (the oldest such; the model's own version if none is kept).
2. *Folds*, in one short transaction under the person's lock: the learner at version V (the
   model's base replayed through its journal up to V, as a rebuild does) becomes the model's
   new base, and the profile's walk over episodes 1..S (:mod:`app.services.folds`) is stored
   in ``history_folds``. Nothing the person's model, decisions or profile say changes: the
   head is untouched, a rebuild starts from the new base, the profile goes on from the walk.
3. *Removes*, a batch at a time, each batch its own transaction: the episodes 1..S (with
   their decisions, answers, feedback and stored replay answers) and the journal's entries up
   to V.

Killed at any point, the database is consistent (the fold is one transaction; the removals
only remove what a stored fold covers), and the next run removes what is left and goes on.
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from sqlalchemy.orm import Session

from app.daily import DailyTime
from app.db.repositories import audit as audit_repo
from app.db.repositories import journal
from app.db.repositories import retention as repo
from app.db.repositories import users as users_repo
from app.db.repositories.models import ModelRow
from app.db.repositories.users import UserRow
from app.db.session import Database
from app.db.types import utcnow
from app.errors import Forbidden, ValidationFailed
from app.learning import NegotiationSpace

from . import audit
from .auth import require_manager
from .context import Principal, ServiceContext
from .folds import History
from .person_model import PersonModel

__all__ = [
    "MAX_DAYS",
    "FleetRun",
    "LastRun",
    "RunReport",
    "WindowView",
    "history_view",
    "run",
    "set_history",
    "window_view",
]

log = logging.getLogger("attune.retention")

MAX_DAYS = 36_500
PEOPLE_PAGE = 200  # people read per transaction while a fleet is walked


@dataclass
class FleetRun:
    """What a run did in one fleet."""

    fleet: str
    days: int
    kept_from: dt.datetime
    people: int = 0
    folded: int = 0  # people whose fold moved on
    episodes_removed: int = 0
    journal_removed: int = 0
    skipped: list[str] = field(default_factory=list)  # people changed under the run: next run


@dataclass
class RunReport:
    started_at: dt.datetime
    finished_at: dt.datetime | None = None
    fleets: list[FleetRun] = field(default_factory=list)

    @property
    def episodes_removed(self) -> int:
        return sum(f.episodes_removed for f in self.fleets)

    @property
    def journal_removed(self) -> int:
        return sum(f.journal_removed for f in self.fleets)

    def to_json(self) -> dict[str, Any]:
        return {
            "started_at": self.started_at.isoformat(),
            "finished_at": None if self.finished_at is None else self.finished_at.isoformat(),
            "episodes_removed": self.episodes_removed,
            "journal_removed": self.journal_removed,
            "fleets": [{**asdict(f), "kept_from": f.kept_from.isoformat()} for f in self.fleets],
        }


Progress = Callable[[str, str], None]  # (fleet, user id) as each person is done


def run(
    db: Database,
    ctx: ServiceContext,
    *,
    fleet: str | None = None,
    now: dt.datetime | None = None,
    batch: int | None = None,
    progress: Progress | None = None,
) -> RunReport:
    """One retention run over every fleet with a window (or ``fleet`` only)."""
    report = RunReport(started_at=utcnow())
    at = now or report.started_at
    size = batch or ctx.settings.retention_batch
    with db.transaction(write=False) as session:
        windows = repo.fleet_windows(session)
    for name, days in windows:
        if fleet is not None and name != fleet:
            continue
        done = FleetRun(name, days, at - dt.timedelta(days=days))
        report.fleets.append(done)
        after = 0
        while True:
            with db.transaction(write=False) as session:
                page = repo.people(session, name, after_pk=after, limit=PEOPLE_PAGE)
            for user_pk, user_id in page:
                _person(db, ctx, done, user_pk, user_id, size)
                if progress is not None:
                    progress(name, user_id)
            if len(page) < PEOPLE_PAGE:
                break
            after = page[-1][0]
        with db.transaction() as session:
            audit.record(
                session,
                audit.CLI,
                "fleet.retention",
                target=name,
                fleet=name,
                detail={
                    "days": days,
                    "kept_from": done.kept_from.isoformat(),
                    "people": done.people,
                    "episodes_removed": done.episodes_removed,
                    "journal_removed": done.journal_removed,
                },
            )
        log.info(
            "retention in fleet %s (%d days, history kept from %s): %d people, %d folded, "
            "%d episodes and %d journal entries removed%s",
            name,
            days,
            done.kept_from.isoformat(timespec="seconds"),
            done.people,
            done.folded,
            done.episodes_removed,
            done.journal_removed,
            f", {len(done.skipped)} changed during the run (next run)" if done.skipped else "",
        )
    report.finished_at = utcnow()
    return report


@dataclass(frozen=True, slots=True)
class _Plan:
    user: UserRow
    model: ModelRow
    previous: repo.FoldRow | None
    upto_seq: int
    upto_version: int
    kept_from: dt.datetime
    base: dict[str, Any] | None  # the learner at upto_version (None: the base stays)
    base_layout: int
    doc: dict[str, Any]


def _person(
    db: Database, ctx: ServiceContext, done: FleetRun, user_pk: int, user_id: str, size: int
) -> None:
    done.people += 1
    with db.transaction(write=False) as session:
        plan = _plan(session, ctx, done.fleet, user_id, done.kept_from)
    if plan is not None:
        with db.transaction() as session:
            folded = _fold(session, ctx, plan)
        if folded:
            done.folded += 1
        else:
            done.skipped.append(user_id)
    with db.transaction(write=False) as session:
        fold = repo.fold(session, user_pk)
    if fold is None:
        return
    while True:
        with db.transaction() as session:
            n = repo.delete_episodes(session, user_pk, fold.upto_seq, limit=size)
        done.episodes_removed += n
        if n < size:
            break
    while True:
        with db.transaction() as session:
            n = journal.delete_folded(session, user_pk, fold.upto_version, limit=size)
        done.journal_removed += n
        if n < size:
            break


def _plan(
    session: Session, ctx: ServiceContext, fleet: str, user_id: str, before: dt.datetime
) -> _Plan | None:
    user = users_repo.get(session, fleet, user_id)
    if user is None:
        return None
    person = PersonModel.open(session, ctx, user)
    model = person.head
    previous = repo.fold(session, user.id)
    start = 0 if previous is None else previous.upto_seq
    upto = repo.upto_seq(session, user.id, before)
    if upto <= start:
        return None
    first = repo.first_kept_version(session, user.id, upto)
    version = max(model.base_version, min(model.version, model.version if first is None else first))
    base, layout = None, model.base_mission_version
    if version > model.base_version:
        replay = person.replay(upto=version)
        base, layout = replay.through(version).to_state(), replay.layout
    current = person.learner
    history = History.from_doc(None if previous is None else previous.doc)
    spaces: dict[int, NegotiationSpace] = {}

    def space_of(version: int) -> NegotiationSpace:
        if version not in spaces:
            spaces[version] = ctx.missions.get(session, fleet, version).space
        return spaces[version]

    pointed = {r.overridden_at for r in current.guidance.rules if r.overridden_at is not None}
    history.walk_stored(session, user.id, space_of, upto_seq=upto, keep_moments=pointed)
    history.upto_seq = upto
    kept = repo.first_kept_created(session, user.id, upto)
    return _Plan(
        user=user,
        model=model,
        previous=previous,
        upto_seq=upto,
        upto_version=version,
        kept_from=before if kept is None else min(before, kept),
        base=base,
        base_layout=layout,
        doc=history.to_doc(pointed),
    )


def _fold(session: Session, ctx: ServiceContext, plan: _Plan) -> bool:
    """Store the plan, if the person is as it was planned on: whether it was stored."""
    user = users_repo.lock(session, plan.user.fleet, plan.user.user_id)
    if user is None or user.id != plan.user.id:
        return False
    fold = repo.fold(session, user.id)
    before = 0 if plan.previous is None else plan.previous.upto_seq
    if (0 if fold is None else fold.upto_seq) != before:
        return False
    person = PersonModel.open(session, ctx, user, write=True)
    if not person.fold(
        base=plan.base,
        base_layout=plan.base_layout,
        upto_version=plan.upto_version,
        upto_seq=plan.upto_seq,
        kept_from=plan.kept_from,
        expect_base_version=plan.model.base_version,
    ):
        return False
    person.save()
    repo.put_fold(
        session,
        user.id,
        upto_seq=plan.upto_seq,
        upto_version=plan.upto_version,
        kept_from=plan.kept_from,
        now=utcnow(),
        doc=plan.doc,
    )
    return True


def history_view(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str
) -> dict[str, Any]:
    """``GET /v1/admin/fleets/{fleet}/history`` (the fleet's staff, admins)."""
    _check_fleet(principal, fleet)
    days = repo.window(session, fleet)
    return {
        "fleet": fleet,
        "history_days": days,
    }


def set_history(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    days: int | None,
) -> dict[str, Any]:
    """``PUT /v1/admin/fleets/{fleet}/history``: the fleet's retention window (``None``: keep
    everything). It takes effect at the next run."""
    _check_fleet(principal, fleet)
    if days is not None and not 1 <= days <= MAX_DAYS:
        raise ValidationFailed(f"history_days must be between 1 and {MAX_DAYS}, or null.")
    if repo.window(session, fleet) != days:
        repo.set_window(session, fleet, days=days, now=utcnow(), actor=principal.key_id)
        audit.record(
            session,
            principal,
            "fleet.history",
            target=fleet,
            fleet=fleet,
            detail={"history_days": days},
        )
    return history_view(session, ctx, principal, fleet)


@dataclass(frozen=True, slots=True)
class LastRun:
    """What the latest run did in a fleet (its ``fleet.retention`` audit entry)."""

    at: dt.datetime
    days: int  # the window it applied
    people: int
    episodes_removed: int


@dataclass(frozen=True, slots=True)
class WindowView:
    """A fleet's window with its story, for the console: when and by which key it was last
    set, the latest run there, and the service's own time of day for runs (``None``: the
    service runs none; cron may run ``attune retention run``)."""

    fleet: str
    days: int | None
    set_at: dt.datetime | None
    set_by: str | None
    last_run: LastRun | None
    runs_at: DailyTime | None


def window_view(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str
) -> WindowView:
    """The fleet's window, its last change and its last run (the fleet's staff, admins)."""
    _check_fleet(principal, fleet)
    changed = audit_repo.latest(session, fleet=fleet, action="fleet.history")
    ran = audit_repo.latest(session, fleet=fleet, action="fleet.retention")
    last = None
    if ran is not None:
        detail = ran.detail or {}
        last = LastRun(
            at=ran.at,
            days=int(detail.get("days", 0)),
            people=int(detail.get("people", 0)),
            episodes_removed=int(detail.get("episodes_removed", 0)),
        )
    return WindowView(
        fleet=fleet,
        days=repo.window(session, fleet),
        set_at=None if changed is None else changed.at,
        set_by=None if changed is None else changed.actor_key_id,
        last_run=last,
        runs_at=ctx.settings.retention_at,
    )


def _check_fleet(principal: Principal, fleet: str) -> None:
    require_manager(principal)
    if not principal.sees(fleet):
        raise Forbidden("Staff keys manage their own fleet's history only.")
