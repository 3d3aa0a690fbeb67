"""What a person is believed to want in one context (app.learning.beliefs, docs/method.md §14):
the evidence each episode gives, from the person's answers; the belief and its certainty
(unknown, tentative, confident); a change of mind after :data:`CHANGE_RUN` contradicting
episodes; refusals of a detail do not speak against a service; a later detail refines a belief
that named only the service. The thresholds are read from the module, not copied.
"""

from __future__ import annotations

import math

import pytest

from app.learning import ActionKind
from app.learning.beliefs import (
    CHANGE_RUN,
    CONFIDENT_SHARE,
    CONFIDENT_SUPPORT,
    WINDOW,
    Answer,
    EpisodeEvidence,
    Item,
    belief,
    episode_evidence,
)
from tests.support.office import DRINK, INFO, INITIATE, PASS, PERFORM_TEA, QUERY_TYPE, S, act

TEA = Item(DRINK, "tea")
COFFEE = Item(DRINK, "coffee")
A_DRINK = Item(DRINK)
NEWS = Item(INFO, "news")


def chose(seq: int, item: Item) -> EpisodeEvidence:
    """An episode where the person took or named ``item``."""
    return EpisodeEvidence(seq, chose=item, accepted=1)


def refused(seq: int, item: Item) -> EpisodeEvidence:
    """An episode where the person turned ``item`` down when the robot brought it."""
    return EpisodeEvidence(seq, refused=[item], refused_count=1)


def refused_offer(seq: int) -> EpisodeEvidence:
    return EpisodeEvidence(seq, refused_offer=True, refused_count=1)


def nothing(seq: int) -> EpisodeEvidence:
    """An episode that says nothing about the person (no answer of theirs)."""
    return EpisodeEvidence(seq)


def perform(item: Item) -> int:
    return act(ActionKind.PERFORM, item.service, item.detail)


class TestEvidence:
    def test_a_performed_service_taken(self) -> None:
        ev = episode_evidence(S, 1, [Answer(INITIATE, "accepted"), Answer(PERFORM_TEA, "accepted")])
        assert ev.chose == TEA
        assert (ev.accepted, ev.refused_count) == (1, 0)
        assert ev.relevant

    def test_a_performed_service_turned_down(self) -> None:
        ev = episode_evidence(S, 1, [Answer(INITIATE, "accepted"), Answer(PERFORM_TEA, "rejected")])
        assert ev.chose is None
        assert ev.refused == [TEA]
        assert ev.refused_count == 1
        assert ev.relevant

    def test_an_offer_turned_down(self) -> None:
        ev = episode_evidence(S, 1, [Answer(INITIATE, "rejected")])
        assert ev.refused_offer
        assert ev.chose is None
        assert ev.relevant

    def test_a_request_and_answers(self) -> None:
        asked = episode_evidence(S, 1, [], request=TEA)
        assert (asked.chose, asked.asked_for) == (TEA, 1)
        named = episode_evidence(S, 2, [Answer(PASS, "human_request", DRINK, "coffee")])
        assert (named.chose, named.asked_for) == (COFFEE, 1)
        typed = episode_evidence(
            S, 3, [Answer(INITIATE, "accepted"), Answer(QUERY_TYPE, "answered", DRINK)]
        )
        assert (typed.chose, typed.answered) == (A_DRINK, 1)
        detailed = episode_evidence(
            S,
            4,
            [
                Answer(INITIATE, "accepted"),
                Answer(QUERY_TYPE, "answered", DRINK),
                Answer(act(ActionKind.QUERY_DETAIL, DRINK), "answered", None, "water"),
            ],
        )
        assert (detailed.chose, detailed.answered) == (Item(DRINK, "water"), 2)

    def test_no_answer_says_nothing(self) -> None:
        ev = episode_evidence(S, 1, [Answer(PASS, "none")])
        assert not ev.relevant
        assert belief([ev]).certainty == "unknown"


