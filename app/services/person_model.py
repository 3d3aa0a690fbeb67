"""A person's learner model as one aggregate: opened, changed, saved.

::

    model = PersonModel.open(session, ctx, user)              # to read (a private learner)
    model = PersonModel.open(session, ctx, user, write=True)  # the caller holds the user's lock
    model.learner                                             # loaded when first used
    model.teach(transitions)       # an outcome's steps          \\
    model.feedback(...)            # explicit feedback on a step  |  each one version on,
    model.correct(...) / .lift(...)  # a staff correction          |  journalled as a typed
    model.move(mission_version)    # to another mission version   |  entry
    model.replace(learner, ...)    # a reset, a new learner, an import (a new base)
    model.save()                   # journal, head (and snapshot when due), cache on commit

*Open* reads the model's head (every person is created with one: a person without it is a
broken database, and says so); the user row, locked by the caller, is the per-person lock of
every write. *Load* gives the learner at the head's version: for a writer the worker's cached
one (taken, so that no one else sees it change), else the stored snapshot with the journal's
later entries replayed onto it. A change applies to the learner what its journal entry says, by
the same code a replay runs (:func:`apply`), so that a rebuild is the model by construction.
*Save* writes the change's entries, moves the head (storing the learner's state every
``snapshot_every`` versions, and at once for a staff correction, a move or a new base) and
gives the learner back to the cache once the transaction commits.

:class:`Replay` is the other way in: the model's base taught its journal, as far as asked (a
rebuild, a retention run's fold).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable, Iterable, Iterator, Sequence
from itertools import groupby
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import corrections as corrections_repo
from app.db.repositories import journal
from app.db.repositories import models as repo
from app.db.repositories.corrections import CorrectionRow
from app.db.repositories.models import ModelRow, Origin
from app.db.repositories.users import UserRow
from app.db.types import utcnow
from app.errors import ValidationFailed
from app.learning import Mission, Polarity, learner_from_state, make_learner
from app.learning import Transition as Step
from app.learning.changes import ContextChange
from app.learning.guidance import Rule, RuleKind
from app.learning.learners import TabularLearner

from . import audit
from .context import Principal, ServiceContext, after_commit

__all__ = [
    "JOURNAL_PAGE",
    "PersonModel",
    "Replay",
    "Rules",
    "apply",
    "fresh_learner",
    "rule_of",
]

JOURNAL_PAGE = 5_000  # journal entries read at a time while a long journal is replayed

# The staff correction a "correction" or "lift" entry names (app.learning.guidance)
Rules = Callable[[journal.Correction | journal.Lift], Rule]
# Carries a learner from one mission version to another (a "mission" entry).
Mover = Callable[[TabularLearner[Any], int, int], TabularLearner[Any]]


def fresh_learner(
    algorithm: str, params: dict[str, Any] | None, mission: Mission
) -> TabularLearner[Any]:
    """A new learner, or 422 naming what is wrong with the algorithm or its parameters."""
    try:
        return make_learner(algorithm, params, mission)
    except ValueError as exc:
        raise ValidationFailed(str(exc)) from None


def rule_of(row: CorrectionRow, since: int) -> Rule:
    """The learning core's rule of a stored correction, made when the learner had seen
    ``since`` episodes."""
    return Rule(
        id=row.correction_id,
        kind=RuleKind(row.kind),
        time_slot=row.time_slot,
        situation=row.situation,
        service=row.service,
        detail=row.detail,
        since=since,
        meta={"author": row.actor_key_id, "at": _stamp(row.created_at), "note": row.note},
    )


def _stamp(at: dt.datetime) -> str:
    return at.astimezone(dt.UTC).replace(microsecond=0).isoformat()


def apply(
    learner: TabularLearner[Any],
    entries: Sequence[journal.Entry],
    *,
    layout: int,
    rules: Rules | None = None,
    move: Mover | None = None,
) -> tuple[TabularLearner[Any], int]:
    """Teach ``learner`` (laid out for mission version ``layout``) the entries of one model
    version, as they were taught when written: returns the learner (another one after a move)
    and its layout. The learner raises ``ValueError`` before changing anything if an entry
    does not fit it; a base (reset, import, fold) is never applied."""
    first = entries[0]
    if isinstance(first, journal.MissionMove):
        if move is None:
            raise ValueError(
                f"version {first.version} moves the model to mission version "
                f"{first.mission_version}, and no mover was given"
            )
        return move(learner, layout, first.mission_version), first.mission_version
    if isinstance(first, journal.Correction | journal.Lift):
        if rules is None:
            raise ValueError(
                f"version {first.version} is a staff correction, and no rules were given"
            )
        rule = rules(first)
        if isinstance(first, journal.Correction):
            learner.correct(rule)
        elif learner.guidance.get(rule.id) is not None:
            learner.lift(rule.id)
        else:  # already out of the model (an import or a reset dropped it): a version still
            learner.version += 1
    elif isinstance(first, journal.Feedback):
        learner.feedback(first.episode, first.context, first.action, first.reward)
    elif isinstance(first, journal.Transition):
        learner.update([_step(e) for e in entries])
    else:
        raise ValueError(
            f"version {first.version} is a {first.kind}: a base a rebuild starts from, "
            "not a change to replay"
        )
    return learner, layout


def _step(entry: journal.Entry) -> Step:
    if not isinstance(entry, journal.Transition):
        raise ValueError(f"version {entry.version} mixes a {entry.kind} with transitions")
    return Step(
        entry.episode,
        entry.context,
        entry.state,
        entry.action,
        entry.reward,
        entry.next_state,
        Polarity(entry.signal),
    )


def _by_version(entries: Iterable[journal.Entry]) -> Iterator[list[journal.Entry]]:
    for _, group in groupby(entries, key=lambda e: e.version):
        yield list(group)


class PersonModel:
    """One person's learner model: its head (``head``), its learner (``learner``, loaded on
    first use) and the changes made since it was opened, written by :meth:`save`.

    Open it with :meth:`open`; change it only with ``write=True``, in a transaction that holds
    the person's lock (the user row); the changes are stored by :meth:`save` in that same
    transaction, and the learner returns to the worker's cache once it commits.
    """

    __slots__ = (
        "session",
        "ctx",
        "user",
        "head",
        "write",
        "_learner",
        "_pending",
        "_snapshot",
        "_moved",
        "_replaced",
        "_keep_base",
        "_origin",
        "_rules",
        "decided",
    )

    def __init__(
        self, session: Session, ctx: ServiceContext, user: UserRow, head: ModelRow, *, write: bool
    ) -> None:
        self.session, self.ctx, self.user, self.head, self.write = session, ctx, user, head, write
        self._learner: TabularLearner[Any] | None = None
        self._pending: list[journal.Entry] = []
        self._snapshot = False  # store the learner's state with this save
        self._moved = False  # the head's mission version changed
        self._replaced = False  # started over: from itself as its base, or a fresh learner
        self._keep_base = False
        self._origin = Origin()
        self._rules: Rules | None = None
        # The contexts the latest teach decided changed (the learner's own mechanism)
        self.decided: tuple[ContextChange, ...] = ()

    # -- open and load -------------------------------------------------------------------------
    @classmethod
    def open(
        cls,
        session: Session,
        ctx: ServiceContext,
        user: UserRow,
        *,
        write: bool = False,
        head: ModelRow | None = None,
    ) -> PersonModel:
        """The person's model at its head (``head``: already read with the person's lock)."""
        if head is None:
            head = repo.head(session, user.id)
        if head is None:  # every person is created with a model; only a broken database lacks it
            raise RuntimeError(f"user {user.fleet}/{user.user_id} has no model row")
        return cls(session, ctx, user, head, write=write)

    @property
    def version(self) -> int:
        return self.head.version

    @property
    def mission_version(self) -> int:
        """The fleet's mission version the learner is laid out for."""
        return self.head.mission_version

    @property
    def mission(self) -> Mission:
        return self.ctx.missions.get(self.session, self.user.fleet, self.mission_version).mission

    @property
    def now(self) -> int:
        """The learner's episode index of the person's next episode ("if asked now"): an
        imported model may have seen more episodes than the person has, and its clock must
        never run backwards."""
        return self.user.episode_count + self.head.episode_offset + 1

    @property
    def learner(self) -> TabularLearner[Any]:
        """The learner at the head's version, laid out for the head's mission version: for a
        writer, the worker's cached one if it holds this version; for a reader, one of its own."""
        if self._learner is None:
            self._learner = self._load()
        return self._learner

    def _load(self) -> TabularLearner[Any]:
        head = self.head
        if self.write:
            cached = self.ctx.cache.take(self.user.id, head.version)
            if cached is not None:
                return cached
        learner = learner_from_state(repo.snapshot(self.session, self.user.id), self.mission)
        if head.version > head.state_version:  # a move always stores a snapshot: none here
            for group in _by_version(
                journal.entries_since(self.session, self.user.id, head.state_version)
            ):
                learner, _ = apply(learner, group, layout=head.mission_version, rules=self.rules)
        return learner

    def document(self) -> dict[str, Any]:
        """The model as the learner-state document that an import accepts (an export)."""
        if self.head.state_version == self.head.version and self._learner is None:
            return repo.snapshot(self.session, self.user.id)
        return self.learner.to_state()

    @property
    def rules(self) -> Rules:
        """The rules of the person's "correction" and "lift" entries (stored corrections, read
        once when first needed)."""
        if self._rules is None:
            loaded: dict[int, CorrectionRow] | None = None
            session, user_pk = self.session, self.user.id

            def resolve(entry: journal.Correction | journal.Lift) -> Rule:
                nonlocal loaded
                if loaded is None:
                    loaded = {
                        row.id: row
                        for row in corrections_repo.for_user(session, user_pk)
                        if row.id is not None
                    }
                row = loaded.get(entry.correction_pk)
                if row is None:
                    raise ValueError(
                        f"version {entry.version} names correction row {entry.correction_pk}, "
                        "which is not stored"
                    )
                return rule_of(row, entry.since)

            self._rules = resolve
        return self._rules

    def mover(self) -> Mover:
        """Carries a learner of this person between versions of their fleet's mission."""
        session, book, fleet = self.session, self.ctx.missions, self.user.fleet
        return lambda learner, old, new: book.carry(session, fleet, learner, old, new)

    # -- changes: each one model version ---------------------------------------------------------
    def _change(
        self,
        entries: Sequence[journal.Entry],
        *,
        rules: Rules | None = None,
        snapshot: bool = False,
    ) -> None:
        if not self.write:
            raise RuntimeError("a model opened to read cannot be changed")
        learner, layout = apply(
            self.learner, entries, layout=self.mission_version, rules=rules, move=self.mover()
        )
        self._learner = learner
        self.decided = learner.changes if isinstance(entries[0], journal.Transition) else ()
        self.head.version += 1
        if layout != self.head.mission_version:
            self.head.mission_version, self._moved = layout, True
        self._pending.extend(entries)
        self._snapshot = self._snapshot or snapshot

    def _next(self) -> int:
        return self.head.version + 1

    def teach(self, steps: Sequence[Step]) -> None:
        """An outcome's steps (one ``update``): the transitions it taught."""
        if not steps:
            return
        version, layout = self._next(), self.mission_version
        self._change(
            [
                journal.Transition(
                    version,
                    layout,
                    s.episode,
                    s.context,
                    s.state,
                    s.action,
                    float(s.reward),
                    s.next_state,
                    int(s.signal),
                )
                for s in steps
            ]
        )

    def feedback(
        self, *, episode: int, context: int, state: int, action: int, reward: float
    ) -> bool:
        """Explicit feedback on a step the model learned: whether the learner took it (it
        refuses a step it no longer holds; then nothing changes)."""
        entry = journal.Feedback(
            self._next(), self.mission_version, episode, context, state, action, float(reward)
        )
        try:
            self._change([entry])
        except ValueError:
            return False
        return True

    def correct(self, rule: Rule, correction_pk: int, *, context: int) -> None:
        """Put the stored correction ``correction_pk`` (the learning core's ``rule``) in force."""
        entry = journal.Correction(
            self._next(), self.mission_version, correction_pk, rule.since, context
        )
        self._change([entry], rules=lambda _entry: rule, snapshot=True)

    def lift(self, rule: Rule, correction_pk: int, *, context: int) -> None:
        """Lift the stored correction ``correction_pk`` (a version even if the model no longer
        holds it)."""
        entry = journal.Lift(self._next(), self.mission_version, correction_pk, rule.since, context)
        self._change([entry], rules=lambda _entry: rule, snapshot=True)

    def move(self, mission_version: int) -> None:
        """Carry the model to ``mission_version`` of its fleet's mission."""
        self._change([journal.MissionMove(self._next(), mission_version)], snapshot=True)

    def reset(
        self,
        learner: TabularLearner[Any],
        *,
        actor: Principal,
        cause: str,
        action: str,
        detail: dict[str, Any],
    ) -> int:
        """Start the model over as ``learner``, a fresh learner (``cause``: ``"reset"``, staff
        forgot what was learned; ``"learner"``, staff chose another learner), which may keep
        the staff corrections in force: then it is the base a rebuild starts from, else a
        rebuild starts from a fresh learner. See :meth:`_replace` for what is recorded;
        returns how many corrections were lifted."""
        kept = len(learner.guidance)
        entry = journal.Reset(
            self._next(),
            self.mission_version,
            actor=actor.key_id,
            algorithm=learner.algorithm,
            cause=cause,
            corrections_kept=kept,
        )
        return self._replace(
            learner, entry, actor=actor, action=action, detail=detail, keep_base=kept > 0
        )

    def import_learner(
        self,
        learner: TabularLearner[Any],
        *,
        actor: Principal,
        action: str,
        detail: dict[str, Any],
        episode_offset: int,
        version: int | None = None,
    ) -> int:
        """Replace the model by an imported ``learner`` (laid out for the model's mission
        version), the base a rebuild starts from; ``episode_offset`` moves the learner's
        episode clock. ``version``: the version the model takes, when it must go on from one a
        person's history refers to (a person imported with their history); one on otherwise.
        See :meth:`_replace`; returns how many corrections were lifted."""
        if version is not None and version <= self.head.version:
            raise ValueError(f"a model at version {self.head.version} cannot go to {version}")
        if version is not None:
            self.head.version = version - 1
        entry = journal.Import(
            self._next(),
            self.mission_version,
            actor=actor.key_id,
            algorithm=learner.algorithm,
            episodes=learner.episodes,
        )
        return self._replace(
            learner,
            entry,
            actor=actor,
            action=action,
            detail=detail,
            keep_base=True,
            episode_offset=episode_offset,
        )

    def _replace(
        self,
        learner: TabularLearner[Any],
        entry: journal.Reset | journal.Import,
        *,
        actor: Principal,
        action: str,
        detail: dict[str, Any],
        keep_base: bool,
        episode_offset: int | None = None,
    ) -> int:
        """Start the model over from ``learner``, one version on, journalled as ``entry``; the
        history stays. ``keep_base``: the learner is stored as the base a rebuild starts from
        (an import, a reset that keeps corrections); otherwise a rebuild starts fresh.

        Who did it, and when, is recorded with the change whatever the route (the API, the
        console, the command line): the person's stored corrections that the new model does
        not hold are lifted by ``actor`` now, those it holds are in force again, and the audit
        log gets ``action`` with ``detail`` and ``corrections_lifted``. Returns how many
        corrections it lifted.
        """
        if not self.write:
            raise RuntimeError("a model opened to read cannot be changed")
        if self._pending:
            raise RuntimeError("a model is replaced on its own, not after other changes")
        self.ctx.cache.drop(self.user.id)
        self._learner = learner
        self.head.version += 1
        self.head.base_version = self.head.version
        self.head.base_mission_version = self.head.mission_version
        if episode_offset is not None:
            self.head.episode_offset = episode_offset
        self._replaced = True
        self._keep_base = keep_base
        self._origin = Origin("imported") if keep_base else Origin()
        self._pending.append(entry)
        now = utcnow()
        lifted = 0
        for row in corrections_repo.for_user(self.session, self.user.id):
            held = learner.guidance.get(row.correction_id) is not None
            if row.id is None or held == (row.lifted_at is None):
                continue
            lifted += not held
            corrections_repo.lift(
                self.session, row.id, at=None if held else now, by=None if held else actor.key_id
            )
        audit.record(
            self.session,
            actor,
            action,
            target=self.user.user_id,
            fleet=self.user.fleet,
            detail={**detail, "version": self.head.version, "corrections_lifted": lifted},
        )
        return lifted

    def restore(self, learner: TabularLearner[Any]) -> None:
        """Store ``learner`` (the model rebuilt from its history) as the model, one version
        on, without a journal entry: the journal already holds what it was taught."""
        if not self.write:
            raise RuntimeError("a model opened to read cannot be changed")
        self._learner = learner
        self.head.version += 1
        self._snapshot = True

    def fold(
        self,
        *,
        base: dict[str, Any] | None,
        base_layout: int,
        upto_version: int,
        upto_seq: int,
        kept_from: dt.datetime,
        expect_base_version: int,
    ) -> bool:
        """A retention run's fold: the journal up to ``upto_version`` (and the person's
        episodes up to ``upto_seq``, received before ``kept_from``) is about to be removed, so
        the model's base moves there (``base``, the learner at ``upto_version`` laid out for
        ``base_layout``; ``None``: the base is there already) and the snapshot, if older, moves
        to the head; the journal gets a :class:`~app.db.repositories.journal.Fold` entry at
        the new base. The model itself does not change. False (and nothing done) if the base
        moved since the run planned it (``expect_base_version``: a reset or an import since)."""
        if not self.write:
            raise RuntimeError("a model opened to read cannot be changed")
        head, user_pk = self.head, self.user.id
        if head.base_version != expect_base_version:
            return False
        if base is not None:
            moved = repo.move_base(
                self.session,
                user_pk,
                expect_base_version=expect_base_version,
                base_state=base,
                base_version=upto_version,
                base_mission_version=base_layout,
            )
            if not moved:
                return False
            head.base_version, head.base_mission_version = upto_version, base_layout
        if head.state_version < upto_version:  # it must not need the entries about to go
            self.store_snapshot()
        journal.replace_fold(
            self.session,
            user_pk,
            journal.Fold(
                head.base_version,
                head.base_mission_version,
                upto_seq=upto_seq,
                kept_from=kept_from,
            ),
        )
        return True

    def holds_step(self, *, episode: int, action: int) -> bool:
        """Whether the model, since its base, was taught ``action``'s step of the learner's
        ``episode`` (not if it was reset or replaced since)."""
        return journal.has_transition(
            self.session,
            self.user.id,
            episode=episode,
            action=action,
            after_version=self.head.base_version,
        )

    # -- save -----------------------------------------------------------------------------------
    def save(self) -> None:
        """Write the changes made since the model was opened (or since the last save): the
        journal's entries and the head, the learner's state when due; the learner goes back to
        the worker's cache once the transaction commits. Nothing changed: nothing is written
        (a writer's learner still goes back to the cache)."""
        if not self.write:
            raise RuntimeError("a model opened to read is not saved")
        head, user_pk, now = self.head, self.user.id, utcnow()
        if self._replaced:
            state = self.learner.to_state()
            repo.replace(
                self.session,
                user_pk,
                version=head.version,
                state=state,
                base_state=state if self._keep_base else None,
                episode_offset=head.episode_offset,
                mission_version=head.mission_version,
                updated_at=now,
                base_origin=self._origin,
            )
            head.state_version = head.version
        elif self._pending or self._snapshot:
            due = (
                self._snapshot
                or head.version - head.state_version >= self.ctx.settings.snapshot_every
            )
            repo.advance(
                self.session,
                user_pk,
                version=head.version,
                updated_at=now,
                state=self.learner.to_state() if due else None,
                mission_version=head.mission_version if self._moved else None,
            )
            if due:
                head.state_version = head.version
        journal.append(self.session, user_pk, self._pending)
        self._pending = []
        self._snapshot = self._moved = False
        self._replaced, self._keep_base, self._origin = False, False, Origin()
        learner, version, cache = self._learner, head.version, self.ctx.cache
        if learner is not None:
            after_commit(self.session, lambda: cache.put(user_pk, version, learner))

    def store_snapshot(self) -> bool:
        """Store the learner's state as of the head's version (the model does not change):
        False when the stored one was current."""
        if self.head.state_version == self.head.version:
            return False
        repo.store_snapshot(
            self.session, self.user.id, version=self.head.version, state=self.learner.to_state()
        )
        self.head.state_version = self.head.version
        return True

    # -- the way back: the base and its journal ------------------------------------------------
    def base_learner(self) -> TabularLearner[Any]:
        """The learner a rebuild starts from, at ``head.base_version``, laid out for
        ``head.base_mission_version``: the stored base (an import, the fleet's prior, a
        retention run's fold), or a fresh learner."""
        base = self.base_document()
        mission = self.ctx.missions.get(
            self.session, self.user.fleet, self.head.base_mission_version
        ).mission
        if base:
            return learner_from_state(base, mission)
        return fresh_learner(self.user.algorithm, dict(self.user.params), mission)

    def base_document(self) -> dict[str, Any] | None:
        """The stored base's learner document (an import, the fleet's prior, a fold), or None
        when the base is a fresh learner."""
        return repo.base_state(self.session, self.user.id)

    def history(self, after: int | None = None) -> Iterator[list[journal.Entry]]:
        """The journal since the base (or since version ``after``, when later), one version's
        entries at a time, in order, without the bases themselves (what a replay teaches),
        read a page at a time."""
        lower = self.head.base_version if after is None else max(after, self.head.base_version)
        entries = journal.entries_between(
            self.session, self.user.id, lower, self.head.version, page=JOURNAL_PAGE
        )
        return (g for g in _by_version(entries) if g[0].kind not in journal.BASE_KINDS)

    def replay(self, *, upto: int | None = None) -> Replay:
        """The model's base, ready to be taught its journal up to ``upto`` (the head's version
        if not given)."""
        return Replay(self, self.head.version if upto is None else upto)


class Replay:
    """A person's model rebuilt: their base taught the journal's entries in order, as far as
    asked with :meth:`through`; ``writes`` and ``entries`` count what was taught. The journal
    is read a page at a time (``JOURNAL_PAGE``), so a long one is replayed in bounded memory.
    """

    def __init__(self, model: PersonModel, upto: int) -> None:
        head = model.head
        self.learner = model.base_learner()
        self.layout = head.base_mission_version
        self.writes = 0
        self.entries = 0
        self._rules, self._move = model.rules, model.mover()
        self._groups = _by_version(
            journal.entries_between(
                model.session, model.user.id, head.base_version, upto, page=JOURNAL_PAGE
            )
        )
        self._next: list[journal.Entry] | None = None

    def through(self, version: int) -> TabularLearner[Any]:
        """The learner taught every entry up to ``version``."""
        while True:
            if self._next is None:
                self._next = next(self._groups, None)
                if self._next is None:
                    return self.learner
            if self._next[0].version > version:
                return self.learner
            self.learner, self.layout = apply(
                self.learner, self._next, layout=self.layout, rules=self._rules, move=self._move
            )
            self.writes += 1
            self.entries += len(self._next)
            self._next = None
