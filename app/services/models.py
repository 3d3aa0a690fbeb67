"""What a user's learner believes, the paper's metrics, and model administration."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.db.repositories import episodes as episodes_repo
from app.db.repositories import retention as retention_repo
from app.db.repositories import users as users_repo
from app.errors import ValidationFailed
from app.learning import Observation, StateFormatError, learner_from_state
from app.learning.evaluation import episode_metrics
from app.learning.learners import TabularLearner
from app.learning.negotiation import INTERACTION_CODE
from app.learning.state import same_state
from app.learning.types import Interaction
from app.schemas.common import ActionOut
from app.schemas.models import (
    ActionBelief,
    ContextModel,
    ModelOut,
    StartedFrom,
    StateModel,
    StatsOut,
)

from . import audit
from .auth import require_manager
from .context import Principal, ServiceContext, rng_for
from .episodes import action_out
from .person_model import PersonModel, fresh_learner
from .prior import started_from
from .users import visible_user

__all__ = [
    "RebuildReport",
    "every_user",
    "export_model",
    "fleets_with",
    "import_model",
    "imported_learner",
    "model_view",
    "rebuild_model",
    "reset_model",
    "snapshot_model",
    "stats",
]


def _num(x: float) -> float | None:
    return None if math.isnan(x) else x


def model_view(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    time_slot: str | None,
    situation: str | None,
    fleet: str | None = None,
) -> ModelOut:
    user = visible_user(session, principal, user_id, fleet=fleet)
    model = PersonModel.open(session, ctx, user)
    layout = ctx.missions.get(session, user.fleet, model.mission_version)
    mission, space = layout.mission, layout.space
    if time_slot is not None and time_slot not in [t.name for t in mission.time_slots]:
        raise ValidationFailed(
            f"time_slot must be one of {', '.join(t.name for t in mission.time_slots)}."
        )
    if situation is not None and situation not in mission.situations:
        raise ValidationFailed(f"situation must be one of {', '.join(mission.situations)}.")
    learner = model.learner
    now = model.now  # "if asked now": the person's next episode
    contexts = []
    for c in range(mission.n_contexts):
        slot, sit = mission.context_names(c)
        if (time_slot and slot != time_slot) or (situation and sit != situation):
            continue
        view = learner.explain(c, now)
        states = []
        for s in range(space.n_states):
            info = space.state_info(s)
            actions = [
                ActionBelief(
                    action=ActionOut(**action_out(space, a)),
                    q=float(view.q[a]),
                    visits=int(view.visits[a]),
                    kept_visits=None if view.kept_visits is None else float(view.kept_visits[a]),
                    since_last=int(view.since_last[a]),
                    measure=None if view.measure is None else float(view.measure[a]),
                    p=float(view.probabilities[a]),
                )
                for a in space.actions_of(s)
            ]
            states.append(
                StateModel(
                    state=info.kind.value, service=info.service, detail=info.detail, actions=actions
                )
            )
        contexts.append(ContextModel(time_slot=slot, situation=sit, states=states))
    return ModelOut(
        user_id=user.user_id,
        algorithm=user.algorithm,
        params=dict(user.params),
        version=model.version,
        episodes=user.episode_count,
        mission_version=model.mission_version,
        started_from=StartedFrom(**started_from(session, user.id)),
        contexts=contexts,
    )


def stats(
    session: Session,
    principal: Principal,
    user_id: str,
    *,
    last: int | None,
    fleet: str | None = None,
) -> StatsOut:
    user = visible_user(session, principal, user_id, fleet=fleet)
    rows = episodes_repo.metric_rows(session, user.id, last=last)
    interaction = np.asarray(
        [INTERACTION_CODE[Interaction(r.interaction_class)] for r in rows], dtype=np.int64
    )
    reward = np.asarray([r.total_reward for r in rows], dtype=np.float64)
    m = episode_metrics(
        np.asarray([r.initiated for r in rows], dtype=bool),
        interaction,
        np.asarray([r.success for r in rows], dtype=bool),
        np.asarray([r.queries for r in rows], dtype=np.int64),
        reward,
    )
    return StatsOut(
        episodes=len(rows),
        history_from=retention_repo.kept_from(session, user.id),
        missions=int(m["missions"]),
        interaction_rate=_num(m["interaction_rate"]),
        success_rate=_num(m["success_rate"]),
        queries_per_mission=_num(m["queries_per_mission"]),
        total_reward=float(reward.sum()),
        cumulative_reward=[0.0, *np.cumsum(reward).tolist()],
    )


def reset_model(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
    drop_corrections: bool = False,
) -> None:
    """Forget what was learned; the staff corrections in force stay, unless
    ``drop_corrections``."""
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet, lock=True)
    model = PersonModel.open(session, ctx, user, write=True)
    fresh = fresh_learner(user.algorithm, dict(user.params), model.mission)
    if not drop_corrections:
        fresh.guidance = model.learner.guidance.copy()
    # A fresh learner that keeps corrections is the base a rebuild starts from, as an import is
    model.reset(
        fresh,
        actor=principal,
        cause="reset",
        action="model.reset",
        detail={"corrections_kept": len(fresh.guidance)},
    )
    model.save()


def export_model(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
) -> dict[str, Any]:
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet)
    model = PersonModel.open(session, ctx, user)
    audit.record(
        session,
        principal,
        "model.export",
        target=user_id,
        fleet=user.fleet,
        detail={"version": model.version},
    )
    return model.document()


def import_model(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    doc: Any,
    *,
    fleet: str | None = None,
) -> ModelOut:
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet, lock=True)
    model = PersonModel.open(session, ctx, user, write=True)
    learner = imported_learner(session, ctx, user.fleet, model.mission_version, doc)
    user.algorithm, user.params = learner.algorithm, learner.params.to_dict()
    users_repo.save_profile(session, user)
    model.import_learner(
        learner,
        actor=principal,
        action="model.import",
        detail={"algorithm": learner.algorithm},
        episode_offset=max(model.head.episode_offset, learner.episodes - user.episode_count),
    )
    model.save()
    return model_view(
        session, ctx, principal, user_id, time_slot=None, situation=None, fleet=user.fleet
    )


def imported_learner(
    session: Session, ctx: ServiceContext, fleet: str, layout: int, doc: Any
) -> TabularLearner[Any]:
    """An exported learner state, carried to the fleet's mission version ``layout`` if it was
    learned under an earlier version of the fleet's mission; or 422."""
    meta = doc.get("mission") if isinstance(doc, dict) else None
    fingerprint = meta.get("fingerprint") if isinstance(meta, dict) else None
    source = layout
    if isinstance(fingerprint, str):
        for version in range(layout, 0, -1):
            if ctx.missions.get(session, fleet, version).mission.fingerprint == fingerprint:
                source = version
                break
    try:
        learner = learner_from_state(doc, ctx.missions.get(session, fleet, source).mission)
    except (StateFormatError, ValueError) as exc:
        raise ValidationFailed(f"Not a learner state this deployment can load: {exc}") from None
    return ctx.missions.carry(session, fleet, learner, source, layout)


