"""Bad input to the core's public functions gets a ValueError (or a StateFormatError /
MissionError, both ValueErrors) with a sentence, and leaves nothing changed; out-of-order closes
and forgotten episodes keep the recency rule right."""

from __future__ import annotations

import base64
import copy
import json
import zlib
from datetime import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.learning import (
    Mission,
    MissionError,
    Observation,
    Polarity,
    Rewards,
    Service,
    StateFormatError,
    TimeSlot,
    Transition,
    learner_from_state,
    load_mission,
    make_learner,
    space_for,
)
from app.learning.learners import HriLearner
from app.learning.simulation import UserProfile, event_stream, respond
from tests.support.office import END, ENGAGED, INITIATE, MISSION, OBS, PASS, S

ALGORITHMS = ["hri", "rmax", "qlearning", "dts"]


def snapshot(learner: Any) -> str:
    return json.dumps(learner.to_state(), sort_keys=True)


class TestBadInput:
    @pytest.mark.parametrize(
        ("algorithm", "params", "words"),
        [
            (5, None, "algorithm must be one of"),
            (["hri"], None, "algorithm must be one of"),
            ("hri", [1], "must be an object"),
            ("hri", {"tau": 10**400}, "tau"),
            ("dts", {"forgetting": "0.5"}, "forgetting"),
        ],
    )
    def test_make_learner(self, algorithm: Any, params: Any, words: str) -> None:
        with pytest.raises(ValueError, match=words):
            make_learner(algorithm, params, MISSION)

    @pytest.mark.parametrize("algorithm", ALGORITHMS)
    @pytest.mark.parametrize(
        ("obs", "words"),
        [
            (Observation(0.5, OBS, 1), "context must be a whole number"),  # type: ignore[arg-type]
            (Observation(0, "OBSERVE", 1), "state must be a whole number"),  # type: ignore[arg-type]
            (Observation(0, OBS, None), "episode must be a whole number"),  # type: ignore[arg-type]
            (Observation(0, OBS, 2**63), "episode must be in"),
            (Observation(-1, OBS, 1), "context must be in"),
            (Observation(0, OBS, True), "episode must be a whole number"),
        ],
    )
    def test_select_action(self, algorithm: str, obs: Observation, words: str) -> None:
        learner = make_learner(algorithm, None, MISSION)
        with pytest.raises(ValueError, match=words):
            learner.select_action(obs, np.random.default_rng(0))

    @pytest.mark.parametrize("algorithm", ALGORITHMS)
    @pytest.mark.parametrize(
        ("bad", "words"),
        [
            (Transition(1, 0, OBS, INITIATE, "x", ENGAGED), "reward must be a number"),  # type: ignore[arg-type]
            (Transition(1, 0, OBS, INITIATE, float("nan"), ENGAGED), "finite"),
            (Transition(1, 0, OBS, INITIATE, 1.0, ENGAGED, 5), "signal"),  # type: ignore[arg-type]
            (Transition(2**63, 0, OBS, INITIATE, 1.0, ENGAGED), "episode must be in"),
            (Transition(1, 0, OBS, 7, 1.0, ENGAGED), "not available"),
            (Transition(1, 0, OBS, 1.0, 1.0, ENGAGED), "action must be a whole number"),  # type: ignore[arg-type]
            (Transition(1, 0, OBS, INITIATE, 1.0, 99), "next_state must be in"),
            # Each a whole number of the right range but one field: what a fast path must
            # not let through.
            (Transition(1, 0, OBS, INITIATE, 1.0, ENGAGED, True), "signal"),  # type: ignore[arg-type]
            (Transition(True, 0, OBS, INITIATE, 1.0, ENGAGED), "episode must be a whole number"),
            (Transition(1, 0, OBS, INITIATE, float("inf"), ENGAGED), "finite"),
            (Transition(1, 0, OBS, INITIATE, True, ENGAGED), "reward must be a number"),
            (Transition(1, 10**6, OBS, INITIATE, 1.0, ENGAGED), "context must be in"),
            (Transition(1, 0, OBS, INITIATE, 1.0, OBS), "cannot follow"),
            (Transition(1, 0, END, INITIATE, 1.0, ENGAGED), "state must be in"),
        ],
    )
    def test_update_is_atomic(self, algorithm: str, bad: Transition, words: str) -> None:
        learner = make_learner(algorithm, None, MISSION)
        learner.update([Transition(1, 3, OBS, PASS, 0.0, END)])
        before = snapshot(learner)
        good = Transition(2, 0, OBS, INITIATE, 1.0, ENGAGED, Polarity.POSITIVE)
        with pytest.raises(ValueError, match=words):
            learner.update([good, bad])
        assert snapshot(learner) == before

    @pytest.mark.parametrize("algorithm", ALGORITHMS)
    def test_numpy_numbers_learn_as_python_numbers(self, algorithm: str) -> None:
        """A transition of numpy scalars (as read from arrays) is checked the long way and
        learned exactly as the same transition of plain ints and floats."""
        plain, wide = make_learner(algorithm, None, MISSION), make_learner(algorithm, None, MISSION)
        i = np.int64
        plain.update([Transition(1, 0, OBS, INITIATE, 1.0, ENGAGED, Polarity.POSITIVE)])
        wide.update(
            [Transition(i(1), i(0), i(OBS), i(INITIATE), np.float64(1.0), i(ENGAGED), i(1))]  # type: ignore[arg-type]
        )
        assert snapshot(wide) == snapshot(plain)

    def test_empty_update_changes_nothing(self) -> None:
        learner = make_learner("hri", None, MISSION)
        learner.update([])
        assert learner.version == 0