class TestCertainty:
    def test_unknown_without_choices(self) -> None:
        for evidence in ([], [nothing(1), nothing(2)]):
            b = belief(evidence)
            assert b.wants is None
            assert b.certainty == "unknown"
            assert b.support == 0
            assert b.change is None

    def test_refusals_alone_say_nothing_wanted(self) -> None:
        b = belief([refused(1, TEA), refused_offer(2), refused(3, COFFEE)])
        assert b.wants is None
        assert b.certainty == "unknown"

    def test_tentative_after_one_choice(self) -> None:
        b = belief([chose(1, TEA)])
        assert b.wants == TEA
        assert b.certainty == "tentative"
        assert (b.support, b.recent) == (1, 1)

    def test_confident_with_enough_support(self) -> None:
        for n in range(1, CONFIDENT_SUPPORT + 3):
            b = belief([chose(i, TEA) for i in range(1, n + 1)])
            assert b.wants == TEA
            assert b.certainty == ("confident" if n >= CONFIDENT_SUPPORT else "tentative"), n
            assert b.support == min(n, WINDOW)
            assert b.support <= b.recent <= WINDOW

    @staticmethod
    def _mixed(support: int, refusals: int) -> list[EpisodeEvidence]:
        """``support`` choices of tea and ``refusals`` of it, never two refusals in a row (the
        belief holds: CHANGE_RUN > 1)."""
        assert CHANGE_RUN > 1
        assert refusals <= support - 1
        evidence = [chose(1, TEA)]
        for _ in range(refusals):
            evidence += [refused(len(evidence) + 1, TEA), chose(len(evidence) + 2, TEA)]
        while len(evidence) < support + refusals:
            evidence.append(chose(len(evidence) + 1, TEA))
        return evidence

    def test_confident_needs_the_share(self) -> None:
        for support in range(1, WINDOW + 1):
            for refusals in range(0, min(support - 1, WINDOW - support) + 1):
                b = belief(self._mixed(support, refusals))
                assert b.wants == TEA
                assert (b.support, b.recent) == (support, support + refusals)
                confident = support >= CONFIDENT_SUPPORT and support >= CONFIDENT_SHARE * (
                    support + refusals
                )
                assert b.certainty == ("confident" if confident else "tentative"), b

    def test_the_share_boundary(self) -> None:
        # exactly CONFIDENT_SHARE of the recent episodes support it: confident; one more
        # refusal among them: tentative
        support = CONFIDENT_SUPPORT
        while not math.isclose(support / CONFIDENT_SHARE, round(support / CONFIDENT_SHARE)):
            support += 1
        total = round(support / CONFIDENT_SHARE)
        assert total <= WINDOW
        assert belief(self._mixed(support, total - support)).certainty == "confident"
        assert belief(self._mixed(support, total - support + 1)).certainty == "tentative"

    def test_only_the_window_counts(self) -> None:
        evidence = [chose(i, TEA) for i in range(1, 3 * WINDOW)]
        b = belief(evidence)
        assert (b.support, b.recent) == (WINDOW, WINDOW)
        assert b.certainty == "confident"


