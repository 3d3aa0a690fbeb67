"""Rolling a candidate learner out to a fleet safely: a canary, compared while it runs, promoted
or rolled back (``/v1/admin/fleets/{fleet}/rollout``; docs/api.md "Rollouts", docs/method.md
§18).

- **Arms, stored.** Starting a rollout (``PUT .../rollout {candidate, share}``) gives every
  person of the fleet an arm by a salted stable hash of their id (``candidate`` when the hash is
  below ``share``, else ``control``) and **stores it** (``rollout_arms``). Newcomers are given
  one when they are created (unless whoever created them chose their learner), by the same hash
  and the share then in force. A stored arm never changes by itself: a lower share moves no
  one, nor do a mission change or a restart; a higher share moves the control people whose
  hash is now below it (staff said so), and promote and roll back move everyone left.
- **Moving keeps what was learned.** A person moved to another learner does not start over: the
  learner they move to is taught their whole history since their model's base, in order, as it
  would have learned it online (:func:`app.services.evaluation.relearned`, the evaluation's own
  replay), and becomes their model (journalled as an import; audited as ``user.learner`` with
  the rollout's id). Their staff corrections stay in force.
- **Compared while it runs.** Each look (``GET .../rollout``) compares the arms' mean return per
  encounter over the closed episodes each person began since they got their arm, with the
  always-valid interval of :mod:`app.learning.sequential` (one that holds at every look at once,
  however often staff look).
- **The guard.** When that interval says the candidate is worse (its high end below 0), the
  rollout is rolled back automatically: every service runs the check every
  ``ATTUNE_ROLLOUT_GUARD_MINUTES`` (a lease lets one process at a time do it), and the roll back
  is audited with the key ``guard`` and the comparison that decided it.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import logging
import secrets
import threading
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import rollouts as repo
from app.db.repositories import users as users_repo
from app.db.repositories.rollouts import ArmRow, RolloutRow
from app.db.repositories.users import UserRow
from app.db.session import Database
from app.db.types import utcnow
from app.errors import Conflict, Forbidden, NotFound, ValidationFailed
from app.learning.sequential import BETTER, CANDIDATE, CONTROL, WORSE, Comparison, compare, guard
from app.logs import FIELDS

from . import audit, leases
from .auth import require_manager
from .context import Principal, ServiceContext, after_commit
from .evaluation import CandidateSpec, candidate_spec, live_candidate, relearned
from .person_model import PersonModel

__all__ = [
    "GUARD",
    "arm_for_newcomer",
    "check_guard",
    "complete_moves",
    "Mover",
    "hash_place",
    "person_arm",
    "person_arms",
    "promote",
    "put_rollout",
    "roll_back",
    "rollout_view",
]

log = logging.getLogger("attune.rollouts")

GUARD = "guard"
"""The key id the automatic roll back is recorded with."""
LEASE = "rollout-guard"
"""The lease of the guard's check (:class:`app.services.periodic.Periodic`)."""


def new_salt() -> str:
    """A fresh rollout's salt, 8 random bytes in hex: no two rollouts split a fleet alike."""
    return secrets.token_hex(8)