class TestImportChecksMeaning:
    def doc(self) -> dict[str, Any]:
        learner = make_learner("hri", None, MISSION)
        learner.update([Transition(1, 0, OBS, INITIATE, -2.0, END, Polarity.NEGATIVE)])
        return learner.to_state()

    def replace_array(self, doc: dict[str, Any], name: str, change: Any) -> dict[str, Any]:
        out = copy.deepcopy(doc)
        current = learner_from_state(doc, MISSION)
        array = getattr(current, name).copy()
        change(array)
        raw = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<")).tobytes()
        out["arrays"][name]["data"] = base64.b64encode(zlib.compress(raw)).decode()
        return out

    @pytest.mark.parametrize(
        ("name", "change", "words"),
        [
            ("rho", lambda a: a.__setitem__((0, 0), 7), "rho must hold polarities"),
            ("visits", lambda a: a.__setitem__((0, 0), -1), "visits must not be negative"),
            ("last", lambda a: a.__setitem__((0, 0), 99), "last must be between"),
            ("ns", lambda a: a.__setitem__((0, 0, 0, 0), -3.0), "ns must not be negative"),
            ("rho_episode", lambda a: a.__setitem__((0, 0), 50), "rho_episode must not exceed"),
        ],
    )
    def test_impossible_tables_are_refused(self, name: str, change: Any, words: str) -> None:
        with pytest.raises(StateFormatError, match=words):
            learner_from_state(self.replace_array(self.doc(), name, change), MISSION)

    def test_missing_params_are_refused(self) -> None:
        doc = self.doc()
        del doc["params"]
        with pytest.raises(StateFormatError, match="params must be an object"):
            learner_from_state(doc, MISSION)

    @pytest.mark.parametrize("shape", [None, 16, "16,30"])
    def test_bad_shape_field(self, shape: Any) -> None:
        doc = self.doc()
        doc["arrays"]["visits"]["shape"] = shape
        with pytest.raises(StateFormatError, match="arrays.visits.shape"):
            learner_from_state(doc, MISSION)

    def test_a_zlib_bomb_is_not_inflated(self) -> None:
        doc = self.doc()
        bomb = zlib.compress(bytes(200 * 1024 * 1024), 9)  # 200 MiB of zeros, ~200 KiB packed
        doc["arrays"]["visits"]["data"] = base64.b64encode(bomb).decode()
        with pytest.raises(StateFormatError, match="bytes, expected"):
            learner_from_state(doc, MISSION)

    def test_pending_row_with_infinite_episode(self) -> None:
        doc = self.doc()
        doc["pending"] = [[float("inf"), 0, 0, 0, 1.0, ENGAGED, 1]]
        with pytest.raises(StateFormatError, match="pending"):
            learner_from_state(doc, MISSION)


