"""Each fleet's mission, versioned: read it, change it, and move every model of the fleet to
the new version by names (what still applies is kept, docs/operations.md §10).

A fleet's version 1 is stored when its first user is created (the deployment's default mission:
``ATTUNE_MISSION_PATH`` or the built-in office mission), unless its staff set one before. A
change is one transaction: it locks the fleet's mission and every user of the fleet, stores the
new version, closes the users' open episodes as ``interrupted`` (they cannot go on in a
negotiation that no longer exists), and moves every model: the learner is carried to the new
layout (``app.learning.remap``), stored as a snapshot, and the move is journalled (a sample of
kind "mission") so that ``attune models rebuild`` replays it.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import episodes as episodes_repo
from app.db.repositories import missions as repo
from app.db.repositories import users as users_repo
from app.db.repositories.missions import MissionRow
from app.db.repositories.models import ModelRow
from app.db.types import utcnow
from app.errors import Conflict, Forbidden, ValidationFailed
from app.learning import Mission, MissionError
from app.learning.learners import TabularLearner
from app.learning.remap import (
    MissionDiff,
    Renames,
    SpaceMap,
    check_renames,
    diff_missions,
)

from . import audit
from .auth import require_manager
from .context import Principal, ServiceContext
from .mission_book import Stored
from .person_model import PersonModel

__all__ = [
    "LIMITS",
    "ChangePreview",
    "change_of",
    "change_result",
    "check_limits",
    "current_version",
    "fleet_mission",
    "list_missions",
    "mission_of",
    "move_learner",
    "parse_mission",
    "preview_change",
    "set_mission",
    "space_map",
    "user_layout",
]

# Sizes a mission may have: every user's model holds tables of (contexts x pairs), and pairs
# grow with the services and details.
LIMITS = {
    "time_slots": 12,
    "situations": 16,
    "contexts": 96,
    "services": 16,
    "details_per_service": 16,
    "details": 64,
}


def mission_of(session: Session, ctx: ServiceContext, fleet: str, version: int) -> Stored:
    """Version ``version`` of ``fleet``'s mission."""
    return ctx.missions.get(session, fleet, version)


def user_layout(session: Session, ctx: ServiceContext, fleet: str, model: ModelRow) -> Stored:
    """The mission version a user's model is laid out for."""
    return ctx.missions.get(session, fleet, model.mission_version)


def current_version(
    session: Session, ctx: ServiceContext, fleet: str, *, for_new_user: bool = False
) -> int:
    """The version of ``fleet``'s mission in force. ``for_new_user``: a user is being created
    in the fleet: the fleet's mission is locked first (a change waits, or is waited for), and
    a fleet with none stored gets the default as its version 1."""
    if for_new_user:
        repo.lock_latest(session, fleet)
    version = repo.latest_version(session, fleet)
    if version is not None:
        return version
    if for_new_user:
        repo.add_first(session, _row(fleet, 1, ctx.missions.default))
    return 1


def _row(
    fleet: str,
    version: int,
    mission: Mission,
    *,
    renames: Renames | None = None,
    change_id: str | None = None,
    request_hash: str | None = None,
    response: dict[str, Any] | None = None,
    actor: str | None = None,
) -> MissionRow:
    return MissionRow(
        fleet=fleet,
        version=version,
        name=mission.name,
        fingerprint=mission.fingerprint,
        document=mission.to_dict(),
        renames=renames.to_dict() if renames else None,
        change_id=change_id,
        request_hash=request_hash,
        response=response,
        actor_key_id=actor,
        created_at=utcnow(),
    )


def parse_mission(doc: Any, *, where: str = "mission") -> Mission:
    """The mission of a request, or 422 with the mission loader's message."""
    try:
        mission = Mission.from_dict(doc, source=where)
    except MissionError as exc:
        raise ValidationFailed(str(exc)) from None
    check_limits(mission, where=where)
    return mission


def check_limits(mission: Mission, *, where: str = "mission") -> None:
    """422 naming the first size over :data:`LIMITS`."""
    details = [len(s.details) for s in mission.services]
    sizes = {
        "time_slots": len(mission.time_slots),
        "situations": len(mission.situations),
        "contexts": mission.n_contexts,
        "services": len(mission.services),
        "details_per_service": max(details),
        "details": sum(details),
    }
    for name, size in sizes.items():
        if size > LIMITS[name]:
            raise ValidationFailed(
                f"{where}: {size} {name.replace('_', ' ')} is more than the "
                f"{LIMITS[name]} a mission may have."
            )


