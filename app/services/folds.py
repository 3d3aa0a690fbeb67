"""What a person's profile reads of their history, as a walk that can stop and go on.

The profile (:mod:`app.services.profile`) walks the person's episodes in order, context by
context. :class:`History` is that walk: a retention run (:mod:`app.services.retention`) walks
the episodes it is about to remove, stores the walk as a small document (``history_folds``),
and the profile goes on from it over the episodes that are kept, so it says exactly what it
said before the run. The document holds counts, the latest few relevant episodes of each
context (what the belief can still look at, :class:`~app.learning.beliefs.BeliefFold`) and
the times the profile shows; nothing else of the removed episodes.
"""

from __future__ import annotations

import datetime as dt
from collections import defaultdict
from collections.abc import Callable, Container, Iterable
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy.orm import Session

from app.db.repositories import episodes as episodes_repo
from app.db.repositories.episodes import HistoryAnswer, HistoryEpisode, local_time
from app.learning import NegotiationSpace
from app.learning.beliefs import Answer, BeliefFold, EpisodeEvidence, Item, episode_evidence

__all__ = ["ContextHistory", "History", "Moment"]

FOLD_VERSION = 1
PAGE = 2_000  # episodes read at a time while a long history is walked
# A context's walk keeps the local times of its latest episodes only (those its belief can
# still look at); it sheds the others once it holds this many.
_TIMES_KEPT = 256


@dataclass(slots=True)
class ContextHistory:
    """One context's part of the walk."""

    fold: BeliefFold = field(default_factory=BeliefFold)
    episodes: int = 0
    open: int = 0
    accepted: int = 0
    refused: int = 0
    asked_for: int = 0
    answered: int = 0
    last_seen: dt.datetime | None = None
    times: dict[int, dt.datetime] = field(default_factory=dict)  # seq -> local time

    def add(self, ep: HistoryEpisode, ev: EpisodeEvidence, when: dt.datetime) -> None:
        self.episodes += 1
        self.open += ep.status == "open"
        self.accepted += ev.accepted
        self.refused += ev.refused_count
        self.asked_for += ev.asked_for
        self.answered += ev.answered
        self.last_seen = when
        self.times[ep.seq] = when
        self.fold.add(ev)
        if len(self.times) > _TIMES_KEPT:  # only the episodes the walk can still look at
            keep = {e.seq for _, e in (*self.fold.tail, *self.fold.run)}
            self.times = {s: t for s, t in self.times.items() if s in keep}

    def recent(self, n: int) -> list[EpisodeEvidence]:
        return self.fold.recent(n)

    def to_doc(self) -> dict[str, Any]:
        kept = {e.seq for _, e in self.fold.tail}
        return {
            "fold": self.fold.to_doc(),
            "episodes": self.episodes,
            "open": self.open,
            "accepted": self.accepted,
            "refused": self.refused,
            "asked_for": self.asked_for,
            "answered": self.answered,
            "last_seen": _iso(self.last_seen),
            "times": {str(s): _iso(t) for s, t in self.times.items() if s in kept},
        }

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> ContextHistory:
        return cls(
            fold=BeliefFold.from_doc(doc["fold"]),
            episodes=int(doc["episodes"]),
            open=int(doc["open"]),
            accepted=int(doc["accepted"]),
            refused=int(doc["refused"]),
            asked_for=int(doc["asked_for"]),
            answered=int(doc["answered"]),
            last_seen=_time(doc["last_seen"]),
            times={int(s): t for s, v in doc["times"].items() if (t := _time(v)) is not None},
        )


@dataclass(frozen=True, slots=True)
class Moment:
    """An episode a correction can point to: its number and local time."""

    seq: int
    at: dt.datetime


