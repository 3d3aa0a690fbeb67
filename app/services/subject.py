"""A person's export (docs/api.md, "A person's export"): everything stored about them in one
JSON document, for the person (a subject's access request) or for another deployment.

The document's head (who they are, their part in the fleet's prior, the model and what it says
in plain words, the corrections, the audit entries about them, who looked at them) is read in
the request's transaction, which also records the export (audit ``user.export``, and a read
``subject``). Their episodes follow, newest first, each with its decisions, answers and
feedback: read a page at a time in transactions of their own while the answer is sent, so
that a person with any number of episodes is exported in bounded memory. The episodes are
those the person had when the head was read.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import orjson
from pydantic_core import to_jsonable_python
from sqlalchemy.orm import Session

from app.db.repositories import audit as audit_repo
from app.db.repositories import changes as changes_repo
from app.db.repositories import episodes as episodes_repo
from app.db.repositories import retention as folds_repo
from app.db.repositories import shadows as shadows_repo
from app.db.repositories import views as views_repo
from app.db.repositories.episodes import EpisodeRow
from app.db.session import Database
from app.db.types import utcnow

from . import audit, rollouts, views
from .auth import require_manager
from .changes import person_changes
from .context import Principal, ServiceContext
from .corrections import list_corrections
from .episodes import get_trace
from .person_model import PersonModel
from .profile import profile_view
from .users import user_out, visible_user

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "PAGE",
    "Export",
    "begin_export",
    "restore_part",
    "stored_episode",
]

FORMAT = "attune.subject"
FORMAT_VERSION = 1
PAGE = 200  # episodes read per transaction while the document streams


@dataclass(frozen=True, slots=True)
class Export:
    """An export under way: its head (every part but the episodes) and where the episodes
    are."""

    head: dict[str, Any]
    user_pk: int
    user_id: str
    fleet: str
    episodes: int  # the person's episode count when the head was read
    principal: Principal

    @property
    def filename(self) -> str:
        return f"attune-person-{self.fleet}-{self.user_id}.json".replace(":", "_")

    def stream(self, db: Database, ctx: ServiceContext) -> Iterator[bytes]:
        """The document, in pieces: the head's fields, then ``"episodes": [...]``."""
        head = orjson.dumps(to_jsonable_python(self.head))
        yield head[:-1] + b',"episodes":['
        before = self.episodes + 1
        first = True
        while True:
            with db.transaction(write=False) as session:
                rows = episodes_repo.list_page(session, self.user_pk, before_seq=before, limit=PAGE)
                shadowed = shadows_repo.for_episodes(session, [row.id for row in rows])
                traces = [
                    {
                        **get_trace(session, ctx, self.principal, row.id).model_dump(mode="json"),
                        "stored": stored_episode(session, row),
                        "shadow_decisions": shadowed.get(row.id, []),
                    }
                    for row in rows
                ]
            for trace in traces:
                yield (b"" if first else b",") + orjson.dumps(trace)
                first = False
            if len(rows) < PAGE:
                break
            before = rows[-1].seq
        yield b"]}"


def begin_export(
    session: Session,
    ctx: ServiceContext,
    principal: Principal,
    user_id: str,
    *,
    fleet: str | None = None,
) -> Export:
    """Check the caller (staff of the fleet, admin), record the export, and read the head."""
    require_manager(principal)
    user = visible_user(session, principal, user_id, fleet=fleet)
    profile = profile_view(session, ctx, principal, user_id, fleet=user.fleet)
    model = PersonModel.open(session, ctx, user)
    head: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "exported_at": utcnow(),
        "exported_by": {
            "key_id": principal.key_id,
            "role": principal.role,
            "fleet": principal.fleet,
        },
        "person": user_out(user),
        "fleet_prior": {
            "takes_part": user.fleet_prior,
            "model_started_from": profile.started_from,
        },
        "profile": profile,
        "model": model.document(),
        "corrections": list_corrections(session, ctx, principal, user_id, fleet=user.fleet).items,
        "audit": [
            audit.entry_out(e)
            for e in audit_repo.about(
                session, fleet=user.fleet, user_id=user_id, prefixes=audit.ABOUT_A_USER
            )
        ],
        "views": [
            views.view_out(v)
            for v in views_repo.list_page(
                session, fleet=user.fleet, user_id=user_id, before_id=None, limit=1_000_000
            )
        ],
        "changes": person_changes(
            session, ctx, principal, user_id, limit=1_000_000, cursor=None, fleet=user.fleet
        ).items,
        "rollout_arms": rollouts.person_arms(session, user.id),
        "episode_count": user.episode_count,
        "restore": restore_part(session, ctx, user.fleet, user.id, model, user.draws),
    }
    audit.record(
        session,
        principal,
        "user.export",
        target=user_id,
        fleet=user.fleet,
        detail={"episodes": user.episode_count},
    )
    views.add(session, ctx.settings, principal, fleet=user.fleet, user_id=user_id, what="subject")
    return Export(head, user.id, user_id, user.fleet, user.episode_count, principal)


def restore_part(
    session: Session,
    ctx: ServiceContext,
    fleet: str,
    user_pk: int,
    model: PersonModel,
    draws: int,
) -> dict[str, Any]:
    """What another deployment needs besides the rest to put the person back as stored
    (``POST /v1/users/import``): the model's version and episode clock, the decisions drawn,
    the fleet's mission versions the episodes and the model ran under (by fingerprint: the
    importing fleet must have the same missions), and a retention run's fold of the removed
    episodes (what the profile goes on from)."""
    versions = {model.mission_version, *episodes_repo.mission_versions(session, user_pk)}
    fold = folds_repo.fold(session, user_pk)
    return {
        "model_version": model.version,
        "episode_offset": model.head.episode_offset,
        "mission_version": model.mission_version,
        "decisions_drawn": draws,
        "missions": [
            {"version": v, "fingerprint": ctx.missions.get(session, fleet, v).mission.fingerprint}
            for v in sorted(versions)
        ],
        "history_fold": None
        if fold is None
        else {"upto_seq": fold.upto_seq, "kept_from": fold.kept_from, "doc": fold.doc},
        "context_beliefs": [
            {"time_slot": slot, "situation": situation, "upto_seq": upto, "doc": doc}
            for slot, situation, upto, doc in changes_repo.beliefs(session, user_pk)
        ],
    }


def stored_episode(session: Session, row: EpisodeRow) -> dict[str, Any]:
    """An episode as stored (indices into its mission version's layout), with its decisions
    and feedback: what an import writes back."""
    return {
        "seq": row.seq,
        "learner_episode": row.learner_episode,
        "context": row.context,
        "state": row.state,
        "request": None
        if row.request_service is None
        else {"service": row.request_service, "detail": row.request_detail},
        "initiated": row.initiated,
        "success": row.success,
        "queries": row.queries,
        "utc_offset": row.utc_offset,
        "received_at": row.created_at,
        "closed_at": row.closed_at,
        "decisions": [
            {
                "position": d.position,
                "state": d.state,
                "action": d.action,
                "probabilities": d.probabilities,
                "chain": d.chain,
                "draw": d.draw,
                "forced": d.forced,
                "model_version": d.model_version,
                "decided_at": d.decided_at,
                "response": d.response,
                "service": d.service,
                "detail": d.detail,
                "feedback": d.feedback,
                "reward": d.reward,
                "next_state": d.next_state,
                "answered_at": d.answered_at,
            }
            for d in episodes_repo.decisions(session, row.id)
        ],
    }
