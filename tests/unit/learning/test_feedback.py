"""Delayed explicit feedback (``Learner.feedback``): a smile or a complaint after the fact moves
the pair's value the right way, open episodes take it as part of the sample, bad calls change
nothing, and no amount of it breaks the tables.

Office mission: r_pos 1, r_acc 5, r_neg -2, r_q -0.5.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from app.learning import (
    ALGORITHMS,
    Transition,
    learner_from_state,
    make_learner,
)
from app.learning.learners import HriLearner
from app.learning.state import decode_array
from tests.support.office import (
    DK,
    END,
    ENGAGED,
    INFER_TEA,
    INITIATE,
    MISSION,
    NEG,
    OBS,
    PERFORM_TEA,
    POS,
    QUERY_TYPE,
    TK,
    S,
)

CONTEXT = 0


def opening(ep: int, *, query_reward: float = -0.5) -> list[Transition]:
    """Initiated and accepted, then asked for the type (the person named a drink)."""
    return [
        Transition(ep, CONTEXT, OBS, INITIATE, 1.0, ENGAGED, POS),
        Transition(ep, CONTEXT, ENGAGED, QUERY_TYPE, query_reward, TK, POS),
    ]


def closing(ep: int, *, reward: float = 5.0) -> list[Transition]:
    """Inferred tea and served it."""
    return [
        Transition(ep, CONTEXT, TK, INFER_TEA, 0.0, DK),
        Transition(ep, CONTEXT, DK, PERFORM_TEA, reward, END, POS if reward > 0 else NEG),
    ]


def episode(ep: int, **rewards: float) -> list[Transition]:
    query = {"query_reward": rewards["query_reward"]} if "query_reward" in rewards else {}
    close = {"reward": rewards["reward"]} if "reward" in rewards else {}
    return opening(ep, **query) + closing(ep, **close)


def trained(algorithm: str, episodes: int = 2) -> Any:
    """A learner that served tea ``episodes`` times in ``CONTEXT`` (every pair known to R-MAX)."""
    learner = make_learner(algorithm, None, MISSION)
    for ep in range(1, episodes + 1):
        learner.update(episode(ep))
    return learner


def q_of(learner: Any, episode_index: int = 3) -> np.ndarray:
    q: np.ndarray = learner.explain(CONTEXT, episode_index).q
    return q


def snapshot(learner: Any) -> str:
    return json.dumps(learner.to_state(), sort_keys=True)


def clone(learner: Any) -> Any:
    return learner_from_state(json.loads(json.dumps(learner.to_state())), MISSION)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
@pytest.mark.parametrize("reward", [3.0, -3.0])
def test_feedback_on_a_closed_episode_moves_q(algorithm: str, reward: float) -> None:
    plain, told = trained(algorithm), trained(algorithm)
    before = told.version
    told.feedback(2, CONTEXT, PERFORM_TEA, reward)
    assert told.version == before + 1
    assert told.version == plain.version + 1
    q_plain, q_told = q_of(plain)[PERFORM_TEA], q_of(told)[PERFORM_TEA]
    if reward > 0:
        assert q_told > q_plain
    else:
        assert q_told < q_plain
    back = clone(told)
    assert back.version == told.version
    np.testing.assert_array_equal(q_of(back), q_of(told))
    assert snapshot(back) == snapshot(told)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_feedback_on_an_open_episode_counts_as_a_larger_reward(algorithm: str) -> None:
    extra = 2.0
    told = trained(algorithm, episodes=1)
    plain = trained(algorithm, episodes=1)
    larger = trained(algorithm, episodes=1)
    for tr in opening(2):
        told.update([tr])
        plain.update([tr])
    version = told.version
    told.feedback(2, CONTEXT, QUERY_TYPE, extra)
    assert told.version == version + 1
    # The open row carries the extra reward (and so does the export).
    assert [row[4] for row in told.to_state()["pending"] if row[3] == QUERY_TYPE] == [-0.5 + extra]
    np.testing.assert_array_equal(q_of(clone(told)), q_of(told))
    told.update(closing(2))
    plain.update(closing(2))
    larger.update(episode(2, query_reward=-0.5 + extra))
    assert told.to_state()["pending"] == []
    if algorithm == "hri":  # learns at close: the feedback is part of the sample
        np.testing.assert_array_equal(q_of(told), q_of(larger))
        assert told.to_state()["arrays"] == larger.to_state()["arrays"]
    assert q_of(told)[QUERY_TYPE] > q_of(plain)[QUERY_TYPE]
    assert q_of(larger)[QUERY_TYPE] > q_of(plain)[QUERY_TYPE]


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_feedback_on_a_pair_of_an_earlier_episode_while_another_is_open(algorithm: str) -> None:
    # Episode 2 is open but has not served tea yet: the feedback is about episode 1's sample.
    plain, told = trained(algorithm, episodes=1), trained(algorithm, episodes=1)
    plain.update(opening(2))
    told.update(opening(2))
    told.feedback(1, CONTEXT, PERFORM_TEA, 4.0)
    assert q_of(told)[PERFORM_TEA] >= q_of(plain)[PERFORM_TEA]
    assert snapshot(clone(told)) == snapshot(told)


def test_hri_feedback_lands_in_a_bucket_with_samples() -> None:
    # root_only: in-mission pairs keep no reference, so the neutral bucket is the target; tea's
    # sample sits under the positive polarity, and the feedback must join it there.
    learner = make_learner("hri", {"exclusion": "root_only"}, MISSION)
    assert isinstance(learner, HriLearner)
    learner.update(episode(1))
    q_before = q_of(learner)[PERFORM_TEA]
    learner.feedback(1, CONTEXT, PERFORM_TEA, 1.0)
    ns = learner.ns[CONTEXT, PERFORM_TEA].sum(axis=1)
    rs = learner.rs[CONTEXT, PERFORM_TEA]
    assert np.all(rs[ns == 0] == 0.0)
    assert rs[POS] == pytest.approx(6.0)
    assert q_of(learner)[PERFORM_TEA] > q_before


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
@pytest.mark.parametrize(
    ("episode_index", "context", "action", "reward", "words"),
    [
        (1, CONTEXT, S.PASS, 1.0, "never executed"),
        (1, CONTEXT + 1, PERFORM_TEA, 1.0, "never executed"),
        (0, CONTEXT, PERFORM_TEA, 1.0, "episode"),
        (4, CONTEXT, PERFORM_TEA, 1.0, "not been seen"),
        (1, CONTEXT, PERFORM_TEA, float("nan"), "finite"),
        (1, CONTEXT, PERFORM_TEA, float("inf"), "finite"),
        (1, CONTEXT, PERFORM_TEA, -float("inf"), "finite"),
        (1, CONTEXT, PERFORM_TEA, 10**400, "finite"),
        (1, CONTEXT, PERFORM_TEA, True, "number"),
        (1, CONTEXT, PERFORM_TEA, "1", "number"),
        (1, CONTEXT, S.n_actions, 1.0, "action"),
        (1, CONTEXT, -1, 1.0, "action"),
        (1, CONTEXT, 1.0, 1.0, "action"),
        (1, MISSION.n_contexts, PERFORM_TEA, 1.0, "context"),
    ],
)
def test_invalid_feedback_is_refused_and_changes_nothing(
    algorithm: str, episode_index: Any, context: Any, action: Any, reward: Any, words: str
) -> None:
    learner = trained(algorithm)
    learner.update(opening(3)[:1])  # an open episode too: episodes 1 to 3 are seen
    before = snapshot(learner)
    with pytest.raises(ValueError, match=words):
        learner.feedback(episode_index, context, action, reward)
    assert snapshot(learner) == before


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_many_alternating_feedbacks_stay_finite(algorithm: str) -> None:
    plain, learner = trained(algorithm), trained(algorithm)
    for i in range(2_000):
        learner.feedback(2, CONTEXT, PERFORM_TEA, 50.0 if i % 2 == 0 else -50.0)
    assert learner.version == plain.version + 2_000
    doc = learner.to_state()
    for name, enc in doc["arrays"].items():
        array = decode_array(
            enc, name=name, dtype=np.dtype(enc["dtype"]), shape=tuple(enc["shape"])
        )
        assert np.all(np.isfinite(array)), name
    q = q_of(learner)
    assert np.all(np.isfinite(q))
    np.testing.assert_allclose(q, q_of(plain), atol=1e-6)
    np.testing.assert_array_equal(q_of(clone(learner)), q)