@dataclass
class RebuildReport:
    """What ``attune models rebuild`` found: replayed writes, redrawn decisions, differences."""

    user_id: str
    version: int
    writes: int = 0
    samples: int = 0
    decisions: int = 0
    mismatched_decisions: list[str] = field(default_factory=list)
    identical: bool = False
    rebuilt: dict[str, Any] = field(default_factory=dict)


def rebuild_model(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    save: bool = False,
    fleet: str | None = None,
) -> RebuildReport:
    """Replay the user's history onto a fresh learner (or the imported base) and redraw every
    decision from the same seed stream; the result must equal the stored model. With ``save``,
    a rebuilt model that differs is stored (one version on, audited)."""
    user = visible_user(session, principal, user_id, fleet=fleet, lock=True)
    model = PersonModel.open(session, ctx, user, write=save)
    replay = model.replay()
    report = RebuildReport(user_id, model.version)
    for decision, context, seq in episodes_repo.decisions_for_rebuild(
        session, user.id, model.head.base_version
    ):
        learner = replay.through(decision.model_version)
        drawn_steps = [s for s in decision.chain if not s.get("forced")]
        start = drawn_steps[0]["state"] if drawn_steps else decision.state
        assert decision.draw is not None
        again = learner.select_action(
            Observation(context, start, seq),
            rng_for(ctx.settings.seed, user.seed_key, decision.draw),
        )
        same = np.allclose(again.probabilities, decision.probabilities, rtol=0, atol=1e-12) and (
            decision.forced or again.action == decision.action
        )
        report.decisions += 1
        if not same:
            report.mismatched_decisions.append(decision.id)
    learner = replay.through(model.version)
    report.writes, report.samples = replay.writes, replay.entries
    report.rebuilt = learner.to_state()
    stored = PersonModel.open(session, ctx, user).learner.to_state()
    report.identical = same_state(report.rebuilt, stored) and not report.mismatched_decisions
    if save and not report.identical:
        model.restore(learner)
        model.save()
        audit.record(
            session,
            principal,
            "model.rebuild",
            target=user_id,
            fleet=user.fleet,
            detail={
                "version": model.version,
                "mismatched_decisions": len(report.mismatched_decisions),
            },
        )
    return report


def snapshot_model(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
) -> bool:
    """Store the user's learner state as of its current version (the journal since the last
    snapshot replayed onto it); the model does not change. False when it was current."""
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet, lock=True)
    return PersonModel.open(session, ctx, user).store_snapshot()


def fleets_with(session: Session, user_id: str) -> list[str]:
    """The fleets that have a user of this id (the command line, which sees them all)."""
    return users_repo.fleets_with(session, user_id)


def every_user(session: Session) -> list[tuple[str, str]]:
    """(fleet, user id) of every user of the deployment (the command line)."""
    return users_repo.all_ids(session)
