"""The head of a person's learner model: its row (the journal is ``journal``'s).

The model row holds ``version`` (up by one with every change), the learner's state document as
of ``state_version`` (a snapshot, written every few versions), and where the model started
(``base_state`` at ``base_version``: an imported document or the fleet's prior, or ``None`` for
a fresh learner).
Replaying the journal's entries after ``state_version`` onto the snapshot gives the learner at
``version``; replaying those after ``base_version`` onto the base gives it too (a rebuild).
The aggregate that keeps them in step is ``app.services.person_model``.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import bindparam, select, update
from sqlalchemy.orm import Session

from ..models import LearnerModel, User
from ._rows import Prepared, columns, conn, record, table

__all__ = [
    "ModelRow",
    "Origin",
    "advance",
    "base_state",
    "head",
    "move_base",
    "origin",
    "prior_contributors",
    "replace",
    "snapshot",
    "store_snapshot",
]


@dataclass(slots=True)
class ModelRow:
    """A model's head, without its documents."""

    version: int
    base_version: int
    episode_offset: int
    state_version: int
    mission_version: int  # the fleet's mission version the learner is laid out for
    base_mission_version: int  # the one its base (fresh or imported) was laid out for


@dataclass(frozen=True, slots=True)
class Origin:
    """Where a model's base came from: ``"fresh"``, ``"imported"`` or ``"fleet_prior"`` (then
    ``contributors``: how many people the prior averaged)."""

    kind: str = "fresh"
    contributors: int | None = None


_models = table(LearnerModel)
_users = table(User)
_HEAD = Prepared(
    select(*columns(_models, ModelRow)).where(_models.c.user_pk == bindparam("user_pk"))
)
_SNAPSHOT = Prepared(select(_models.c.state).where(_models.c.user_pk == bindparam("user_pk")))
_ADVANCE = Prepared(update(_models).where(_models.c.user_pk == bindparam("b_user_pk")), keyed=True)


def head(session: Session, user_pk: int) -> ModelRow | None:
    return record(ModelRow, _HEAD.first(session, {"user_pk": user_pk}))


def snapshot(session: Session, user_pk: int) -> dict[str, Any]:
    """The stored state document (the learner as of the row's ``state_version``)."""
    row = _SNAPSHOT.first(session, {"user_pk": user_pk})
    if row is None:
        raise LookupError(f"user {user_pk} has no model row")
    doc: dict[str, Any] = row[0]
    return doc


def base_state(session: Session, user_pk: int) -> dict[str, Any] | None:
    doc: dict[str, Any] | None = (
        conn(session)
        .execute(select(_models.c.base_state).where(_models.c.user_pk == user_pk))
        .scalar_one()
    )
    return doc


def origin(session: Session, user_pk: int) -> Origin:
    row = (
        conn(session)
        .execute(
            select(_models.c.base_origin, _models.c.base_contributors).where(
                _models.c.user_pk == user_pk
            )
        )
        .first()
    )
    return Origin() if row is None else Origin(row[0], row[1])


def prior_contributors(
    session: Session,
    *,
    fleet: str,
    algorithm: str,
    mission_version: int,
    min_episodes: int,
    limit: int,
) -> list[int]:
    """The users of ``fleet`` whose models may add to its prior for a newcomer learning with
    ``algorithm``: taking part, with that learner, at least ``min_episodes`` episodes and laid
    out for ``mission_version``; at most ``limit``, those whose models changed last first."""
    stmt = (
        select(_users.c.id)
        .join(_models, _models.c.user_pk == _users.c.id)
        .where(
            _users.c.fleet == fleet,
            _users.c.fleet_prior.is_(True),
            _users.c.algorithm == algorithm,
            _users.c.episode_count >= min_episodes,
            _models.c.mission_version == mission_version,
        )
        .order_by(_models.c.updated_at.desc(), _users.c.id)
        .limit(limit)
    )
    return list(conn(session).execute(stmt).scalars())


def advance(
    session: Session,
    user_pk: int,
    *,
    version: int,
    updated_at: dt.datetime,
    state: dict[str, Any] | None = None,
    mission_version: int | None = None,
) -> None:
    """Move the model to ``version``; with ``state``, the snapshot moves there too; with
    ``mission_version``, the model is now laid out for that mission version."""
    params: dict[str, Any] = {"b_user_pk": user_pk, "version": version, "updated_at": updated_at}
    if state is not None:
        params["state"], params["state_version"] = state, version
    if mission_version is not None:
        params["mission_version"] = mission_version
    _ADVANCE.run(session, params)


def store_snapshot(session: Session, user_pk: int, *, version: int, state: dict[str, Any]) -> None:
    """The learner's state as of ``version`` (the model's own version stays)."""
    conn(session).execute(
        update(_models)
        .where(_models.c.user_pk == user_pk)
        .values(state=state, state_version=version)
    )


def move_base(
    session: Session,
    user_pk: int,
    *,
    expect_base_version: int,
    base_state: dict[str, Any] | None,
    base_version: int,
    base_mission_version: int,
) -> bool:
    """Move the model's base to ``base_version`` (the learner then: ``base_state``), if it is
    still at ``expect_base_version`` (no reset or import since): whether it moved."""
    moved = conn(session).execute(
        update(_models)
        .where(_models.c.user_pk == user_pk, _models.c.base_version == expect_base_version)
        .values(
            base_state=base_state,
            base_version=base_version,
            base_mission_version=base_mission_version,
        )
    )
    return bool(moved.rowcount)


def replace(
    session: Session,
    user_pk: int,
    *,
    version: int,
    state: dict[str, Any],
    base_state: dict[str, Any] | None,
    episode_offset: int,
    mission_version: int,
    updated_at: dt.datetime,
    base_origin: Origin | None = None,
) -> None:
    """Start the model over at ``version`` from ``state`` (a reset, a new learner, an import:
    ``base_state`` is the imported document or the fleet's prior, ``None`` for a fresh
    learner; ``base_origin`` says which), laid out for ``mission_version``."""
    made = base_origin or Origin("fresh" if base_state is None else "imported")
    conn(session).execute(
        update(_models)
        .where(_models.c.user_pk == user_pk)
        .values(
            version=version,
            state=state,
            state_version=version,
            base_state=base_state,
            base_version=version,
            episode_offset=episode_offset,
            mission_version=mission_version,
            base_mission_version=mission_version,
            updated_at=updated_at,
            base_origin=made.kind,
            base_contributors=made.contributors,
        )
    )