class TestChange:
    def test_a_change_after_the_run(self) -> None:
        before = [chose(i, TEA) for i in range(1, 6)]
        for run in range(1, CHANGE_RUN):
            b = belief(before + [chose(5 + i, COFFEE) for i in range(1, run + 1)])
            assert b.wants == TEA, run
            assert b.change is None
        b = belief(before + [chose(5 + i, COFFEE) for i in range(1, CHANGE_RUN + 1)])
        assert b.wants == COFFEE
        assert b.change is not None
        assert b.change.before == TEA
        assert b.change.now == COFFEE
        assert b.change.seq == 6  # where the new wish first showed
        assert b.certainty == ("confident" if CHANGE_RUN >= CONFIDENT_SUPPORT else "tentative")
        assert b.support == CHANGE_RUN
        assert b.recent == CHANGE_RUN  # counted since the change

    def test_the_latest_choice_of_the_run_is_the_new_belief(self) -> None:
        run = (
            [chose(10, NEWS)]
            + [refused_offer(11 + i) for i in range(CHANGE_RUN - 2)]
            + [chose(10 + CHANGE_RUN, COFFEE)]
        )
        b = belief([chose(i, TEA) for i in range(1, 4)] + run)
        assert b.change is not None
        assert b.change.before == TEA
        assert b.change.now == COFFEE
        assert b.change.seq == 10

    def test_refusals_only_leave_nothing_wanted(self) -> None:
        b = belief(
            [chose(1, TEA), chose(2, TEA)]
            + [refused(3 + i, TEA) if i % 2 else refused_offer(3 + i) for i in range(CHANGE_RUN)]
        )
        assert b.change is not None
        assert b.change.before == TEA
        assert b.change.now is None
        assert b.change.seq == 3
        assert b.wants is None
        assert b.certainty == "unknown"
        # the next choice becomes the belief
        after = belief(
            [chose(1, TEA), chose(2, TEA)]
            + [refused_offer(3 + i) for i in range(CHANGE_RUN)]
            + [chose(3 + CHANGE_RUN, NEWS)]
        )
        assert after.wants == NEWS
        assert after.certainty == "tentative"

    def test_a_support_breaks_the_run(self) -> None:
        evidence = [chose(1, TEA)]
        seq = 2
        for _ in range(4):
            evidence += [chose(seq + i, COFFEE) for i in range(CHANGE_RUN - 1)]
            seq += CHANGE_RUN - 1
            evidence.append(chose(seq, TEA))
            seq += 1
        b = belief(evidence)
        assert b.wants == TEA
        assert b.change is None

    def test_a_change_is_reported_while_among_the_latest_episodes(self) -> None:
        evidence = [chose(1, TEA)] + [chose(2 + i, COFFEE) for i in range(CHANGE_RUN)]
        seq = 2 + CHANGE_RUN
        # still among the latest WINDOW episodes: reported
        while len(evidence) - 1 <= WINDOW:  # the change's first episode is evidence[1]
            b = belief(evidence)
            assert b.change is not None, len(evidence)
            assert b.change.seq == 2
            evidence.append(chose(seq, COFFEE))
            seq += 1
        # the change's first episode has left the latest WINDOW: no longer reported
        assert [e.seq for e in evidence[-WINDOW:]][0] > 2
        b = belief(evidence)
        assert b.wants == COFFEE
        assert b.change is None
        assert b.certainty == "confident"

    def test_episodes_that_say_nothing_do_not_break_or_make_a_run(self) -> None:
        evidence = [chose(1, TEA), chose(2, COFFEE), nothing(3), nothing(4), chose(5, COFFEE)]
        b = belief(evidence)
        assert b.wants == (COFFEE if CHANGE_RUN == 2 else TEA)
        assert b.recent <= len([e for e in evidence if e.relevant])


class TestServiceAndDetail:
    def test_refusing_coffee_does_not_contradict_wanting_a_drink(self) -> None:
        evidence = [chose(1, A_DRINK)] + [refused(2 + i, COFFEE) for i in range(2 * CHANGE_RUN)]
        b = belief(evidence)
        assert b.wants == A_DRINK
        assert b.change is None
        assert not evidence[1].contradicts(A_DRINK)
        assert evidence[1].contradicts(COFFEE)

    def test_a_later_detail_refines_the_service(self) -> None:
        b = belief([chose(1, A_DRINK), chose(2, TEA)])
        assert b.wants == TEA
        assert b.change is None
        assert b.support == 2
        # a detail of another service is no refinement: it contradicts
        other = belief([chose(1, A_DRINK)] + [chose(2 + i, NEWS) for i in range(CHANGE_RUN)])
        assert other.wants == NEWS
        assert other.change is not None
        assert other.change.before == A_DRINK

    def test_a_service_only_choice_supports_a_detailed_belief(self) -> None:
        b = belief([chose(1, TEA)] + [chose(2 + i, A_DRINK) for i in range(CHANGE_RUN + 1)])
        assert b.wants == TEA
        assert b.support == CHANGE_RUN + 2

    def test_taking_then_refusing_the_same_is_no_choice(self) -> None:
        ev = episode_evidence(
            S,
            1,
            [
                Answer(INITIATE, "accepted"),
                Answer(perform(TEA), "accepted"),
                Answer(perform(TEA), "rejected"),
            ],
        )
        assert ev.chose is None
        assert ev.refused == [TEA]
        assert not ev.supports(TEA)
        assert ev.contradicts(TEA)


@pytest.mark.parametrize("item", [TEA, A_DRINK, NEWS])
def test_covers_compares_the_known_parts(item: Item) -> None:
    assert item.covers(item)
    assert A_DRINK.covers(TEA)
    assert TEA.covers(A_DRINK)
    assert not TEA.covers(COFFEE)
    assert not NEWS.covers(A_DRINK)
