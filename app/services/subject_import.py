"""A person's import: an export (``GET /v1/users/{id}/export`` of this or another deployment)
read back into a fleet, history included (docs/api.md, "A person's import").

The document is read as a stream (:mod:`ijson`): its head first (who they are, the model, the
corrections, what the import needs to put them back: ``restore``), then its episodes one at a
time, written a page at a time, so a history of any length is imported in bounded memory. All
of it is one transaction: the person appears whole, or not at all.

What comes back: the person (their id, or another one given), their learner and its model
(going on from the model version the history refers to, so that every decision keeps the
version it was drawn from), their episodes with their decisions, answers and feedback (an
episode still open in the export comes back ``interrupted``: its robot is elsewhere),
their corrections with notes, authors and times, their part in the fleet's prior, and what a
retention run had folded of their removed episodes. What stays behind: the audit entries and the
record of who looked (they are the other deployment's records, about keys that do not exist
here); the import is audited here (``user.import``). The episodes' and decisions' ids are new;
the events keep their ids, so a robot's retry of an event from before the move is refused as
already used (409).

The history's indices belong to the missions it ran under: each must be a version of the
importing fleet's mission (the same fingerprint), or the import is refused (422) naming it.
"""

from __future__ import annotations

import datetime as dt
import re
import secrets
from collections.abc import Iterator
from dataclasses import dataclass
from typing import IO, Any

import ijson
from pydantic import ValidationError
from sqlalchemy.orm import Session

from app.db.repositories import changes as changes_repo
from app.db.repositories import corrections as corrections_repo
from app.db.repositories import episodes as episodes_repo
from app.db.repositories import missions as missions_repo
from app.db.repositories import retention as folds_repo
from app.db.repositories import users as users_repo
from app.db.repositories.changes import ChangeRow
from app.db.repositories.corrections import CorrectionRow
from app.db.repositories.episodes import DecisionRow, EpisodeRow, FeedbackRow
from app.db.types import utcnow
from app.errors import Conflict, Forbidden, ValidationFailed
from app.schemas.common import CLIENT_ID_PATTERN
from app.schemas.episodes import FeedbackIn
from app.schemas.profile import CorrectionIn
from app.schemas.users import LearnerSpec

from . import audit
from .auth import require_manager
from .context import Principal, ServiceContext, body_hash
from .episodes.render import brief
from .models import imported_learner
from .person_model import PersonModel
from .subject import FORMAT, FORMAT_VERSION
from .users import create_user

__all__ = ["Imported", "import_subject"]

_CLIENT_ID = re.compile(CLIENT_ID_PATTERN)
PAGE = 500  # episodes written at a time
STATUSES = frozenset({"open", "closed", "interrupted"})


@dataclass(frozen=True, slots=True)
class Imported:
    """What an import made: the person, and how much of their history came with them."""

    user_id: str
    fleet: str
    episodes: int
    decisions: int
    feedback: int
    corrections: int
    model_version: int

    def to_json(self) -> dict[str, Any]:
        return {
            "user_id": self.user_id,
            "fleet": self.fleet,
            "episodes": self.episodes,
            "decisions": self.decisions,
            "feedback": self.feedback,
            "corrections": self.corrections,
            "model_version": self.model_version,
        }


class _Refused(ValidationFailed):
    """The document is not an export this deployment can import (422)."""


def _events(source: IO[bytes]) -> Iterator[tuple[str, str, Any]]:
    """The document's parse events; 422 for what is not JSON, or holds the NUL character
    (which no text of the service may hold: PostgreSQL cannot store it)."""
    try:
        for prefix, kind, value in ijson.parse(source, use_float=True):
            if kind in ("string", "map_key") and "\x00" in value:
                raise _Refused(f"{prefix or 'The document'}: text must not contain NUL (U+0000).")
            yield prefix, kind, value
    except ijson.JSONError as exc:
        raise _Refused(f"Not a JSON document: {exc}") from None


def _value(first: tuple[str, str, Any], events: Iterator[tuple[str, str, Any]]) -> Any:
    """The JSON value that starts with ``first`` (its remaining events taken from ``events``)."""
    builder = ijson.ObjectBuilder()
    depth = 0
    event: tuple[str, str, Any] | None = first
    while event is not None:
        _, kind, value = event
        builder.event(kind, value)
        if kind in ("start_map", "start_array"):
            depth += 1
        elif kind in ("end_map", "end_array"):
            depth -= 1
        if depth == 0:
            return builder.value
        event = next(events, None)
    raise _Refused("The document ends in the middle of a value.")


