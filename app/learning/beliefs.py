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

from .space import ActionKind, NegotiationSpace

__all__ = [
    "CHANGE_RUN",
    "CONFIDENT_SHARE",
    "CONFIDENT_SUPPORT",
    "WINDOW",
    "Answer",
    "Belief",
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
    relevant = [e for e in evidence if e.relevant]
    current: Item | None = None
    since = 0  # index in ``relevant`` where the current belief's episodes start
    run: list[int] = []  # contradicting episodes in a row
    change: Change | None = None
    for i, ev in enumerate(relevant):
        if current is None:
            if ev.chose is not None:
                current, since, run = ev.chose, i, []
            continue
        if ev.supports(current):
            run = []
            if current.detail is None and ev.chose is not None and ev.chose.detail is not None:
                current = Item(current.service, ev.chose.detail)
        elif ev.contradicts(current):
            run.append(i)
            if len(run) >= CHANGE_RUN:
                now = _latest_choice(relevant[j] for j in run)
                change = Change(relevant[run[0]].seq, current, now)
                current, since, run = now, run[0], []
    window = relevant[max(since, len(relevant) - WINDOW) :]
    if change is not None and all(e.seq > change.seq for e in relevant[-WINDOW:]):
        change = None
    if current is None:
        return Belief(None, "unknown", 0, len(window), change)
    support = sum(e.supports(current) for e in window)
    confident = support >= CONFIDENT_SUPPORT and support >= CONFIDENT_SHARE * len(window)
    return Belief(current, "confident" if confident else "tentative", support, len(window), change)


def _latest_choice(episodes: Iterable[EpisodeEvidence]) -> Item | None:
    chosen = [e.chose for e in episodes if e.chose is not None]
    return chosen[-1] if chosen else None