class TestRecencyUnderConcurrency:
    def test_most_recent_episode_sets_rho_even_if_it_closes_first(self) -> None:
        learner = make_learner("hri", None, MISSION)
        assert isinstance(learner, HriLearner)
        # Episode 1 is accepted and still open when episode 2 is rejected and closes.
        learner.update([Transition(1, 0, OBS, INITIATE, 1.0, ENGAGED, Polarity.POSITIVE)])
        learner.update([Transition(2, 0, OBS, INITIATE, -2.0, END, Polarity.NEGATIVE)])
        assert learner.rho[0, INITIATE] == Polarity.NEGATIVE
        query = S.actions_of(ENGAGED).start
        learner.update([Transition(1, 0, ENGAGED, query, -2.5, END, Polarity.NEGATIVE)])
        # Episode 2 is the last interaction in context 0: its rejection stays the reference.
        assert learner.rho[0, INITIATE] == Polarity.NEGATIVE
        assert learner.rho_episode[0, INITIATE] == 2
        assert learner.rho[0, query] == Polarity.NEGATIVE  # set by episode 1, the only one

    def test_an_episode_whose_start_was_forgotten_is_not_labelled(self) -> None:
        learner = make_learner("hri", None, MISSION)
        assert isinstance(learner, HriLearner)
        learner.update([Transition(1, 0, OBS, INITIATE, 1.0, ENGAGED, Polarity.POSITIVE)])
        for episode in range(2, 2 + learner.MAX_OPEN_EPISODES):  # robots that never report back
            learner.update([Transition(episode, 1, OBS, INITIATE, 1.0, ENGAGED, Polarity.POSITIVE)])
        assert 1 not in learner._pending
        query = S.actions_of(ENGAGED).start
        learner.update([Transition(1, 0, ENGAGED, query, -2.5, END, Polarity.NEGATIVE)])
        assert learner.ns[0].sum() == 0.0
        assert learner.rho[0, query] == Polarity.NEUTRAL

    def test_vmax_if_never_tried_survives_a_round_trip_mid_episode(self) -> None:
        learner = make_learner("hri", {"unknown": "vmax_if_never_tried"}, MISSION)
        learner.select_action(Observation(0, OBS, 1), np.random.default_rng(0))  # fills a cache
        learner.update([Transition(1, 0, OBS, INITIATE, 1.0, ENGAGED, Polarity.POSITIVE)])
        copy_ = learner_from_state(json.loads(json.dumps(learner.to_state())), MISSION)
        a = learner.select_action(Observation(0, OBS, 2), np.random.default_rng(1))
        b = copy_.select_action(Observation(0, OBS, 2), np.random.default_rng(1))
        assert np.array_equal(a.probabilities, b.probabilities)
        assert np.array_equal(learner.explain(0, 2).q, copy_.explain(0, 2).q)


class TestMissionInput:
    def test_lists_are_accepted_and_frozen(self) -> None:
        mission = Mission(
            name="tiny",
            time_slots=[TimeSlot("day", time(0, 0), time(0, 0))],  # type: ignore[arg-type]
            situations=["here"],  # type: ignore[arg-type]
            services=[Service("Tea", ["green"])],  # type: ignore[arg-type]
        )
        assert isinstance(mission.situations, tuple)
        assert isinstance(mission.services[0].details, tuple)
        assert space_for(mission).n_actions > 0  # hashable, so the space cache accepts it

    @pytest.mark.parametrize("value", [1e308, 10**400, float("nan")])
    def test_absurd_rewards(self, value: float) -> None:
        with pytest.raises(MissionError, match="rewards.positive"):
            Rewards(positive=value)

    def test_not_utf8(self, tmp_path: Path) -> None:
        path = tmp_path / "m.json"
        path.write_bytes(b"\xff\xfe{")
        with pytest.raises(MissionError, match="not UTF-8"):
            load_mission(path)

    def test_deeply_nested(self, tmp_path: Path) -> None:
        path = tmp_path / "m.json"
        path.write_text("[" * 100_000 + "]" * 100_000, encoding="utf-8")
        with pytest.raises(MissionError, match="m.json"):
            load_mission(path)


class TestSimulationInput:
    def test_change_points_must_start_at_zero(self) -> None:
        profile = UserProfile(())
        with pytest.raises(ValueError, match="change_points"):
            event_stream([profile], [5], MISSION, 10, np.random.default_rng(0))

    def test_abort_never_applies_to_staying_passive(self) -> None:
        profile = UserProfile((), p_abort=1.0)
        reaction = respond(S, profile, 0, OBS, PASS, np.array([0.9, 0.0]))
        assert (reaction.response, reaction.reward) == ("none", 0.0)
        reaction = respond(S, profile, 0, OBS, INITIATE, np.array([0.9, 0.0]))
        assert reaction.response == "terminated"
