"""The tables. History (episodes, decisions, feedback, the model's journal) is the source of
truth; each user's learner state sits beside it and changes in the same transaction as the rows
that fed it.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import Mapped, mapped_column

from .base import Base
from .types import LearnerStateType, UTCDateTime, utcnow

__all__ = [
    "ApiKey",
    "AuditEntry",
    "ChangeEvent",
    "ContextBelief",
    "Correction",
    "DataView",
    "Decision",
    "Episode",
    "Evaluation",
    "Feedback",
    "FleetMission",
    "FleetSettings",
    "HistoryFold",
    "JournalEntry",
    "LearnerModel",
    "Lease",
    "Rollout",
    "RolloutArm",
    "Shadow",
    "ShadowDecision",
    "User",
]

ID = 40  # server-chosen ids: a prefix and 32 hex digits
CLIENT_ID = 128  # client-chosen ids: ^[A-Za-z0-9._:-]{1,128}$


class ApiKey(Base):
    """An API key; only the SHA-256 of its secret is stored."""

    __tablename__ = "api_keys"

    id: Mapped[str] = mapped_column(String(ID), primary_key=True)
    prefix: Mapped[str] = mapped_column(String(16))
    secret_hash: Mapped[str] = mapped_column(String(64), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    name: Mapped[str | None] = mapped_column(String(200))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    revoked_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())


class User(Base):
    """A person a fleet serves: ``user_id`` is the fleet's own id for them (two fleets may both
    have a ``lin``), ``id`` the deployment's. The row is the per-user lock of every model
    update. ``seed_key`` names the user's stream of decision seeds: the user id for users made
    before fleets had ids of their own (their decisions redraw as they were), ``fleet/user_id``
    since."""

    __tablename__ = "users"
    # SQLite: AUTOINCREMENT, so that an erased user's number is never given to the next user
    # made (it keys their learner in every worker's cache, and each row that was theirs).
    __table_args__ = (UniqueConstraint("fleet", "user_id"), {"sqlite_autoincrement": True})

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    user_id: Mapped[str] = mapped_column(String(CLIENT_ID))
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    display_name: Mapped[str | None] = mapped_column(String(200))
    algorithm: Mapped[str] = mapped_column(String(32))
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    episode_count: Mapped[int] = mapped_column(Integer, default=0)
    draws: Mapped[int] = mapped_column(Integer, default=0)  # decisions drawn: the seed stream
    seed_key: Mapped[str] = mapped_column(String(2 * CLIENT_ID + 1))
    # False: the person neither starts from the fleet's prior nor adds to it (docs/api.md)
    fleet_prior: Mapped[bool] = mapped_column(Boolean, default=True)


class FleetSettings(Base):
    """A fleet's own settings, where they differ from the deployment's: whether its newcomers
    start from the fleet's prior (``prior_enabled``), and how long its raw history is kept
    (``history_days``; ``None``: kept until the person is erased). A fleet without a row has
    the defaults."""

    __tablename__ = "fleet_settings"

    fleet: Mapped[str] = mapped_column(String(CLIENT_ID), primary_key=True)
    prior_enabled: Mapped[bool] = mapped_column(Boolean, default=True)
    history_days: Mapped[int | None] = mapped_column(Integer)
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    updated_by: Mapped[str | None] = mapped_column(String(ID))


class FleetMission(Base):
    """One version of a fleet's mission: the document as set, and how it was set.

    Versions count 1, 2, 3... per fleet and are never changed or removed; the highest is the
    mission in force. A fleet gets its version 1 (the deployment's default mission) when its
    first user is created, unless its staff set one before. ``renames`` carried statistics from
    the previous version; ``change_id`` makes the change idempotent (``request_hash`` and
    ``response`` answer a repeat).
    """

    __tablename__ = "fleet_missions"
    __table_args__ = (
        UniqueConstraint("fleet", "version"),
        UniqueConstraint("fleet", "change_id"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    version: Mapped[int] = mapped_column(Integer)
    name: Mapped[str] = mapped_column(String(64))
    fingerprint: Mapped[str] = mapped_column(String(80))
    document: Mapped[dict[str, Any]] = mapped_column(JSON)
    renames: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    change_id: Mapped[str | None] = mapped_column(String(CLIENT_ID))
    request_hash: Mapped[str | None] = mapped_column(String(64))
    response: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    actor_key_id: Mapped[str | None] = mapped_column(String(ID))  # None: the default
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)


class LearnerModel(Base):
    """A user's learner: a snapshot of its state (the learning core's document) and where it
    started from.

    ``version`` goes up by one with every change and never goes back (a reset or an import is a
    change too). ``state`` is the learner as of ``state_version`` (written every few versions):
    replaying the journal's entries written after ``state_version`` onto it gives the learner
    at ``version``. ``base_state`` is the imported document the current model grew from (``None``:
    a fresh learner), ``base_version`` the version it had then: replaying the journal's entries
    written after ``base_version`` onto the base rebuilds the model.
    """

    __tablename__ = "learner_models"

    user_pk: Mapped[int] = mapped_column(
        ForeignKey("users.id", ondelete="CASCADE"), primary_key=True
    )
    version: Mapped[int] = mapped_column(Integer, default=0)
    state: Mapped[dict[str, Any]] = mapped_column(LearnerStateType())
    state_version: Mapped[int] = mapped_column(Integer, default=0)
    base_state: Mapped[dict[str, Any] | None] = mapped_column(LearnerStateType())
    base_version: Mapped[int] = mapped_column(Integer, default=0)
    # Added to a user's episode index to give the learner's: an imported model may have seen
    # more episodes than this user has, and its clock must never run backwards.
    episode_offset: Mapped[int] = mapped_column(Integer, default=0)
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    # The fleet's mission version the learner is laid out for, and the one its base was.
    mission_version: Mapped[int] = mapped_column(Integer, default=1)
    base_mission_version: Mapped[int] = mapped_column(Integer, default=1)
    # Where the base came from: "fresh" (a new learner), "imported" (an exported document) or
    # "fleet_prior" (the fleet's prior, averaged over ``base_contributors`` of its people).
    base_origin: Mapped[str] = mapped_column(String(16), default="fresh")
    base_contributors: Mapped[int | None] = mapped_column(Integer)


class Episode(Base):
    """One event near a user: a service negotiation, open until its last outcome."""

    __tablename__ = "episodes"
    __table_args__ = (
        UniqueConstraint("user_pk", "event_id"),
        UniqueConstraint("user_pk", "seq"),
        Index("ix_episodes_closed_at", "closed_at"),  # the shadows' pass: closed since
    )

    id: Mapped[str] = mapped_column(String(ID), primary_key=True)
    user_pk: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    seq: Mapped[int] = mapped_column(Integer)  # the user's 1-based episode index
    learner_episode: Mapped[int] = mapped_column(Integer)  # seq + the model's episode offset
    event_id: Mapped[str] = mapped_column(String(CLIENT_ID))
    robot_id: Mapped[str | None] = mapped_column(String(CLIENT_ID))
    occurred_at: Mapped[dt.datetime] = mapped_column(UTCDateTime())
    time_slot: Mapped[str] = mapped_column(String(64))
    situation: Mapped[str] = mapped_column(String(64))
    context: Mapped[int] = mapped_column(Integer)
    initiator: Mapped[str] = mapped_column(String(16))
    request_service: Mapped[str | None] = mapped_column(String(64))
    request_detail: Mapped[str | None] = mapped_column(String(64))
    status: Mapped[str] = mapped_column(String(16), default="open")
    state: Mapped[int] = mapped_column(Integer)
    total_reward: Mapped[float] = mapped_column(Float, default=0.0)
    interaction_class: Mapped[str] = mapped_column(String(8), default="none")
    initiated: Mapped[bool] = mapped_column(Boolean, default=False)
    success: Mapped[bool] = mapped_column(Boolean, default=False)
    queries: Mapped[int] = mapped_column(Integer, default=0)
    request_hash: Mapped[str] = mapped_column(String(64))
    response: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    closed_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())
    mission_version: Mapped[int] = mapped_column(Integer, default=1)  # the fleet's, at start
    # Minutes east of UTC of the offset ``occurred_at`` came with: the person's local time
    # (None: stored before offsets were kept; shown in UTC).
    utc_offset: Mapped[int | None] = mapped_column(Integer)


class Decision(Base):
    """What the robot was told to do at one step, and what the person did."""

    __tablename__ = "decisions"
    __table_args__ = (UniqueConstraint("episode_id", "position"),)

    id: Mapped[str] = mapped_column(String(ID), primary_key=True)
    episode_id: Mapped[str] = mapped_column(ForeignKey("episodes.id", ondelete="CASCADE"))
    position: Mapped[int] = mapped_column(Integer)
    state: Mapped[int] = mapped_column(Integer)
    action: Mapped[int] = mapped_column(Integer)
    probabilities: Mapped[list[float]] = mapped_column(JSON)
    chain: Mapped[list[dict[str, Any]]] = mapped_column(JSON)
    draw: Mapped[int | None] = mapped_column(Integer)  # position in the user's seed stream
    forced: Mapped[bool] = mapped_column(Boolean, default=False)  # the person chose the action
    model_version: Mapped[int] = mapped_column(Integer)  # the model it was drawn from
    decided_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    response: Mapped[str | None] = mapped_column(String(32))
    service: Mapped[str | None] = mapped_column(String(64))
    detail: Mapped[str | None] = mapped_column(String(64))
    feedback: Mapped[str | None] = mapped_column(String(16))
    reward: Mapped[float | None] = mapped_column(Float)
    next_state: Mapped[int | None] = mapped_column(Integer)
    answered_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())
    outcome_hash: Mapped[str | None] = mapped_column(String(64))
    outcome_response: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class Feedback(Base):
    """Explicit feedback on an episode, during or after it."""

    __tablename__ = "feedback"
    __table_args__ = (UniqueConstraint("episode_id", "feedback_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    episode_id: Mapped[str] = mapped_column(ForeignKey("episodes.id", ondelete="CASCADE"))
    feedback_id: Mapped[str] = mapped_column(String(CLIENT_ID))
    feedback: Mapped[str] = mapped_column(String(16))
    reward: Mapped[float] = mapped_column(Float)
    received_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    request_hash: Mapped[str] = mapped_column(String(64))
    response: Mapped[dict[str, Any]] = mapped_column(JSON)


class Correction(Base):
    """A staff correction of what was learned about a user: in one context, the person
    ``prefers`` a service and detail, the robot must ``avoid`` a service (or a detail), or must
    stay ``quiet``. Part of the user's history: the journal holds a "correction" entry when it
    is made and a "lift" entry when it is lifted (their ``correction_pk`` is this row's
    ``id``), so a rebuild replays it. ``correction_id`` makes the request idempotent
    (``request_hash`` and ``response`` answer a repeat)."""

    __tablename__ = "corrections"
    __table_args__ = (UniqueConstraint("user_pk", "correction_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    user_pk: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    correction_id: Mapped[str] = mapped_column(String(CLIENT_ID))
    kind: Mapped[str] = mapped_column(String(16))
    time_slot: Mapped[str] = mapped_column(String(64))
    situation: Mapped[str] = mapped_column(String(64))
    service: Mapped[str | None] = mapped_column(String(64))
    detail: Mapped[str | None] = mapped_column(String(64))
    note: Mapped[str | None] = mapped_column(String(500))
    actor_key_id: Mapped[str] = mapped_column(String(ID))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    model_version: Mapped[int] = mapped_column(Integer)  # the model version it produced
    lifted_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())
    lifted_by: Mapped[str | None] = mapped_column(String(ID))
    request_hash: Mapped[str] = mapped_column(String(64))
    response: Mapped[dict[str, Any]] = mapped_column(JSON)


class JournalEntry(Base):
    """The model's journal: what changed a person's learner model, one model version at a
    time, as typed entries (``app.db.repositories.journal`` reads and writes them; its record
    classes name every field of every kind).

    ``kind`` says which entry a row is, and each column means one thing for every kind that
    has it:

    - ``"transition"``: a step the learner was taught (the transitions of one version were one
      ``update`` call): ``episode`` (the learner's episode index), ``context``, ``state``,
      ``action``, ``reward``, ``next_state``, ``signal``;
    - ``"feedback"``: explicit feedback taught on a step: ``episode``, ``context``, ``state``,
      ``action``, ``reward``;
    - ``"correction"`` and ``"lift"``: a staff correction put in force or lifted:
      ``correction_pk`` (the correction's row), ``since`` (the episodes the learner had seen
      then), ``context`` (the context it is about, 0 if the mission no longer has it);
    - ``"mission"``: the model moved to mission version ``mission_version``;
    - ``"reset"``, ``"import"`` and ``"fold"``: the model started over from a new base at this
      version (a reset or a new learner, an imported document, a retention run's fold): they
      mark the base a rebuild starts from and are never replayed; ``detail`` says who and how.

    ``mission_version`` is, for every kind, the mission version whose layout the entry's
    indices refer to (for a move, the one moved to).
    """

    __tablename__ = "journal"
    __table_args__ = (
        Index("ix_journal_user_version", "user_pk", "version"),
        Index("ix_journal_user_episode", "user_pk", "episode"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    user_pk: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    version: Mapped[int] = mapped_column(Integer)
    kind: Mapped[str] = mapped_column(String(16))
    mission_version: Mapped[int] = mapped_column(Integer)
    episode: Mapped[int | None] = mapped_column(Integer)
    context: Mapped[int | None] = mapped_column(Integer)
    state: Mapped[int | None] = mapped_column(Integer)
    action: Mapped[int | None] = mapped_column(Integer)
    reward: Mapped[float | None] = mapped_column(Float)
    next_state: Mapped[int | None] = mapped_column(Integer)
    signal: Mapped[int | None] = mapped_column(Integer)
    correction_pk: Mapped[int | None] = mapped_column(
        ForeignKey("corrections.id", ondelete="CASCADE")
    )
    since: Mapped[int | None] = mapped_column(Integer)
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class AuditEntry(Base):
    """One admin action: who (the key, its role and fleet), what (action, target), when.

    Append only: rows are added and read, never changed or removed (the ORM refuses both, see
    ``app.db.repositories.audit``; the database too, with triggers), and they outlive their
    target (no foreign key: the entry of a deleted user stays). The one change allowed, by the
    database as well: once a person is erased, the ``detail`` of the entries about them becomes
    ``{"erased": true}`` (who did what, when, and to which id, stay).
    """

    __tablename__ = "audit_log"

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    actor_key_id: Mapped[str] = mapped_column(String(ID))  # "cli": the command line
    actor_role: Mapped[str] = mapped_column(String(16))
    actor_fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    action: Mapped[str] = mapped_column(String(32))  # "user.delete", "model.reset", ...
    target: Mapped[str] = mapped_column(String(CLIENT_ID))  # a user id or a key id
    fleet: Mapped[str | None] = mapped_column(String(CLIENT_ID))  # the target's fleet
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class DataView(Base):
    """One read of a person's data by staff or an admin: who (the key, its role and fleet),
    when, what (``what``: the API resource or console page) and through which door (``via``:
    ``api`` or ``console``). Robots' reads are not recorded. Part of the person's data: erased
    with them (the foreign key cascades); older entries than the deployment's window
    (``ATTUNE_VIEW_LOG_DAYS``) are removed as new ones are added."""

    __tablename__ = "data_views"
    __table_args__ = (
        Index("ix_data_views_user_id", "user_pk", "id"),
        Index("ix_data_views_fleet_id", "fleet", "id"),
        Index("ix_data_views_fleet_at", "fleet", "at"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    user_pk: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))  # the person's
    at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    actor_key_id: Mapped[str] = mapped_column(String(ID))
    actor_role: Mapped[str] = mapped_column(String(16))
    actor_fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    what: Mapped[str] = mapped_column(String(32))
    via: Mapped[str] = mapped_column(String(8))


class HistoryFold(Base):
    """What a retention run kept of a person's removed history: the episodes up to
    ``upto_seq`` (all closed, received before ``kept_from``) are folded into ``doc`` (the
    profile's walk over them, :mod:`app.services.folds`) and into the model's base (the
    learner at ``upto_version``, the model's base since), and then removed with the journal's
    entries up to ``upto_version``. Part of the person's data: erased with them."""

    __tablename__ = "history_folds"

    user_pk: Mapped[int] = mapped_column(
        ForeignKey("users.id", ondelete="CASCADE"), primary_key=True
    )
    upto_seq: Mapped[int] = mapped_column(Integer)
    upto_version: Mapped[int] = mapped_column(Integer)
    kept_from: Mapped[dt.datetime] = mapped_column(UTCDateTime())
    folded_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    doc: Mapped[dict[str, Any]] = mapped_column(JSON)


class Lease(Base):
    """A job that one process of the deployment runs at a time (``retention``: the retention
    run, whether the service's own at ``ATTUNE_RETENTION_AT`` or ``attune retention run``):
    ``holder`` holds it until ``expires_at`` and renews it while it works; it took it at
    ``acquired_at``. A lease whose ``expires_at`` has passed is free (a holder that finished
    sets it to the time it let go; one that died lets it run out). The row is taken by a
    conditional ``UPDATE`` (or the first ``INSERT``) in a transaction of its own, so it works
    on SQLite, on PostgreSQL and through a pooler in transaction pooling, where a
    session-level advisory lock would not."""

    __tablename__ = "leases"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    holder: Mapped[str] = mapped_column(String(200))  # host:pid:random, one per taking
    acquired_at: Mapped[dt.datetime] = mapped_column(UTCDateTime())
    expires_at: Mapped[dt.datetime] = mapped_column(UTCDateTime())


class ContextBelief(Base):
    """What a person is believed to want in one context (``time_slot``, ``situation``: by
    name, so a mission change keeps it), from their own answers: the profile's walk over the
    context's episodes as they ended (:class:`app.learning.beliefs.BeliefFold`'s document),
    up to episode ``upto_seq``. Kept so that each ending episode is weighed at once against
    what came before (a change is news for staff), not when someone reads the profile. Part of
    the person's data: erased with them; a retention run leaves it (it holds no episode)."""

    __tablename__ = "context_beliefs"

    user_pk: Mapped[int] = mapped_column(
        ForeignKey("users.id", ondelete="CASCADE"), primary_key=True
    )
    time_slot: Mapped[str] = mapped_column(String(64), primary_key=True)
    situation: Mapped[str] = mapped_column(String(64), primary_key=True)
    upto_seq: Mapped[int] = mapped_column(Integer)
    doc: Mapped[dict[str, Any]] = mapped_column(JSON)


class ChangeEvent(Base):
    """A change in what a person wants in one context, as Attune decided it (``source``:
    ``profile``, what the profile says changed, for every learner; ``learner``, the learner's
    own change test): before, ``before_service``/``before_detail``; from episode ``seq`` on
    (which happened ``at``, local time ``utc_offset``), ``now_service``/``now_detail`` (no
    service: they turn it down and chose nothing else yet); decided when episode
    ``detected_seq`` ended (``detected_at``), on ``evidence`` (the episodes that showed it:
    what the person chose and turned down). Part of the person's history: it stays through a
    rebuild, a mission change and a retention run, and goes when they are erased."""

    __tablename__ = "change_events"
    __table_args__ = (
        Index("ix_change_events_user_id", "user_pk", "id"),
        Index("ix_change_events_fleet_detected", "fleet", "detected_at"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    user_pk: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))  # the person's
    source: Mapped[str] = mapped_column(String(16))
    time_slot: Mapped[str] = mapped_column(String(64))
    situation: Mapped[str] = mapped_column(String(64))
    seq: Mapped[int] = mapped_column(Integer)
    at: Mapped[dt.datetime] = mapped_column(UTCDateTime())
    utc_offset: Mapped[int | None] = mapped_column(Integer)
    detected_seq: Mapped[int] = mapped_column(Integer)
    detected_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    before_service: Mapped[str | None] = mapped_column(String(64))
    before_detail: Mapped[str | None] = mapped_column(String(64))
    now_service: Mapped[str | None] = mapped_column(String(64))
    now_detail: Mapped[str | None] = mapped_column(String(64))
    evidence: Mapped[list[dict[str, Any]]] = mapped_column(JSON)


class Evaluation(Base):
    """An evaluation of candidate learners on a fleet's logged decisions, run as a background
    job (``POST /v1/admin/fleets/{fleet}/evaluations``; :mod:`app.services.evaluation_jobs`):
    what was asked (``request``: the candidates, the period, the estimator), by whom, its
    ``status`` (``queued``, ``running``, ``done``, ``failed``, ``cancelled``), how far it got
    (``done_people`` of ``total_people``) and, once done, its ``result`` (the estimates, per
    candidate and per person). A job is idempotent on the fleet's ``request_id``. At most one
    job of a fleet is queued or running: the partial unique index ``ux_evaluations_active``
    says so to every process of the deployment. The process that runs a job writes
    ``heartbeat_at`` as it goes; a queued or running job whose heartbeat is older than the
    stale limit was left by a process that stopped, and counts as failed. The result names
    people: an erased person's row is removed from it."""

    __tablename__ = "evaluations"
    __table_args__ = (
        UniqueConstraint("fleet", "request_id", name="uq_evaluations_fleet_request"),
        Index("ix_evaluations_fleet_created", "fleet", "created_at"),
        Index(
            "ux_evaluations_active",
            "fleet",
            unique=True,
            sqlite_where=text("status IN ('queued', 'running')"),
            postgresql_where=text("status IN ('queued', 'running')"),
        ),
    )

    id: Mapped[str] = mapped_column(String(ID), primary_key=True)  # ev_ and 32 hex digits
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    request_id: Mapped[str] = mapped_column(String(CLIENT_ID))
    request_hash: Mapped[str] = mapped_column(String(64))
    request: Mapped[dict[str, Any]] = mapped_column(JSON)
    status: Mapped[str] = mapped_column(String(16))
    actor_key_id: Mapped[str] = mapped_column(String(ID))
    actor_role: Mapped[str] = mapped_column(String(16))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    started_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())
    finished_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())
    heartbeat_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    holder: Mapped[str | None] = mapped_column(String(200))  # host:pid:random of its runner
    done_people: Mapped[int] = mapped_column(Integer, default=0)
    total_people: Mapped[int | None] = mapped_column(Integer)
    cancel_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    error: Mapped[str | None] = mapped_column(String(2000))
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON)


class Rollout(Base):
    """A fleet's rollout of a candidate learner (``PUT /v1/admin/fleets/{fleet}/rollout``;
    :mod:`app.services.rollouts`): the candidate (``algorithm``, ``params``), the ``share`` of
    the fleet's people it serves, the ``salt`` of the stable hash that chose them, and how it
    ended (``status``: ``running``, ``promoted``, ``rolled_back``; by whom, when, why). At most
    one rollout of a fleet runs at a time (the partial unique index
    ``ux_rollouts_running``)."""

    __tablename__ = "rollouts"
    __table_args__ = (
        Index("ix_rollouts_fleet_started", "fleet", "started_at"),
        Index(
            "ux_rollouts_running",
            "fleet",
            unique=True,
            sqlite_where=text("status = 'running'"),
            postgresql_where=text("status = 'running'"),
        ),
    )

    id: Mapped[str] = mapped_column(String(ID), primary_key=True)  # ro_ and 32 hex digits
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    algorithm: Mapped[str] = mapped_column(String(32))
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    share: Mapped[float] = mapped_column(Float)
    salt: Mapped[str] = mapped_column(String(32))
    status: Mapped[str] = mapped_column(String(16))
    started_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    started_by: Mapped[str] = mapped_column(String(ID))
    ended_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())
    ended_by: Mapped[str | None] = mapped_column(String(ID))  # a key id, or "guard"
    end_reason: Mapped[str | None] = mapped_column(String(500))