@dataclass(slots=True)
class History:
    """The walk over a person's episodes, oldest first: per context (time slot, situation),
    and the moments by the learner's episode number."""

    contexts: dict[tuple[str, str], ContextHistory] = field(
        default_factory=lambda: defaultdict(ContextHistory)
    )
    episodes: int = 0
    open: int = 0
    upto_seq: int = 0  # the last episode walked
    utc_offset: int | None = None  # the offset of the last episode walked
    moments: dict[int, Moment] = field(default_factory=dict)

    def walk_stored(
        self,
        session: Session,
        user_pk: int,
        space_of: Callable[[int], NegotiationSpace],
        *,
        upto_seq: int,
        keep_moments: Container[int] | None = None,
    ) -> None:
        """Go on over the person's stored episodes after :attr:`upto_seq` up to ``upto_seq``,
        read :data:`PAGE` at a time: a history of any length in bounded memory."""
        for after in range(self.upto_seq, upto_seq, PAGE):
            episodes, answers = episodes_repo.history(
                session, user_pk, after_seq=after, upto_seq=min(upto_seq, after + PAGE)
            )
            self.walk(episodes, answers, space_of, keep_moments=keep_moments)

    def walk(
        self,
        episodes: Iterable[HistoryEpisode],
        answers: Iterable[HistoryAnswer],
        space_of: Callable[[int], NegotiationSpace],
        *,
        keep_moments: Container[int] | None = None,
    ) -> None:
        """Go on over ``episodes`` (after :attr:`upto_seq`, oldest first) with their answers
        (in order; those of other episodes are ignored). ``keep_moments``: the learner's
        episodes whose moments to keep (those corrections point to); all if not given."""
        by_seq: dict[int, list[HistoryAnswer]] = defaultdict(list)
        for a in answers:
            by_seq[a.seq].append(a)
        for ep in episodes:
            if ep.seq <= self.upto_seq:
                continue
            ev = episode_evidence(
                space_of(ep.mission_version),
                ep.seq,
                [Answer(a.action, a.response, a.service, a.detail) for a in by_seq[ep.seq]],
                request=Item(ep.request_service, ep.request_detail) if ep.request_service else None,
            )
            when = local_time(ep.occurred_at, ep.utc_offset)
            self.contexts[(ep.time_slot, ep.situation)].add(ep, ev, when)
            self.episodes += 1
            self.open += ep.status == "open"
            self.upto_seq = ep.seq
            self.utc_offset = ep.utc_offset
            if keep_moments is None or ep.learner_episode in keep_moments:
                self.moments[ep.learner_episode] = Moment(ep.seq, when)

    def context(self, slot: str, situation: str) -> ContextHistory:
        found = self.contexts.get((slot, situation))
        return ContextHistory() if found is None else found

    def to_doc(self, keep_moments: Iterable[int]) -> dict[str, Any]:
        """The walk as a document, with the moments of the learner's episodes
        ``keep_moments`` (those a correction points to) and no others."""
        keep = set(keep_moments)
        return {
            "fold_version": FOLD_VERSION,
            "contexts": [[s, t, c.to_doc()] for (s, t), c in sorted(self.contexts.items())],
            "episodes": self.episodes,
            "open": self.open,
            "upto_seq": self.upto_seq,
            "utc_offset": self.utc_offset,
            "moments": [
                [e, m.seq, _iso(m.at)] for e, m in sorted(self.moments.items()) if e in keep
            ],
        }

    @classmethod
    def from_doc(cls, doc: dict[str, Any] | None) -> History:
        h = cls()
        if doc is None:
            return h
        if doc.get("fold_version") != FOLD_VERSION:
            raise ValueError(f"a history fold of version {doc.get('fold_version')!r}")
        for slot, situation, c in doc["contexts"]:
            h.contexts[(slot, situation)] = ContextHistory.from_doc(c)
        h.episodes = int(doc["episodes"])
        h.open = int(doc["open"])
        h.upto_seq = int(doc["upto_seq"])
        h.utc_offset = doc["utc_offset"]
        for e, seq, at in doc["moments"]:
            when = _time(at)
            if when is not None:
                h.moments[int(e)] = Moment(int(seq), when)
        return h


def _iso(at: dt.datetime | None) -> str | None:
    return None if at is None else at.isoformat()


def _time(text: str | None) -> dt.datetime | None:
    return None if text is None else dt.datetime.fromisoformat(text)
