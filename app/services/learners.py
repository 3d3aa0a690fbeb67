"""A user's learner: made, loaded, taught and saved through one path for every write.

``load_learner`` gives the learner at the model's current version: the worker's cached one, or
the stored snapshot with the journal's later samples replayed onto it. ``save_learner`` teaches
it one write's samples (the transitions of an outcome, or one feedback), records them in the
journal, moves the model's version on by one and, every ``snapshot_every`` versions, stores the
learner's state. ``replace_model`` replaces the model (a reset, a new learner, an import) and
records who did it. The cache gets the learner back only once the transaction commits.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from itertools import groupby
from typing import Any, Literal

from sqlalchemy.orm import Session

from app.db.repositories import corrections as corrections_repo
from app.db.repositories import models as repo
from app.db.repositories.models import ModelRow, SampleRow
from app.db.repositories.users import UserRow
from app.db.types import utcnow
from app.errors import ValidationFailed
from app.learning import Mission, Polarity, Transition, learner_from_state, make_learner
from app.learning.guidance import Rule
from app.learning.learners import TabularLearner

from . import audit
from .context import Principal, ServiceContext, after_commit

__all__ = [
    "Mover",
    "Rules",
    "StartOver",
    "base_learner",
    "fresh_learner",
    "load_learner",
    "replace_model",
    "replay",
    "save_learner",
    "save_move",
    "transition_samples",
]

StartOver = Literal["fresh", "imported"]
# The staff correction a "correction" or "lift" sample of the journal names (app.learning.guidance)
Rules = Callable[[SampleRow], Rule]
# Carries a learner from one mission version to another (a "mission" sample in the journal).
Mover = Callable[[TabularLearner[Any], int, int], TabularLearner[Any]]


def fresh_learner(
    algorithm: str, params: dict[str, Any] | None, mission: Mission
) -> TabularLearner[Any]:
    """A new learner, or 422 naming what is wrong with the algorithm or its parameters."""
    try:
        return make_learner(algorithm, params, mission)
    except ValueError as exc:
        raise ValidationFailed(str(exc)) from None


def base_learner(
    session: Session, ctx: ServiceContext, user: UserRow, model: ModelRow
) -> TabularLearner[Any]:
    """The learner a rebuild of the user's model starts from, at ``model.base_version`` and
    laid out for ``model.base_mission_version``: the stored base (an import, the fleet's
    prior, or a retention run's fold), or a fresh learner."""
    base = repo.base_state(session, user.id)
    mission = ctx.missions.get(session, user.fleet, model.base_mission_version).mission
    if base:
        return learner_from_state(base, mission)
    return fresh_learner(user.algorithm, dict(user.params), mission)


def replay(
    learner: TabularLearner[Any],
    samples: Iterable[SampleRow],
    *,
    layout: int,
    move: Mover | None = None,
    rules: Rules | None = None,
) -> tuple[TabularLearner[Any], int, int]:
    """Teach ``learner`` (laid out for mission version ``layout``) journal entries in order,
    one call per model version (as they were taught), following the moves to other mission
    versions with ``move`` and the staff corrections with ``rules``; returns (the learner, its
    layout, the number of versions replayed)."""
    writes = 0
    for _, grouped in groupby(samples, key=lambda s: s.version):
        group = list(grouped)
        if group[0].kind == "mission":
            target = group[0].mission_version
            if move is None:
                raise ValueError(
                    f"version {group[0].version} moves the model to mission "
                    f"version {target}, and no mover was given"
                )
            learner, layout = move(learner, layout, target), target
        else:
            _teach(learner, group, rules)
        writes += 1
    return learner, layout, writes


def _teach(
    learner: TabularLearner[Any], samples: Sequence[SampleRow], rules: Rules | None = None
) -> None:
    first = samples[0]
    if first.kind == "mission":
        raise ValueError("a move to another mission version is not taught; see replay")
    if first.kind in ("correction", "lift"):
        if rules is None:
            raise ValueError(
                f"version {first.version} is a staff correction, and no rules were given"
            )
        rule = rules(first)
        if first.kind == "correction":
            learner.correct(rule)
        elif learner.guidance.get(rule.id) is not None:
            learner.lift(rule.id)
        else:  # already out of the model (an import or a reset dropped it): a version still
            learner.version += 1
    elif first.kind == "feedback":
        learner.feedback(first.episode, first.context, first.action, first.reward)
    else:
        learner.update(
            [
                Transition(
                    s.episode,
                    s.context,
                    s.state,
                    s.action,
                    s.reward,
                    _next_state(s),
                    Polarity(s.signal),
                )
                for s in samples
            ]
        )


def _next_state(sample: SampleRow) -> int:
    if sample.next_state is None:
        raise ValueError(f"a transition sample of version {sample.version} has no next state")
    return sample.next_state


def transition_samples(
    user_pk: int, transitions: Sequence[Transition], mission_version: int
) -> list[SampleRow]:
    """The journal entries of one ``update`` call (the version is set when saved)."""
    return [
        SampleRow(
            user_pk,
            0,
            "transition",
            t.episode,
            t.context,
            t.state,
            t.action,
            float(t.reward),
            t.next_state,
            int(t.signal),
            mission_version,
        )
        for t in transitions
    ]


def load_learner(
    session: Session,
    ctx: ServiceContext,
    fleet: str,
    user_pk: int,
    model: ModelRow,
    *,
    for_write: bool,
) -> TabularLearner[Any]:
    """The learner of user ``user_pk`` (of ``fleet``) at ``model.version``, laid out for the
    model's mission version.

    ``for_write``: the caller holds the user's lock and will hand the learner to
    :func:`save_learner`; the worker's cached learner is taken for it (no other request sees it
    until the commit puts it back). A reader gets a private learner of its own.
    """
    if for_write:
        cached = ctx.cache.take(user_pk, model.version)
        if cached is not None:
            return cached
    mission = ctx.missions.get(session, fleet, model.mission_version).mission
    learner = learner_from_state(repo.snapshot(session, user_pk), mission)
    if model.version > model.state_version:  # a move always stores a snapshot: no move here
        learner, _, _ = replay(
            learner,
            repo.samples_since(session, user_pk, model.state_version),
            layout=model.mission_version,
        )
    return learner


def save_move(
    session: Session,
    ctx: ServiceContext,
    user_pk: int,
    model: ModelRow,
    learner: TabularLearner[Any],
    mission_version: int,
) -> None:
    """Store the user's learner carried to ``mission_version``: one version on, journalled as
    a "mission" sample, with a snapshot (a snapshot is always laid out for the model's mission
    version)."""
    model.version += 1
    model.mission_version = mission_version
    repo.advance(
        session,
        user_pk,
        version=model.version,
        updated_at=utcnow(),
        state=learner.to_state(),
        mission_version=mission_version,
    )
    model.state_version = model.version
    repo.add_samples(
        session,
        [SampleRow(user_pk, model.version, "mission", 0, 0, 0, 0, 0.0, None, 0, mission_version)],
    )
    version = model.version
    after_commit(session, lambda: ctx.cache.put(user_pk, version, learner))


def save_learner(
    session: Session,
    ctx: ServiceContext,
    user_pk: int,
    model: ModelRow,
    learner: TabularLearner[Any],
    samples: Sequence[SampleRow] = (),
    *,
    snapshot: bool = False,
    rules: Rules | None = None,
) -> None:
    """Store a write's change of the user's model: one version on.

    With ``samples`` (the transitions of one report, or one feedback): teach them to
    ``learner`` and journal them; the learner's state is stored when the snapshot cadence
    (``snapshot_every`` versions) is due, or at once with ``snapshot``. The learner raises
    ``ValueError`` before changing anything if a sample does not fit; then nothing is stored.
    A staff correction (one "correction" or "lift" sample, taught with ``rules``) is always
    stored with a snapshot, so loading a model never replays one.

    With neither, nothing is stored; the learner just goes back to the cache. A model replaced
    as a whole goes through :func:`replace_model`.
    """
    if samples or snapshot:
        if samples:
            _teach(learner, samples, rules)
            snapshot = snapshot or samples[0].kind in ("correction", "lift")
        model.version += 1
        due = snapshot or model.version - model.state_version >= ctx.settings.snapshot_every
        repo.advance(
            session,
            user_pk,
            version=model.version,
            updated_at=utcnow(),
            state=learner.to_state() if due else None,
        )
        if due:
            model.state_version = model.version
        for s in samples:
            s.version = model.version
        repo.add_samples(session, list(samples))
    version = model.version
    after_commit(session, lambda: ctx.cache.put(user_pk, version, learner))


def replace_model(
    session: Session,
    ctx: ServiceContext,
    actor: Principal,
    user: UserRow,
    model: ModelRow,
    learner: TabularLearner[Any],
    *,
    start_over: StartOver,
    action: str,
    detail: dict[str, Any],
    episode_offset: int | None = None,
) -> int:
    """Replace the user's model by ``learner``, one version on; the history stays. A reset or
    a new learner starts over ``"fresh"``; an imported document (or a reset that keeps the
    corrections) is ``"imported"``: it becomes the base a rebuild starts from.
    ``episode_offset`` moves the learner's episode clock.

    Who did it, and when, is recorded with the change, whatever the route (the API, the
    console, the command line): the user's stored corrections that the new model does not
    hold are lifted by ``actor`` now (``lifted_at``, ``lifted_by``), those it holds are in
    force again, and the audit log gets ``action`` with ``detail`` and
    ``corrections_lifted``. Returns how many corrections it lifted.
    """
    ctx.cache.drop(user.id)
    model.version += 1
    model.base_version = model.state_version = model.version
    if episode_offset is not None:
        model.episode_offset = episode_offset
    state = learner.to_state()
    now = utcnow()
    repo.replace(
        session,
        user.id,
        version=model.version,
        state=state,
        base_state=state if start_over == "imported" else None,
        episode_offset=model.episode_offset,
        mission_version=model.mission_version,
        updated_at=now,
    )
    model.base_mission_version = model.mission_version
    lifted = 0
    for row in corrections_repo.for_user(session, user.id):
        held = learner.guidance.get(row.correction_id) is not None
        if row.id is None or held == (row.lifted_at is None):
            continue
        lifted += not held
        corrections_repo.lift(
            session, row.id, at=None if held else now, by=None if held else actor.key_id
        )
    audit.record(
        session,
        actor,
        action,
        target=user.user_id,
        fleet=user.fleet,
        detail={**detail, "version": model.version, "corrections_lifted": lifted},
    )
    version = model.version
    after_commit(session, lambda: ctx.cache.put(user.id, version, learner))
    return lifted