class RolloutArm(Base):
    """A person's arm in a rollout, stored when they were assigned (``candidate``: served by the
    rollout's candidate; ``control``: by the learner they had), so that a lower share, a
    mission change or a restart never moves them: only staff (a higher share, promote, roll
    back) do. ``previous_algorithm``/``previous_params``: the learner a candidate-arm person had
    before, which a roll back gives them back. Part of the person's data: erased with them."""

    __tablename__ = "rollout_arms"
    __table_args__ = (
        Index("ix_rollout_arms_user", "user_pk"),
        Index("ix_rollout_arms_pending", "pending"),
    )

    rollout_id: Mapped[str] = mapped_column(
        ForeignKey("rollouts.id", ondelete="CASCADE"), primary_key=True
    )
    user_pk: Mapped[int] = mapped_column(
        ForeignKey("users.id", ondelete="CASCADE"), primary_key=True
    )
    arm: Mapped[str] = mapped_column(String(16))
    assigned_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    previous_algorithm: Mapped[str] = mapped_column(String(32))
    previous_params: Mapped[dict[str, Any]] = mapped_column(JSON)
    # A move to the learner their arm gives them is owed (done a person at a time, in the
    # background); ``served_since``: since when their arm's learner serves them (the episodes
    # compared are those begun since; None until the first move is done).
    pending: Mapped[bool] = mapped_column(Boolean, default=False)
    served_since: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())