def _head(events: Iterator[tuple[str, str, Any]]) -> dict[str, Any]:
    """The document's fields before ``episodes`` (an export writes them last)."""
    first = next(events, None)
    if first is None or first[1] != "start_map":
        raise _Refused("An export is a JSON object.")
    head: dict[str, Any] = {}
    for prefix, kind, value in events:
        if prefix == "" and kind == "map_key":
            if value == "episodes":
                start = next(events, None)
                if start is None or start[1] != "start_array":
                    raise _Refused("episodes must be a list.")
                return head
            first_event = next(events, None)
            if first_event is None:
                break
            head[value] = _value(first_event, events)
        elif prefix == "" and kind == "end_map":
            return head
    raise _Refused("The document ends before its episodes.")


def _episodes(events: Iterator[tuple[str, str, Any]]) -> Iterator[dict[str, Any]]:
    for event in events:
        if event[1] == "end_array" and event[0] == "episodes":
            return
        item = _value(event, events)
        if not isinstance(item, dict):
            raise _Refused("Each of episodes must be an object.")
        yield item


def _get(doc: Any, *path: str) -> Any:
    for name in path:
        if not isinstance(doc, dict) or name not in doc:
            raise _Refused(f"The export has no {'.'.join(path)}.")
        doc = doc[name]
    return doc


def _time(text: Any, what: str) -> dt.datetime:
    try:
        at = dt.datetime.fromisoformat(str(text))
    except ValueError:
        raise _Refused(f"{what} is not a time: {text!r}.") from None
    return at if at.tzinfo is not None else at.replace(tzinfo=dt.UTC)


def _maybe_time(text: Any, what: str) -> dt.datetime | None:
    return None if text is None else _time(text, what)


def _new_id(prefix: str) -> str:
    return prefix + secrets.token_hex(16)


def import_subject(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    source: IO[bytes],
    *,
    fleet: str | None = None,
    user_id: str | None = None,
) -> Imported:
    """Read a person's export from ``source`` into the caller's fleet (an admin's: ``fleet``),
    as ``user_id`` or the id they had (staff of the fleet, admins). 409 if the fleet has that
    id; 422 if the document is not an export this deployment can put back."""
    require_manager(principal)
    if fleet is not None and fleet != principal.fleet and not principal.is_admin:
        raise Forbidden("Only admin keys may name a fleet.")
    into = fleet or principal.fleet
    events = _events(source)
    head = _head(events)
    if head.get("format") != FORMAT:
        raise _Refused(f"Not a person's export (format {head.get('format')!r}, not {FORMAT!r}).")
    if head.get("format_version") != FORMAT_VERSION:
        raise _Refused(
            f"An export of format version {head.get('format_version')!r}; this deployment "
            f"reads version {FORMAT_VERSION}."
        )
    restore = head.get("restore")
    if not isinstance(restore, dict):
        raise _Refused(
            "The export has no restore part (it was made before imports were offered): "
            "export the person again."
        )
    person = _get(head, "person")
    uid = user_id or _get(person, "user_id")
    if not isinstance(uid, str) or not _CLIENT_ID.fullmatch(uid):
        raise _Refused(f"user_id must match {CLIENT_ID_PATTERN}.")
    if users_repo.get(session, into, uid) is not None:
        raise Conflict(f"User {uid!r} exists in fleet {into!r}; import under another user_id.")
    versions = _mission_versions(session, ctx, into, restore)
    try:
        spec = LearnerSpec.model_validate(_get(person, "learner"))
    except ValidationError as exc:
        raise _Refused(f"person.learner: {exc.errors()[0]['msg']}") from None

    # made fresh (no prior: the imported model replaces it), then as it was
    create_user(
        session,
        ctx,
        into,
        uid,
        spec=spec,
        display_name=person.get("display_name"),
        fleet_prior=False,
    )
    user = users_repo.lock(session, into, uid)
    assert user is not None  # just made, in this transaction
    user.fleet_prior = bool(_get(head, "fleet_prior", "takes_part"))
    user.episode_count = int(_get(head, "episode_count"))
    user.draws = int(_get(restore, "decisions_drawn"))
    users_repo.save_profile(session, user)
    users_repo.save_counters(session, user)

    corrections = 0
    for item in _get(head, "corrections"):
        _add_correction(session, user.id, item)
        corrections += 1

    model = PersonModel.open(session, ctx, user, write=True)
    learner = imported_learner(session, ctx, into, model.mission_version, _get(head, "model"))
    model_version = int(_get(restore, "model_version")) + 1
    model.import_learner(
        learner,
        actor=principal,
        action="model.import",
        detail={"algorithm": learner.algorithm, "with_history": True},
        episode_offset=int(_get(restore, "episode_offset")),
        version=max(model_version, model.version + 1),
    )
    model.save()

    fold = restore.get("history_fold")
    if fold is not None:
        folds_repo.put_fold(
            session,
            user.id,
            upto_seq=int(_get(fold, "upto_seq")),
            upto_version=0,  # the imported model is its own base: no journal to remove
            kept_from=_time(_get(fold, "kept_from"), "history_fold.kept_from"),
            now=utcnow(),
            doc=_get(fold, "doc"),
        )

    for item in restore.get("context_beliefs") or []:
        changes_repo.put_belief(
            session,
            user.id,
            str(_get(item, "time_slot")),
            str(_get(item, "situation")),
            upto_seq=int(_get(item, "upto_seq")),
            doc=_get(item, "doc"),
        )
    for item in head.get("changes") or []:
        changes_repo.add(session, _change(user.id, into, item))

    counts = {"episodes": 0, "decisions": 0, "feedback": 0}
    page: list[dict[str, Any]] = []
    for item in _episodes(events):
        page.append(item)
        if len(page) >= PAGE:
            _write(session, ctx, into, user.id, page, versions, counts)
            page = []
    _write(session, ctx, into, user.id, page, versions, counts)

    audit.record(
        session,
        principal,
        "user.import",
        target=uid,
        fleet=into,
        detail={
            "episodes": counts["episodes"],
            "corrections": corrections,
            "exported_at": head.get("exported_at"),
            "version": model.version,
        },
    )
    return Imported(
        uid,
        into,
        counts["episodes"],
        counts["decisions"],
        counts["feedback"],
        corrections,
        model.version,
    )


