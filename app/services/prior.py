"""A fleet's prior for newcomers (docs/api.md, "A fleet's prior"; docs/method.md §16).

A new user of a fleet starts from the fleet's prior when the fleet allows it (the default), the
person takes part (``fleet_prior``, the default) and at least ``prior_min_contributors`` of the
fleet's people can contribute: taking part too, learning with the newcomer's algorithm, with at
least ``prior_min_episodes`` episodes, their models laid out for the mission in force. The prior
(``app.learning.prior``) averages their learners' tables per negotiation step, each person
counting once; it is built at that moment and kept as the newcomer's model base, so a rebuild
starts from the very same prior.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import fleets as repo
from app.db.repositories import models as models_repo
from app.db.repositories import users as users_repo
from app.db.repositories.models import Origin
from app.db.types import utcnow
from app.errors import Forbidden
from app.learning.learners import ALGORITHMS, TabularLearner
from app.learning.prior import FRESH_ONLY, population_prior

from . import audit
from .auth import require_manager
from .context import Principal, ServiceContext
from .missions import current_version
from .person_model import PersonModel, fresh_learner

__all__ = [
    "SHARED",
    "fleet_prior_view",
    "prior_enabled",
    "set_fleet_prior",
    "started_from",
    "starting_learner",
]

SHARED = (
    "per negotiation step of each context: the contributors' rates of each outcome and "
    "mean rewards, averaged with each person counting once, at a fixed weight; a step "
    "enters only when at least 3 contributors have evidence on it. Nothing else: no "
    "episode counts, no times, no open episodes, no staff corrections."
)


def prior_enabled(session: Session, fleet: str) -> bool:
    row = repo.get(session, fleet)
    return True if row is None else row.prior_enabled


def _contributors(
    session: Session, ctx: ServiceContext, fleet: str, algorithm: str, mission_version: int
) -> list[int]:
    s = ctx.settings
    return models_repo.prior_contributors(
        session,
        fleet=fleet,
        algorithm=algorithm,
        mission_version=mission_version,
        min_episodes=s.prior_min_episodes,
        limit=max(s.prior_max_contributors, s.prior_min_contributors),
    )


def starting_learner(
    session: Session,
    ctx: ServiceContext,
    fleet: str,
    algorithm: str,
    params: dict[str, Any] | None,
    mission_version: int,
    *,
    takes_part: bool,
) -> tuple[TabularLearner[Any], Origin]:
    """The learner a new user of ``fleet`` starts with, and where it came from: the fleet's
    prior when it is in force for this user, else a fresh learner (422 for a bad algorithm or
    parameters, either way)."""
    mission = ctx.missions.get(session, fleet, mission_version).mission
    fresh = fresh_learner(algorithm, params, mission)
    if not takes_part or algorithm in FRESH_ONLY or not prior_enabled(session, fleet):
        return fresh, Origin()
    pks = _contributors(session, ctx, fleet, algorithm, mission_version)
    if len(pks) < ctx.settings.prior_min_contributors:
        return fresh, Origin()
    learners = []
    for pk in pks:
        contributor = users_repo.by_pk(session, pk)
        assert contributor is not None  # listed from the user rows
        learners.append(PersonModel.open(session, ctx, contributor).learner)
    prior = population_prior(
        algorithm, fresh.params.to_dict(), mission, learners, strength=ctx.settings.prior_strength
    )
    return prior, Origin("fleet_prior", len(learners))


def started_from(session: Session, user_pk: int) -> dict[str, Any]:
    made = models_repo.origin(session, user_pk)
    return {"kind": made.kind, "contributors": made.contributors}


def fleet_prior_view(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str
) -> dict[str, Any]:
    """``GET /v1/admin/fleets/{fleet}/prior`` (the fleet's staff, admins)."""
    _check_fleet(principal, fleet)
    row = repo.get(session, fleet)
    enabled = True if row is None else row.prior_enabled
    version = current_version(session, ctx, fleet)
    s = ctx.settings
    counts = {
        name: len(_contributors(session, ctx, fleet, name, version)) for name in sorted(ALGORITHMS)
    }
    return {
        "fleet": fleet,
        "enabled": enabled,
        "in_force": sorted(
            n
            for n, k in counts.items()
            if enabled and n not in FRESH_ONLY and k >= s.prior_min_contributors
        ),
        "contributors": counts,
        "min_contributors": s.prior_min_contributors,
        "min_episodes": s.prior_min_episodes,
        "max_contributors": s.prior_max_contributors,
        "strength": s.prior_strength,
        "mission_version": version,
        "shared": SHARED,
        "updated_at": None if row is None else row.updated_at,
        "updated_by": None if row is None else row.updated_by,
    }


def set_fleet_prior(
    session: Session, ctx: ServiceContext, principal: Principal, fleet: str, *, enabled: bool
) -> dict[str, Any]:
    """``PUT /v1/admin/fleets/{fleet}/prior``: turn the fleet's prior on or off for the
    fleet's next newcomers (models made from it before keep it)."""
    _check_fleet(principal, fleet)
    row = repo.get(session, fleet)
    if row is None or row.prior_enabled != enabled:
        repo.set_prior(session, fleet, enabled=enabled, now=utcnow(), actor=principal.key_id)
        audit.record(
            session,
            principal,
            "fleet.prior",
            target=fleet,
            fleet=fleet,
            detail={"enabled": enabled},
        )
    return fleet_prior_view(session, ctx, principal, fleet)


def _check_fleet(principal: Principal, fleet: str) -> None:
    require_manager(principal)
    if not principal.sees(fleet):
        raise Forbidden("Staff keys manage their own fleet's prior only.")