class Shadow(Base):
    """A candidate learner that decides beside a fleet's learners without acting
    (``PUT /v1/admin/fleets/{fleet}/shadow``; :mod:`app.services.shadows`): for the ``share``
    of the fleet's people whose salted hash falls below it, each decision the robots were told
    is also decided by the candidate, after the episode ends, and stored
    (``shadow_decisions``). ``checked_until``: the episodes closed before it were looked at;
    ``estimate``: the newest off-policy estimate of the candidate over the episodes since the
    shadow started (``estimated_at``). At most one shadow of a fleet runs at a time."""

    __tablename__ = "shadows"
    __table_args__ = (
        Index("ix_shadows_fleet_started", "fleet", "started_at"),
        Index(
            "ux_shadows_running",
            "fleet",
            unique=True,
            sqlite_where=text("status = 'running'"),
            postgresql_where=text("status = 'running'"),
        ),
    )

    id: Mapped[str] = mapped_column(String(ID), primary_key=True)  # sh_ and 32 hex digits
    fleet: Mapped[str] = mapped_column(String(CLIENT_ID))
    algorithm: Mapped[str] = mapped_column(String(32))
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    share: Mapped[float] = mapped_column(Float)
    salt: Mapped[str] = mapped_column(String(32))
    status: Mapped[str] = mapped_column(String(16))  # running, stopped
    started_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
    started_by: Mapped[str] = mapped_column(String(ID))
    stopped_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())
    stopped_by: Mapped[str | None] = mapped_column(String(ID))
    checked_until: Mapped[dt.datetime] = mapped_column(UTCDateTime())
    estimate: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    estimated_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime())


class ShadowDecision(Base):
    """What a shadow's candidate would have decided at one of the robots' decisions: the action
    it drew, its distribution over the decision's actions, and its probability of the robot's
    action. Part of the person's history: it goes with the decision (a retention run) and with
    the person (an erasure)."""

    __tablename__ = "shadow_decisions"
    __table_args__ = (Index("ix_shadow_decisions_shadow_at", "shadow_id", "decided_at"),)

    decision_id: Mapped[str] = mapped_column(
        ForeignKey("decisions.id", ondelete="CASCADE"), primary_key=True
    )
    shadow_id: Mapped[str] = mapped_column(
        ForeignKey("shadows.id", ondelete="CASCADE"), primary_key=True
    )
    user_pk: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"))
    decided_at: Mapped[dt.datetime] = mapped_column(UTCDateTime())
    state: Mapped[int] = mapped_column(Integer)
    action: Mapped[int] = mapped_column(Integer)
    probabilities: Mapped[list[float]] = mapped_column(JSON)
    logged_action: Mapped[int] = mapped_column(Integer)
    logged_probability: Mapped[float] = mapped_column(Float)
    agrees: Mapped[bool] = mapped_column(Boolean)
