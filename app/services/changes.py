"""Changes in what a person wants, told to the people who care for them.

A change is news for staff (a resident who stops wanting tea in the afternoon may be unwell).
A learner with a change mechanism of its own (``decides_changes``: ``dts-routine``'s routine per
context, DTS's change test) decides at each update which contexts changed
(:mod:`app.learning.changes`); the write that taught it records what it decided (``source``
``routine`` or ``change_test``). For every other learner, each episode that ends is weighed
against what came before in its context as the profile weighs it
(:class:`app.learning.beliefs.BeliefFold`: the last choice the later episodes keep supporting,
replaced after :data:`~app.learning.beliefs.CHANGE_RUN` episodes in a row that contradict it),
from the context's walk so far (``context_beliefs``); a replacement is recorded with ``source``
``profile``. Either way the record (``change_events``) says when the change began, which
context, what the person wanted before and what now, and on what evidence.

The profile's walk weighs episodes in the order they end (a context rarely has two open at
once). What is recorded stays: a rebuild, a mission change (contexts are kept by name) and a
retention run do not touch it; an erasure removes it with the person.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import changes as repo
from app.db.repositories import episodes as episodes_repo
from app.db.repositories.changes import ChangeRow
from app.db.repositories.episodes import DecisionRow, EpisodeRow
from app.db.repositories.users import UserRow
from app.db.types import utcnow
from app.errors import Forbidden, ValidationFailed
from app.learning import Mission, NegotiationSpace
from app.learning.beliefs import Answer, BeliefFold, EpisodeEvidence, Item, episode_evidence
from app.learning.changes import ContextChange
from app.schemas.changes import ChangeEventOut, ChangeList, EvidenceItem, Moment
from app.schemas.profile import Wanted

from . import views
from .auth import require_manager
from .context import Principal, ServiceContext
from .missions import current_version
from .person_model import PersonModel
from .profile import thing, when_where
from .users import visible_user

__all__ = ["Noticed", "change_out", "fleet_changes", "notice", "person_changes", "summary"]


@dataclass(slots=True)
class Noticed:
    """What a write noticed: the changes to record and, for a person whose learner has no
    change mechanism of its own, the context's walk to store. Computed before the write's batch
    of statements (it may read), stored in it."""

    changes: list[ChangeRow]
    belief: tuple[int, str, str, int, dict[str, Any]] | None = None  # user, slot, sit., upto, doc

    def store(self, session: Session) -> None:
        if self.belief is not None:
            user_pk, slot, situation, upto, doc = self.belief
            repo.put_belief(session, user_pk, slot, situation, upto_seq=upto, doc=doc)
        for change in self.changes:
            repo.add(session, change)


def notice(
    session: Session,
    user: UserRow,
    model: PersonModel,
    space: NegotiationSpace,
    *,
    ended: tuple[EpisodeRow, Sequence[DecisionRow]] | None,
) -> Noticed | None:
    """What a write that taught the model noticed. A learner with a change mechanism of its
    own (``decides_changes``: ``dts-routine``'s routines, DTS's change test) says which contexts
    the update decided changed; for every other learner, an episode that ended (``ended``: it,
    and all of its decisions with this write's answers) is weighed against its context's walk
    of the profile's belief."""
    learner = model.learner
    if learner.decides_changes:
        rows = [_decided(session, user, model, space, c) for c in model.decided]
        return Noticed(rows) if rows else None
    if ended is None:
        return None
    return _weigh_ended(session, user, *ended, space)


def _decided(
    session: Session, user: UserRow, model: PersonModel, space: NegotiationSpace, c: ContextChange
) -> ChangeRow:
    """A change the learner decided, as recorded: its evidence (the person's answers) read as
    the profile reads an episode's, per episode."""
    offset = model.head.episode_offset
    names = {space.action_name(a): a for a in range(space.n_actions)}
    by_episode: dict[int, list[Answer]] = {}
    for step in c.evidence:
        if step.action in names:
            by_episode.setdefault(step.episode, []).append(
                Answer(names[step.action], step.response, step.service, step.detail)
            )
    shown = [
        episode_evidence(space, episode - offset, answers)
        for episode, answers in sorted(by_episode.items())
    ]
    since = shown[0].seq if shown else c.episode - offset
    began = episodes_repo.by_seq(session, user.id, since)
    at, utc_offset = began if began is not None else (utcnow(), None)
    return ChangeRow(
        id=None,
        user_pk=user.id,
        fleet=user.fleet,
        source=c.source,
        time_slot=c.time_slot,
        situation=c.situation,
        seq=since,
        at=at,
        utc_offset=utc_offset,
        detected_seq=c.episode - offset,
        detected_at=utcnow(),
        before_service=None if c.before is None else c.before.service,
        before_detail=None if c.before is None else c.before.detail,
        now_service=None if c.now is None else c.now.service,
        now_detail=None if c.now is None else c.now.detail,
        evidence=[_evidence_doc(e) for e in shown],
    )


def _weigh_ended(
    session: Session,
    user: UserRow,
    episode: EpisodeRow,
    decisions: Sequence[DecisionRow],
    space: NegotiationSpace,
) -> Noticed:
    """Weigh an episode that just ended (``decisions``: all of its decisions, with this
    write's answers) against its context's walk."""
    stored = repo.belief(session, user.id, episode.time_slot, episode.situation)
    fold = BeliefFold() if stored is None else BeliefFold.from_doc(stored[1])
    answers = [
        Answer(d.action, d.response, d.service, d.detail)
        for d in sorted(decisions, key=lambda d: d.position)
        if d.response is not None and not d.forced
    ]
    request = (
        Item(episode.request_service, episode.request_detail) if episode.request_service else None
    )
    before = fold.change
    fold.add(episode_evidence(space, episode.seq, answers, request=request))
    found = fold.change
    changes = []
    if found is not None and found != before:
        at, offset = episode.occurred_at, episode.utc_offset
        if found.seq != episode.seq:
            began = episodes_repo.by_seq(session, user.id, found.seq)
            if began is not None:
                at, offset = began
        shown = [e for _, e in fold.tail if e.seq >= found.seq]
        changes.append(
            ChangeRow(
                id=None,
                user_pk=user.id,
                fleet=user.fleet,
                source="profile",
                time_slot=episode.time_slot,
                situation=episode.situation,
                seq=found.seq,
                at=at,
                utc_offset=offset,
                detected_seq=episode.seq,
                detected_at=utcnow(),
                before_service=found.before.service,
                before_detail=found.before.detail,
                now_service=None if found.now is None else found.now.service,
                now_detail=None if found.now is None else found.now.detail,
                evidence=[_evidence_doc(e) for e in shown],
            )
        )
    upto = max(episode.seq, 0 if stored is None else stored[0])
    return Noticed(changes, (user.id, episode.time_slot, episode.situation, upto, fold.to_doc()))


def _evidence_doc(ev: EpisodeEvidence) -> dict[str, Any]:
    def item(i: Item | None) -> dict[str, str | None] | None:
        return None if i is None else {"service": i.service, "detail": i.detail}

    return {
        "episode": ev.seq,
        "chose": item(ev.chose),
        "turned_down": [item(r) for r in ev.refused],
        "turned_down_offer": ev.refused_offer,
    }


def _wanted(service: str | None, detail: str | None) -> Wanted | None:
    return None if service is None else Wanted(service=service, detail=detail)


def _local(at: dt.datetime, offset: int | None) -> dt.datetime:
    if offset is None:
        return at
    return at.astimezone(dt.timezone(dt.timedelta(minutes=offset)))


def summary(mission: Mission, name: str | None, row: ChangeRow) -> str:
    """The change in words, for staff: "Since 3 December, Mrs. Lin no longer wants tea in the
    afternoon, while stretching", "... wants coffee instead of tea ..."."""
    who = name or "this person"
    day = _local(row.at, row.utc_offset)
    since = f"Since {day.day} {day:%B}"
    where = when_where(mission, row.time_slot, row.situation)
    if row.before_service is None:
        if row.now_service is None:
            return f"{since}, {who} turns down what the robot offers {where}."
        return (
            f"{since}, {who} wants {thing(mission, Item(row.now_service, row.now_detail))} {where}."
        )
    before = thing(mission, Item(row.before_service, row.before_detail))
    if row.now_service is None or (
        row.now_detail is None and row.now_service == row.before_service
    ):  # turned it down, and chose nothing else yet (or only "another drink")
        return f"{since}, {who} no longer wants {before} {where}."
    now = thing(mission, Item(row.now_service, row.now_detail))
    return f"{since}, {who} wants {now} instead of {before} {where}."


def change_out(row: ChangeRow, user_id: str, mission: Mission, name: str | None) -> ChangeEventOut:
    return ChangeEventOut(
        change_id=str(row.id),
        user_id=user_id,
        fleet=row.fleet,
        source=row.source,  # type: ignore[arg-type]
        time_slot=row.time_slot,
        situation=row.situation,
        since=Moment(episode=row.seq, at=_local(row.at, row.utc_offset)),
        decided=Moment(episode=row.detected_seq, at=row.detected_at),
        before=_wanted(row.before_service, row.before_detail),
        now=_wanted(row.now_service, row.now_detail),
        evidence=[EvidenceItem.model_validate(e) for e in row.evidence],
        summary=summary(mission, name, row),
    )


def _position(cursor: str | None) -> int | None:
    if cursor is None:
        return None
    if not cursor.isdigit():
        raise ValidationFailed("cursor is not one this API returned.")
    return int(cursor)


def person_changes(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    limit: int,
    cursor: str | None,
    fleet: str | None = None,
) -> ChangeList:
    """``GET /v1/users/{user_id}/changes``: the person's changes, newest first (staff of the
    fleet, admins)."""
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet)
    rows = repo.for_user(session, user.id, before_id=_position(cursor), limit=limit + 1)
    mission = ctx.missions.display(session, user.fleet, current_version(session, ctx, user.fleet))
    return _page(rows, limit, mission, {user.id: user.display_name})