def _change(user_pk: int, fleet: str, item: Any) -> ChangeRow:
    """A change of the export, as stored (``since.at`` keeps its local offset)."""
    since = _time(_get(item, "since", "at"), "a change's since.at")
    offset = since.utcoffset()
    before, now = item.get("before") or {}, item.get("now") or {}
    return ChangeRow(
        id=None,
        user_pk=user_pk,
        fleet=fleet,
        source=str(_get(item, "source")),
        time_slot=str(_get(item, "time_slot")),
        situation=str(_get(item, "situation")),
        seq=int(_get(item, "since", "episode")),
        at=since,
        utc_offset=None if offset is None else int(offset.total_seconds() // 60),
        detected_seq=int(_get(item, "decided", "episode")),
        detected_at=_time(_get(item, "decided", "at"), "a change's decided.at"),
        before_service=before.get("service"),
        before_detail=before.get("detail"),
        now_service=now.get("service"),
        now_detail=now.get("detail"),
        evidence=list(_get(item, "evidence")),
    )


def _mission_versions(
    session: Session, ctx: ServiceContext, fleet: str, restore: dict[str, Any]
) -> dict[int, int]:
    """The exporting fleet's mission versions the person's history names, each mapped to the
    importing fleet's version with the same mission (by fingerprint); 422 naming one that the
    fleet does not have."""
    latest = missions_repo.latest_version(session, fleet) or 1
    here = {
        ctx.missions.get(session, fleet, v).mission.fingerprint: v for v in range(1, latest + 1)
    }
    out: dict[int, int] = {}
    for item in _get(restore, "missions"):
        version, fingerprint = int(_get(item, "version")), _get(item, "fingerprint")
        if fingerprint not in here:
            raise _Refused(
                f"The person's history ran under a mission (version {version} of their "
                f"fleet, fingerprint {fingerprint}) that fleet {fleet!r} does not have: set "
                "that mission for the fleet first, or import into a fleet that has it."
            )
        out[version] = here[fingerprint]
    return out


def _add_correction(session: Session, user_pk: int, item: Any) -> None:
    try:
        body = CorrectionIn.model_validate(
            {
                k: item.get(k)
                for k in ("correction_id", "kind", "time_slot", "situation", "service", "detail")
            }
            | ({"note": item["note"]} if item.get("note") is not None else {})
        )
    except (ValidationError, AttributeError) as exc:
        raise _Refused(f"A correction of the export does not read: {exc}") from None
    if item.get("model_version", 0) == 0:  # a rule imported earlier, without a row of its own
        return
    corrections_repo.add(
        session,
        CorrectionRow(
            id=None,
            user_pk=user_pk,
            correction_id=body.correction_id,
            kind=body.kind,
            time_slot=body.time_slot,
            situation=body.situation,
            service=body.service,
            detail=body.detail,
            note=body.note,
            actor_key_id=str(_get(item, "author")),
            created_at=_time(_get(item, "created_at"), "a correction's created_at"),
            model_version=int(_get(item, "model_version")),
            lifted_at=_maybe_time(item.get("lifted_at"), "a correction's lifted_at"),
            lifted_by=item.get("lifted_by"),
            request_hash=body_hash(body),
            response={**item, "status": "in_force", "overridden_at": None},
        ),
    )


def _write(
    session: Session,
    ctx: ServiceContext,
    fleet: str,
    user_pk: int,
    page: list[dict[str, Any]],
    versions: dict[int, int],
    counts: dict[str, int],
) -> None:
    """One page of exported episodes, as stored rows."""
    episodes: list[EpisodeRow] = []
    decisions: list[DecisionRow] = []
    feedback: list[FeedbackRow] = []
    now = utcnow()
    for item in page:
        stored = _get(item, "stored")
        source_version = int(_get(item, "mission_version"))
        if source_version not in versions:
            raise _Refused(f"An episode names mission version {source_version}, not listed.")
        status = _get(item, "status")
        if status not in STATUSES:
            raise _Refused(f"An episode's status {status!r} is not one of {sorted(STATUSES)}.")
        request = stored.get("request")
        episode = EpisodeRow(
            id=_new_id("ep_"),
            user_pk=user_pk,
            seq=int(_get(stored, "seq")),
            learner_episode=int(_get(stored, "learner_episode")),
            event_id=str(_get(item, "event_id")),
            robot_id=item.get("robot_id"),
            occurred_at=_time(_get(item, "occurred_at"), "an episode's occurred_at"),
            time_slot=str(_get(item, "context", "time_slot")),
            situation=str(_get(item, "context", "situation")),
            context=int(_get(stored, "context")),
            initiator=str(_get(item, "initiator")),
            request_service=None if request is None else request.get("service"),
            request_detail=None if request is None else request.get("detail"),
            status="interrupted" if status == "open" else status,
            state=int(_get(stored, "state")),
            total_reward=float(_get(item, "total_reward")),
            interaction_class=str(_get(item, "interaction_class")),
            initiated=bool(_get(stored, "initiated")),
            success=bool(_get(stored, "success")),
            queries=int(_get(stored, "queries")),
            request_hash="",  # a retry of the event before the move is refused: 409
            response={},
            created_at=_time(_get(stored, "received_at"), "an episode's received_at"),
            closed_at=now
            if status == "open"
            else _maybe_time(stored.get("closed_at"), "an episode's closed_at"),
            mission_version=versions[source_version],
            utc_offset=stored.get("utc_offset"),
        )
        episodes.append(episode)
        for d in _get(stored, "decisions"):
            decisions.append(
                DecisionRow(
                    id=_new_id("dec_"),
                    episode_id=episode.id,
                    position=int(_get(d, "position")),
                    state=int(_get(d, "state")),
                    action=int(_get(d, "action")),
                    probabilities=[float(p) for p in _get(d, "probabilities")],
                    chain=list(_get(d, "chain")),
                    draw=d.get("draw"),
                    forced=bool(d.get("forced")),
                    model_version=int(_get(d, "model_version")),
                    decided_at=_time(_get(d, "decided_at"), "a decision's decided_at"),
                    response=d.get("response"),
                    service=d.get("service"),
                    detail=d.get("detail"),
                    feedback=d.get("feedback"),
                    reward=d.get("reward"),
                    next_state=d.get("next_state"),
                    answered_at=_maybe_time(d.get("answered_at"), "a decision's answered_at"),
                )
            )
        space = ctx.missions.get(session, fleet, episode.mission_version).space
        for f in _get(item, "feedback"):
            given = FeedbackIn(feedback_id=_get(f, "feedback_id"), feedback=_get(f, "feedback"))
            reward = float(_get(f, "reward"))
            feedback.append(
                FeedbackRow(
                    episode_id=episode.id,
                    feedback_id=given.feedback_id,
                    feedback=given.feedback,
                    reward=reward,
                    received_at=_time(_get(f, "received_at"), "a feedback's received_at"),
                    request_hash=body_hash(given),
                    response={"reward": reward, "episode": brief(space, episode)},
                )
            )
    for episode in episodes:
        episodes_repo.insert_episode(session, episode)
    if decisions:
        episodes_repo.insert_decisions(session, decisions)
    for row in feedback:
        episodes_repo.add_feedback(session, row)
    counts["episodes"] += len(episodes)
    counts["decisions"] += len(decisions)
    counts["feedback"] += len(feedback)