def space_map(
    session: Session, ctx: ServiceContext, fleet: str, old: int, new: int
) -> list[SpaceMap]:
    """The steps from version ``old`` to ``new`` (each maps one version's indices onto the
    next's)."""
    steps = []
    for version in range(old + 1, new + 1):
        before = mission_of(session, ctx, fleet, version - 1)
        after = mission_of(session, ctx, fleet, version)
        steps.append(SpaceMap(before.space, after.space, after.renames))
    return steps


def move_learner(
    session: Session,
    ctx: ServiceContext,
    fleet: str,
    learner: TabularLearner[Any],
    old: int,
    new: int,
) -> TabularLearner[Any]:
    """``learner`` (laid out for version ``old``) carried to version ``new``, one version at a
    time."""
    return ctx.missions.carry(session, fleet, learner, old, new)


def _check_fleet(principal: Principal, fleet: str) -> None:
    require_manager(principal)
    if not principal.sees(fleet):
        raise Forbidden("Staff keys manage their own fleet's mission only.")


def fleet_mission(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str | None
) -> dict[str, Any]:
    """``GET /v1/mission``: the caller's fleet's mission in force (an admin may name a
    fleet)."""
    if fleet is not None and fleet != principal.fleet and not principal.is_admin:
        raise Forbidden("Only admin keys may name a fleet.")
    name = fleet or principal.fleet
    version = current_version(session, ctx, name)
    mission = ctx.missions.display(session, name, version)
    return {
        **mission.to_dict(),
        "fleet": name,
        "version": version,
        "fingerprint": mission.fingerprint,
    }


def list_missions(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str
) -> dict[str, Any]:
    """Every version of a fleet's mission, newest first (staff of the fleet, admins)."""
    _check_fleet(principal, fleet)
    rows = repo.list_versions(session, fleet)
    items = [_version_out(r) for r in rows]
    if not items:  # nothing stored yet: the default is what the fleet would get
        items = [
            {
                "version": 1,
                "name": ctx.missions.default.name,
                "fingerprint": ctx.missions.default.fingerprint,
                "created_at": None,
                "change_id": None,
                "renames": None,
                "set_by": None,
                "stored": False,
                "mission": ctx.missions.default.to_dict(),
            }
        ]
    return {"fleet": fleet, "current_version": items[0]["version"], "items": items}


def _version_out(row: MissionRow) -> dict[str, Any]:
    return {
        "version": row.version,
        "name": row.name,
        "fingerprint": row.fingerprint,
        "created_at": row.created_at.isoformat().replace("+00:00", "Z"),
        "change_id": row.change_id,
        "renames": row.renames,
        "set_by": row.actor_key_id,
        "stored": True,
        "mission": row.document,
    }


def _parse_change(
    principal: Principal, fleet: str, mission_doc: Any, renames_doc: Mapping[str, Any] | None
) -> tuple[Mission, Renames]:
    """The caller may change ``fleet``'s mission; the mission and renames as validated (422
    naming what is wrong)."""
    _check_fleet(principal, fleet)
    mission = parse_mission(mission_doc)
    try:
        return mission, Renames.from_dict(renames_doc or {})
    except ValueError as exc:
        raise ValidationFailed(str(exc)) from None