def fleet_changes(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    fleet: str,
    *,
    since: dt.datetime | None,
    limit: int,
    cursor: str | None,
    via: str = "api",
) -> ChangeList:
    """``GET /v1/admin/fleets/{fleet}/changes``: the fleet's changes decided since ``since``,
    newest first (the fleet's staff, admins). Each person it names is recorded as looked at
    (``changes``), in ``session``'s write transaction."""
    require_manager(principal)
    if not principal.sees(fleet):
        raise Forbidden("Staff keys read their own fleet's changes only.")
    if since is not None and since.tzinfo is None:
        raise ValidationFailed("since must carry an offset (RFC 3339).")
    rows = repo.for_fleet(session, fleet, since=since, before_id=_position(cursor), limit=limit + 1)
    mission = ctx.missions.display(session, fleet, current_version(session, ctx, fleet))
    names = repo.display_names(session, {r.user_pk for r, _ in rows})
    for user_id in sorted({uid for _, uid in rows[:limit]}):
        views.add(
            session, ctx.settings, principal, fleet=fleet, user_id=user_id, what="changes", via=via
        )
    return _page(rows, limit, mission, names)


def _page(
    rows: list[tuple[ChangeRow, str]],
    limit: int,
    mission: Mission,
    names: dict[int, str | None],
) -> ChangeList:
    """A page of changes in words; their contexts are named as the fleet's mission in force
    names them (a context a later mission dropped keeps its own names)."""
    more = len(rows) > limit
    items = [change_out(r, uid, mission, names.get(r.user_pk)) for r, uid in rows[:limit]]
    return ChangeList(items=items, next_cursor=str(rows[limit - 1][0].id) if more else None)