def hash_place(salt: str, user_id: str) -> float:
    """The person's place in [0, 1) for this rollout: a salted SHA-256 of their id."""
    digest = hashlib.sha256(f"{salt}\x00{user_id}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


def _spec_of(row: RolloutRow) -> CandidateSpec:
    return candidate_spec(row.algorithm, row.params)


def _check_fleet(principal: Principal, fleet: str) -> None:
    require_manager(principal)
    if not principal.sees(fleet):
        raise Forbidden("Staff keys roll out learners in their own fleet only.")


def _serves(user: UserRow, spec: CandidateSpec) -> bool:
    return user.algorithm == spec.algorithm and dict(user.params) == spec.full_params


def _move(
    session: Session,
    ctx: ServiceContext,
    actor: Principal,
    user: UserRow,
    spec: CandidateSpec,
    *,
    rollout_id: str,
) -> None:
    """Give the person ``spec`` as their learner, taught their history (see the module)."""
    if _serves(user, spec):
        return
    learner, refused = relearned(session, ctx, user, spec)
    model = PersonModel.open(session, ctx, user, write=True)
    before = user.algorithm
    user.algorithm, user.params = learner.algorithm, learner.params.to_dict()
    users_repo.save_profile(session, user)
    model.import_learner(
        learner,
        actor=actor,
        action="user.learner",
        detail={
            "algorithm": learner.algorithm,
            "was": before,
            "rollout": rollout_id,
            "relearned": True,
            "entries_refused": refused,
        },
        episode_offset=max(model.head.episode_offset, learner.episodes - user.episode_count),
    )
    model.save()


def _fleet_people(session: Session, fleet: str) -> list[UserRow]:
    people: list[UserRow] = []
    after: tuple[str, str] | None = None
    while True:
        page = users_repo.list_page(session, fleet=fleet, after=after, limit=500)
        people.extend(page)
        if len(page) < 500:
            return people
        after = (page[-1].fleet, page[-1].user_id)


# ---------------------------------------------------------------------------------------------
# What staff see


def _number(value: float) -> str:
    shown = round(value, 2) + 0.0  # -0.004 shows as +0.00, not −0.00
    return f"{shown:+.2f}".replace("-", "−")


def words(comparison: Comparison, label: str, status: str) -> str:
    """The comparison in a sentence for staff."""
    if not comparison.enough:
        return (
            f"Not enough evidence yet to compare {label} with the current learners: "
            f"{comparison.reason}"
        )
    assert comparison.difference is not None
    assert comparison.low is not None
    assert comparison.high is not None
    span = (
        f"{_number(comparison.difference)} per encounter, between {_number(comparison.low)} and "
        f"{_number(comparison.high)} (95% confidence, however often you look)"
    )
    if comparison.verdict == BETTER:
        return f"{label} earns more than the current learners: {span}."
    if comparison.verdict == WORSE:
        done = " It was rolled back." if status == "rolled_back" else ""
        return f"{label} earns less than the current learners: {span}.{done}"
    return f"No difference shown yet between {label} and the current learners: {span}."


def _comparison(session: Session, row: RolloutRow) -> Comparison:
    found = repo.returns(session, row.id, until=row.ended_at)
    return compare(
        [p for p, _, _ in found],
        [CANDIDATE if arm == CANDIDATE else CONTROL for _, arm, _ in found],
        [r for _, _, r in found],
    )


def _view(session: Session, row: RolloutRow) -> dict[str, Any]:
    spec = _spec_of(row)
    people = repo.arms(session, row.id)
    comparison = _comparison(session, row)
    return {
        "rollout_id": row.id,
        "fleet": row.fleet,
        "candidate": spec.to_dict(),
        "share": row.share,
        "status": row.status,
        "started_at": row.started_at,
        "started_by": row.started_by,
        "ended_at": row.ended_at,
        "ended_by": row.ended_by,
        "end_reason": row.end_reason,
        "people": {
            CANDIDATE: sum(1 for a, _ in people if a.arm == CANDIDATE),
            CONTROL: sum(1 for a, _ in people if a.arm == CONTROL),
        },
        "moving": sum(1 for a, _ in people if a.pending),
        "comparison": comparison.to_dict(),
        "summary": words(comparison, spec.label, row.status),
        "guard": guard(comparison),
    }


def rollout_view(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str
) -> dict[str, Any]:
    """``GET .../rollout``: the fleet's newest rollout with the look at its arms; 404 when the
    fleet never had one."""
    _check_fleet(principal, fleet)
    row = repo.latest(session, fleet)
    if row is None:
        raise NotFound(f"Fleet {fleet!r} has had no rollout.")
    return _view(session, row)


def person_arm(session: Session, user_pk: int) -> dict[str, Any] | None:
    """The person's arm in the newest rollout that gave them one (their profile and export)."""
    found = repo.arm_of(session, user_pk)
    if found is None:
        return None
    arm, row = found
    return {
        "rollout_id": row.id,
        "arm": arm.arm,
        "assigned_at": arm.assigned_at,
        "candidate": _spec_of(row).to_dict(),
        "rollout_status": row.status,
        "moving": arm.pending,
    }


def person_arms(session: Session, user_pk: int) -> list[dict[str, Any]]:
    """Every arm the person was given, oldest first (their export)."""
    return [
        {
            "rollout_id": row.id,
            "arm": arm.arm,
            "assigned_at": arm.assigned_at,
            "candidate": _spec_of(row).to_dict(),
            "rollout_status": row.status,
            "previous_learner": {
                "algorithm": arm.previous_algorithm,
                "params": dict(arm.previous_params),
            },
        }
        for arm, row in repo.arms_of_user(session, user_pk)
    ]


# ---------------------------------------------------------------------------------------------
# What staff do


def put_rollout(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    algorithm: str,
    params: dict[str, Any],
    share: float,
    mover: Mover | None = None,
) -> tuple[dict[str, Any], bool]:
    """Start a rollout of the candidate to ``share`` of the fleet's people, or change the share
    of the one running (the same candidate): (the view, started)."""
    _check_fleet(principal, fleet)
    spec = live_candidate(algorithm, params)
    if not 0.0 < share <= 1.0:
        raise ValidationFailed(
            "share must be above 0 and at most 1.",
            fields=[{"loc": ["body", "share"], "msg": "out of range"}],
        )
    running = repo.lock_running(session, fleet)
    now = utcnow()
    if mover is not None:
        after_commit(session, mover.kick)
    if running is not None:
        if _spec_of(running).key != spec.key:
            raise Conflict(
                f"A rollout of {_spec_of(running).label} is running in fleet {fleet!r}: promote "
                "it or roll it back before rolling out another learner."
            )
        if share != running.share:
            _reshare(session, ctx, principal, running, share, now)
        return _view(session, repo.latest(session, fleet) or running), False
    row = RolloutRow(
        id=f"ro_{secrets.token_hex(16)}",
        fleet=fleet,
        algorithm=spec.algorithm,
        params=dict(spec.params),
        share=share,
        salt=new_salt(),
        status="running",
        started_at=now,
        started_by=principal.key_id,
        ended_at=None,
        ended_by=None,
        end_reason=None,
    )
    repo.add(session, row)
    moved = 0
    for user in _fleet_people(session, fleet):
        arm = CANDIDATE if hash_place(row.salt, user.user_id) < share else CONTROL
        owed = arm == CANDIDATE and not _serves(user, spec)
        repo.add_arm(
            session,
            ArmRow(
                row.id,
                user.id,
                arm,
                now,
                user.algorithm,
                dict(user.params),
                pending=owed,
                served_since=None if owed else now,
            ),
        )
        moved += owed
    audit.record(
        session,
        principal,
        "rollout.start",
        target=fleet,
        fleet=fleet,
        detail={"rollout": row.id, "candidate": spec.key, "share": share, "moved": moved},
    )
    log.info(
        "Rollout %s of %s to %.0f%% of fleet %s started: %d people to move.",
        row.id,
        spec.label,
        share * 100,
        fleet,
        moved,
        extra={FIELDS: {"rollout": row.id, "fleet": fleet}},
    )
    return _view(session, row), True


def _reshare(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    row: RolloutRow,
    share: float,
    now: dt.datetime,
) -> None:
    """A new share: a higher one moves the control people whose place is now below it; a lower
    one moves no one (newcomers get it)."""
    moved = 0
    if share > row.share:
        for arm, user_id in repo.arms(session, row.id):
            if arm.arm != CONTROL or hash_place(row.salt, user_id) >= share:
                continue
            repo.set_arm(session, row.id, arm.user_pk, CANDIDATE, now=now)
            moved += 1
    repo.set_share(session, row.id, share)
    audit.record(
        session,
        principal,
        "rollout.share",
        target=row.fleet,
        fleet=row.fleet,
        detail={"rollout": row.id, "share": share, "was": row.share, "moved": moved},
    )


def _running(session: Session, fleet: str) -> RolloutRow:
    running = repo.lock_running(session, fleet)
    if running is None:
        raise Conflict(f"No rollout is running in fleet {fleet!r}.")
    return running


def promote(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    mover: Mover | None = None,
) -> dict[str, Any]:
    """Give the candidate to everyone of the rollout (the control people move, keeping what was
    learned) and to the fleet's newcomers from now on."""
    _check_fleet(principal, fleet)
    row = _running(session, fleet)
    spec = _spec_of(row)
    now = utcnow()
    moved = repo.owe_moves(session, row.id, CONTROL)
    if mover is not None:
        after_commit(session, mover.kick)
    repo.end(session, row.id, status="promoted", by=principal.key_id, reason=None, now=now)
    audit.record(
        session,
        principal,
        "rollout.promote",
        target=fleet,
        fleet=fleet,
        detail={"rollout": row.id, "candidate": spec.key, "moved": moved},
    )
    return _view(session, repo.latest(session, fleet) or row)


def roll_back(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    reason: str | None = None,
    mover: Mover | None = None,
) -> dict[str, Any]:
    """Give every candidate person back the learner they had (taught their whole history,
    including what the candidate learned with them); newcomers get the fleet's default again."""
    _check_fleet(principal, fleet)
    row = _running(session, fleet)
    now = utcnow()
    moved = repo.owe_moves(session, row.id, CANDIDATE)
    if mover is not None:
        after_commit(session, mover.kick)
    repo.end(session, row.id, status="rolled_back", by=principal.key_id, reason=reason, now=now)
    audit.record(
        session,
        principal,
        "rollout.rollback",
        target=fleet,
        fleet=fleet,
        detail={"rollout": row.id, "moved": moved, "reason": reason},
    )
    return _view(session, repo.latest(session, fleet) or row)


def arm_for_newcomer(
    session: Session, fleet: str, user_id: str
) -> tuple[RolloutRow, str, CandidateSpec | None] | None:
    """For a person about to be created with the fleet's default learner: the rollout that
    gives them an arm (a running one), their arm, and the learner it gives them (the candidate
    or None for the default); for a promoted rollout, (it, "", the candidate); None otherwise."""
    row = repo.latest(session, fleet)
    if row is None or row.status == "rolled_back":
        return None
    if row.status == "promoted":
        return row, "", _spec_of(row)
    arm = CANDIDATE if hash_place(row.salt, user_id) < row.share else CONTROL
    return row, arm, _spec_of(row) if arm == CANDIDATE else None


def record_newcomer(
    session: Session, row: RolloutRow, arm: str, user_id: str, previous: tuple[str, dict[str, Any]]
) -> None:
    """Store a newcomer's arm (``previous``: the learner the fleet's default would have given
    them, which a roll back gives them)."""
    user = users_repo.get(session, row.fleet, user_id)
    if user is None or not arm:
        return
    now = utcnow()
    repo.add_arm(
        session,
        ArmRow(row.id, user.id, arm, now, previous[0], dict(previous[1]), served_since=now),
    )


# ---------------------------------------------------------------------------------------------
# The moves owed


MOVER = Principal("rollout", "admin", "default")
"""Who the audit log says moved a person (``user.learner``): the rollout's own mover (the
rollout's entry says who started, promoted or rolled it back)."""
MOVES_LEASE = "rollout-moves"
MOVES_PAGE = 50


def complete_moves(db: Database, ctx: ServiceContext, *, stopping: Any = None) -> int:
    """Do the moves owed, a person at a time, each in a transaction of its own that holds only
    that person (the robots of everyone else go on): the person gets the learner their arm
    gives them now (the candidate; their previous learner once the rollout was rolled back),
    taught their history. How many people moved."""
    done = 0
    while True:
        with db.transaction(write=False) as session:
            owed = repo.owed(session, limit=MOVES_PAGE)
        if not owed:
            return done
        for arm, row, user_id in owed:
            if stopping is not None and stopping():
                return done
            with db.transaction() as session:
                user = users_repo.lock(session, row.fleet, user_id)
                current = repo.arm(session, row.id, arm.user_pk)
                if user is None or current is None or not current.pending:
                    continue
                now_row = repo.latest_of(session, row.id) or row
                target = (
                    candidate_spec(current.previous_algorithm, current.previous_params)
                    if now_row.status == "rolled_back"
                    else _spec_of(now_row)
                )
                actor = Principal(MOVER.key_id, MOVER.role, row.fleet)
                _move(session, ctx, actor, user, target, rollout_id=row.id)
                repo.moved(session, row.id, arm.user_pk, now=utcnow())
            done += 1


class Mover:
    """A worker's mover: :meth:`kick` (after a rollout's transaction committed, and at the
    worker's start) runs :func:`complete_moves` in a thread of its own, under the lease
    ``rollout-moves`` (one process at a time; a kick while it runs makes it go round once
    more)."""

    def __init__(self, db: Database, ctx: ServiceContext, *, stopping: Any = lambda: False) -> None:
        self.db, self.ctx, self.stopping = db, ctx, stopping
        self._lock = threading.Lock()
        self._again = False
        self._thread: threading.Thread | None = None

    def kick(self) -> None:
        with self._lock:
            self._again = True
            if self._thread is not None and self._thread.is_alive():
                return
            self._thread = threading.Thread(
                target=self._run, name="attune-rollout-moves", daemon=True
            )
            self._thread.start()

    def join(self, timeout: float = 5.0) -> None:
        thread = self._thread
        if thread is not None:
            thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._lock:
                if not self._again or self.stopping():
                    self._thread = None
                    return
                self._again = False
            try:
                with self.db.transaction(write=False) as session:
                    if not repo.owed(session, limit=1):
                        continue  # nothing owed: no lease taken, nothing written
                with leases.held(self.db, MOVES_LEASE):
                    moved = complete_moves(self.db, self.ctx, stopping=self.stopping)
                if moved:
                    log.info(
                        "Rollouts: %d people moved to the learner their arm gives them.", moved
                    )
            except leases.LeaseHeld:
                continue  # another process is doing them
            except Exception:
                log.exception("Rollouts: the moves owed failed; the next kick or check retries.")


# ---------------------------------------------------------------------------------------------
# The guard


def check_guard(db: Database, ctx: ServiceContext) -> list[str]:
    """Look at every running rollout; roll back those whose candidate is worse with the
    method's confidence. The fleets rolled back."""
    complete_moves(db, ctx)  # any left by a process that stopped
    with db.transaction(write=False) as session:
        fleets = repo.running_fleets(session)
    rolled: list[str] = []
    for fleet in fleets:
        with db.transaction(write=False) as session:
            row = repo.lock_running(session, fleet, lock=False)
            if row is None:
                continue
            comparison = _comparison(session, row)
        if not guard(comparison):
            continue
        reason = "the guard: " + words(comparison, _spec_of(row).label, "running")
        actor = Principal(GUARD, "admin", fleet)
        with db.transaction() as session:
            try:
                roll_back(session, ctx, actor, fleet, reason=reason[:500])
            except Conflict:  # ended meanwhile
                continue
        log.warning(
            "Rollout %s of fleet %s rolled back by the guard: %s",
            row.id,
            fleet,
            reason,
            extra={FIELDS: {"rollout": row.id, "fleet": fleet}},
        )
        rolled.append(fleet)
    if rolled:
        complete_moves(db, ctx)
    return rolled