def set_mission(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    change_id: str,
    mission_doc: Any,
    renames_doc: Mapping[str, Any] | None,
) -> tuple[dict[str, Any], bool]:
    """Make ``mission_doc`` the fleet's mission: a new version, every model of the fleet moved
    to it in this transaction. (response, replayed). Idempotent on ``change_id``."""
    mission, renames = _parse_change(principal, fleet, mission_doc, renames_doc)
    digest = body_hash_of(change_id, mission, renames)
    repo.lock_latest(session, fleet)
    earlier = repo.by_change(session, fleet, change_id)
    if earlier is not None:
        if earlier.request_hash != digest:
            raise Conflict(f"change_id {change_id!r} was already used with another mission.")
        return dict(earlier.response or {}), True
    current = repo.latest_version(session, fleet)
    if current is None:  # the default was the fleet's version 1 until now: stored as such
        repo.add_first(session, _row(fleet, 1, ctx.missions.default))
        current = 1
    old = mission_of(session, ctx, fleet, current)
    try:
        check_renames(old.mission, mission, renames)
    except ValueError as exc:
        raise ValidationFailed(str(exc)) from None
    if mission.fingerprint == old.mission.fingerprint and not renames:
        if not mission.same_display(ctx.missions.display(session, fleet, current)):
            # Labels and time zone are display only: the version in force takes them, no
            # model moves and no conversation is interrupted.
            repo.set_document(session, fleet, current, mission.to_dict())
            audit.record(
                session,
                principal,
                "mission.set",
                target=fleet,
                fleet=fleet,
                detail={"version": current, "display_only": True},
            )
        return {
            "fleet": fleet,
            "version": current,
            "previous_version": current,
            "fingerprint": mission.fingerprint,
            "changed": False,
            "users_moved": 0,
            "episodes_interrupted": 0,
            "diff": None,
        }, False
    version = current + 1
    diff = diff_missions(old.mission, mission, renames).to_dict()
    moved = interrupted = 0
    users_repo.lock_fleet(session, fleet)
    for user_pk in repo.models_behind(session, fleet, version):
        interrupted += episodes_repo.interrupt_open(session, user_pk, at=utcnow())
        moved += 1
    out = {
        "fleet": fleet,
        "version": version,
        "previous_version": current,
        "fingerprint": mission.fingerprint,
        "changed": True,
        "users_moved": moved,
        "episodes_interrupted": interrupted,
        "diff": diff,
    }
    repo.add(
        session,
        _row(
            fleet,
            version,
            mission,
            renames=renames,
            change_id=change_id,
            request_hash=digest,
            response=out,
            actor=principal.key_id,
        ),
    )
    for user_pk in repo.models_behind(session, fleet, version):
        user = users_repo.by_pk(session, user_pk)
        assert user is not None  # joined on the user row, locked
        model = PersonModel.open(session, ctx, user, write=True)
        model.move(version)
        model.save()
    audit.record(
        session,
        principal,
        "mission.set",
        target=fleet,
        fleet=fleet,
        detail={
            "version": version,
            "previous_version": current,
            "users_moved": moved,
            "episodes_interrupted": interrupted,
        },
    )
    return out, False


@dataclass(frozen=True, slots=True)
class ChangePreview:
    """What :func:`set_mission` would do with a mission now, without doing it: the version in
    force (``old``, ``version``; ``version`` None: none stored yet, the default is version 1),
    what the change keeps, adds and removes, how many users' models would move and
    how many open episodes would be interrupted."""

    fleet: str
    version: int | None
    old: Mission
    new: Mission
    renames: Renames
    diff: MissionDiff
    changed: bool
    users_moved: int
    episodes_interrupted: int

    @property
    def next_version(self) -> int:
        """The version the change would make (a fleet with none stored has the default as its
        version 1, which the change stores first)."""
        return (self.version or 1) + 1 if self.changed else self.version or 1


def preview_change(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    mission_doc: Any,
    renames_doc: Mapping[str, Any] | None,
) -> ChangePreview:
    """The change :func:`set_mission` would make (same checks, same 422 messages), read
    only."""
    mission, renames = _parse_change(principal, fleet, mission_doc, renames_doc)
    current = repo.latest_version(session, fleet)
    old = mission_of(session, ctx, fleet, current or 1).mission
    try:
        diff = diff_missions(old, mission, renames)
    except ValueError as exc:
        raise ValidationFailed(str(exc)) from None
    changed = mission.fingerprint != old.fingerprint or bool(renames)
    moved = interrupted = 0
    if current is not None and changed:
        moved = len(repo.models_behind(session, fleet, current + 1))
        interrupted = repo.open_episodes(session, fleet)
    return ChangePreview(fleet, current, old, mission, renames, diff, changed, moved, interrupted)


def change_of(
    session: Session, principal: Principal, fleet: str, change_id: str
) -> dict[str, Any] | None:
    """What the change ``change_id`` of the fleet answered, None if it was never made."""
    _check_fleet(principal, fleet)
    row = repo.by_change(session, fleet, change_id)
    return None if row is None else dict(row.response or {})


def change_result(
    session: Session, principal: Principal, fleet: str, version: int
) -> dict[str, Any] | None:
    """What the change that made version ``version`` of the fleet's mission answered (users
    moved, episodes interrupted), None for a version not made by a change."""
    _check_fleet(principal, fleet)
    row = repo.get(session, fleet, version)
    return None if row is None or row.response is None else dict(row.response)


def body_hash_of(change_id: str, mission: Mission, renames: Renames) -> str:
    """A fingerprint of a change request as understood (the mission as validated)."""
    doc = {"change_id": change_id, "mission": mission.to_dict(), "renames": renames.to_dict()}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
