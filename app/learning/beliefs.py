"""What a person is believed to want in one context, from their own answers: the rule the
profile speaks from (docs/method.md §14).

Each episode gives at most one *choice* (the most specific service, or service and detail, the
person took or named: a performed service accepted, a request, an answered question) and what
they turned down (a performed service refused, an offer refused). Walking the context's episodes
in order, the belief is the last choice the later episodes keep supporting; :data:`CHANGE_RUN`
episodes in a row that contradict it (another choice, or turning it or the offer down) replace
it, the recency rule of the learner (docs/method.md §4) in words: the person's recent answers
win over what they wanted before.

Certainty, over the episodes since the belief last changed (the latest :data:`WINDOW` of them):
``unknown`` with no choice; ``confident`` when at least :data:`CONFIDENT_SUPPORT` of them
support it and they are at least :data:`CONFIDENT_SHARE` of them; otherwise ``tentative`` (one
accepted guess is tentative). Pure: the standard library only.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from .space import ActionKind, NegotiationSpace

__all__ = [
    "CHANGE_RUN",
    "CONFIDENT_SHARE",
    "CONFIDENT_SUPPORT",
    "WINDOW",
    "Answer",
    "Belief",
    "BeliefFold",
    "Change",
    "EpisodeEvidence",
    "Item",
    "belief",
    "episode_evidence",
]

WINDOW = 8
CONFIDENT_SUPPORT = 3
CONFIDENT_SHARE = 0.75
CHANGE_RUN = 2


@dataclass(frozen=True, slots=True)
class Item:
    """A service, and the detail when known."""

    service: str
    detail: str | None = None

    def covers(self, other: Item) -> bool:
        """The same service, and the same detail where both are known."""
        return self.service == other.service and (
            self.detail is None or other.detail is None or self.detail == other.detail
        )


@dataclass(frozen=True, slots=True)
class Answer:
    """The person's response to one of the robot's own decisions (a pair index of the
    episode's mission)."""

    action: int
    response: str
    service: str | None = None
    detail: str | None = None


@dataclass(slots=True)
class EpisodeEvidence:
    """What one episode says about the person."""

    seq: int
    chose: Item | None = None
    refused: list[Item] = field(default_factory=list)
    refused_offer: bool = False
    accepted: int = 0
    refused_count: int = 0
    asked_for: int = 0
    answered: int = 0

    @property
    def relevant(self) -> bool:
        return self.chose is not None or bool(self.refused) or self.refused_offer

    def supports(self, item: Item) -> bool:
        return (
            self.chose is not None
            and self.chose.covers(item)
            and not any(_refuses(r, item) for r in self.refused)
        )

    def contradicts(self, item: Item) -> bool:
        if self.supports(item):
            return False
        return (
            self.chose is not None
            or self.refused_offer
            or any(_refuses(r, item) for r in self.refused)
        )


def _refuses(refused: Item, item: Item) -> bool:
    """Turning ``refused`` down speaks against ``item``: the same service and detail (turning
    coffee down says nothing against wanting a drink)."""
    return refused.service == item.service and refused.detail == item.detail


def episode_evidence(
    space: NegotiationSpace, seq: int, answers: Iterable[Answer], *, request: Item | None = None
) -> EpisodeEvidence:
    """The evidence of one episode: its opening request (if the person asked) and the person's
    answers to the robot's decisions, in order; ``space`` is the episode's mission's."""
    ev = EpisodeEvidence(seq)
    if request is not None:
        ev.asked_for += 1
        ev.chose = request
    for a in answers:
        act = space.actions[a.action]
        kind, said = act.kind, a.response
        if kind is ActionKind.PERFORM:
            assert act.service is not None
            item = Item(act.service, act.detail)
            if said == "accepted":
                ev.accepted += 1
                ev.chose = item
            elif said in ("rejected", "terminated"):
                ev.refused_count += 1
                ev.refused.append(item)
                if ev.chose == item:
                    ev.chose = None
        elif kind is ActionKind.INITIATE and said in ("rejected", "terminated"):
            ev.refused_count += 1
            ev.refused_offer = True
        elif kind is ActionKind.PASS and said == "human_request":
            ev.asked_for += 1
            if a.service is not None:
                ev.chose = Item(a.service, a.detail)
        elif kind is ActionKind.QUERY_TYPE and said == "answered" and a.service is not None:
            ev.answered += 1
            ev.chose = Item(a.service, None)
        elif kind is ActionKind.QUERY_DETAIL and said == "answered" and act.service is not None:
            ev.answered += 1
            ev.chose = Item(act.service, a.detail)
        elif kind in (ActionKind.QUERY_TYPE, ActionKind.QUERY_DETAIL) and said == "terminated":
            ev.refused_count += 1
    return ev


@dataclass(frozen=True, slots=True)
class Change:
    """The belief changed: ``before`` no longer held from episode ``seq`` on."""

    seq: int
    before: Item
    now: Item | None


@dataclass(frozen=True, slots=True)
class Belief:
    wants: Item | None
    certainty: str  # "unknown", "tentative", "confident"
    support: int
    recent: int
    change: Change | None  # the latest change, if it is among the recent episodes


def belief(evidence: Sequence[EpisodeEvidence]) -> Belief:
    """What the person wants in a context, from its episodes' evidence in order."""
    fold = BeliefFold()
    for ev in evidence:
        fold.add(ev)
    return fold.belief()


@dataclass(slots=True)
class BeliefFold:
    """The walk of :func:`belief` over a context's episodes, kept so that it can go on later
    from where it stopped: what a retention run stores of the episodes it removes.

    It keeps only what the rest of the walk can still look at: the current choice, where it
    began, the contradicting episodes in a row, the latest change and the latest
    :data:`WINDOW` relevant episodes. Folding some episodes and then the rest gives exactly
    the belief of walking them all at once."""

    relevant: int = 0  # relevant episodes walked
    current: Item | None = None
    since: int = 0  # index (among the relevant) where the current belief's episodes start
    run: list[tuple[int, EpisodeEvidence]] = field(default_factory=list)
    change: Change | None = None
    tail: list[tuple[int, EpisodeEvidence]] = field(default_factory=list)

    def add(self, ev: EpisodeEvidence) -> None:
        if not ev.relevant:
            return
        i = self.relevant
        self.relevant += 1
        self.tail = [*self.tail[-(WINDOW - 1) :], (i, ev)] if WINDOW > 1 else [(i, ev)]
        current = self.current
        if current is None:
            if ev.chose is not None:
                self.current, self.since, self.run = ev.chose, i, []
            return
        if ev.supports(current):
            self.run = []
            if current.detail is None and ev.chose is not None and ev.chose.detail is not None:
                self.current = Item(current.service, ev.chose.detail)
        elif ev.contradicts(current):
            self.run.append((i, ev))
            if len(self.run) >= CHANGE_RUN:
                now = _latest_choice(e for _, e in self.run)
                self.change = Change(self.run[0][1].seq, current, now)
                self.current, self.since, self.run = now, self.run[0][0], []

    def belief(self) -> Belief:
        window = [e for i, e in self.tail if i >= self.since]
        change = self.change
        if change is not None and all(e.seq > change.seq for _, e in self.tail):
            change = None
        current = self.current
        if current is None:
            return Belief(None, "unknown", 0, len(window), change)
        support = sum(e.supports(current) for e in window)
        confident = support >= CONFIDENT_SUPPORT and support >= CONFIDENT_SHARE * len(window)
        return Belief(
            current, "confident" if confident else "tentative", support, len(window), change
        )

    def recent(self, n: int) -> list[EpisodeEvidence]:
        """The latest ``n`` relevant episodes walked (at most :data:`WINDOW`)."""
        return [e for _, e in self.tail[-n:]] if n else []

    def to_doc(self) -> dict[str, Any]:
        """A JSON document of the walk (:meth:`from_doc` reads it back)."""
        return {
            "relevant": self.relevant,
            "current": _item_doc(self.current),
            "since": self.since,
            "run": [[i, _evidence_doc(e)] for i, e in self.run],
            "change": None
            if self.change is None
            else {
                "seq": self.change.seq,
                "before": _item_doc(self.change.before),
                "now": _item_doc(self.change.now),
            },
            "tail": [[i, _evidence_doc(e)] for i, e in self.tail],
        }

    @classmethod
    def from_doc(cls, doc: dict[str, Any]) -> BeliefFold:
        change = doc["change"]
        before = _item(change["before"]) if change else None
        return cls(
            relevant=int(doc["relevant"]),
            current=_item(doc["current"]),
            since=int(doc["since"]),
            run=[(int(i), _evidence(e)) for i, e in doc["run"]],
            change=None
            if change is None or before is None
            else Change(int(change["seq"]), before, _item(change["now"])),
            tail=[(int(i), _evidence(e)) for i, e in doc["tail"]],
        )


def _item_doc(item: Item | None) -> list[str | None] | None:
    return None if item is None else [item.service, item.detail]


def _item(doc: list[str | None] | None) -> Item | None:
    if doc is None:
        return None
    service, detail = doc
    assert service is not None
    return Item(service, detail)


def _evidence_doc(ev: EpisodeEvidence) -> dict[str, Any]:
    return {
        "seq": ev.seq,
        "chose": _item_doc(ev.chose),
        "refused": [_item_doc(r) for r in ev.refused],
        "refused_offer": ev.refused_offer,
        "accepted": ev.accepted,
        "refused_count": ev.refused_count,
        "asked_for": ev.asked_for,
        "answered": ev.answered,
    }


def _evidence(doc: dict[str, Any]) -> EpisodeEvidence:
    return EpisodeEvidence(
        seq=int(doc["seq"]),
        chose=_item(doc["chose"]),
        refused=[r for r in map(_item, doc["refused"]) if r is not None],
        refused_offer=bool(doc["refused_offer"]),
        accepted=int(doc["accepted"]),
        refused_count=int(doc["refused_count"]),
        asked_for=int(doc["asked_for"]),
        answered=int(doc["answered"]),
    )


def _latest_choice(episodes: Iterable[EpisodeEvidence]) -> Item | None:
    chosen = [e.chose for e in episodes if e.chose is not None]
    return chosen[-1] if chosen else None
