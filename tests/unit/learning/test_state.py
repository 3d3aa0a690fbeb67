"""Exported learner states: exact round trips, strict refusal of malformed documents, size."""

from __future__ import annotations

import base64
import copy
import dataclasses
import functools
import json
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from app.learning import (
    ALGORITHMS,
    Mission,
    Observation,
    StateFormatError,
    Transition,
    learner_from_state,
    make_learner,
    office_mission,
)
from app.learning.learners import TabularLearner
from app.learning.simulation import STEP_COLUMNS, random_profile, respond
from app.learning.state import FORMAT, FORMAT_VERSION, decode_array, encode_array, same_state
from tests.support.office import MISSION, S


def drive(lr: TabularLearner[Any], episodes: int, seed: int, *, own_policy: bool) -> None:
    """Run ``episodes`` events of one simulated user through ``lr``.

    own_policy: the learner decides (the service's loop); otherwise actions are uniform at
    random, which is fast and fills every table (the worst case for the exported size).
    """
    rng = np.random.default_rng(seed)
    # A person who accepts any initiation where service is welcome: deep negotiations happen in
    # every such context, not only in the few with a need.
    profile = dataclasses.replace(random_profile(MISSION, rng), p_idle_acc=1.0)
    contexts = rng.integers(S.n_contexts, size=episodes)
    uniforms = rng.random((episodes, STEP_COLUMNS))
    for e in range(episodes):
        episode, context, state, step = e + 1, int(contexts[e]), S.OBSERVE, 0
        while state != S.END:
            if own_policy:
                d = lr.select_action(Observation(context, state, episode), rng)
                batch = d.chain_transitions(episode)
                state, action = d.state, d.action
            else:
                batch = []
                while True:
                    actions = S.actions_of(state)
                    action = actions.start + int(rng.integers(len(actions)))
                    if not S.silent[action]:
                        break
                    nxt = int(S.silent_next[action])
                    batch.append(
                        Transition(
                            episode, context, state, action, float(S.silent_reward[action]), nxt
                        )
                    )
                    state = nxt
            r = respond(S, profile, context, state, action, uniforms[e, 2 * step : 2 * step + 2])
            batch.append(
                Transition(episode, context, state, action, r.reward, r.next_state, r.signal)
            )
            lr.update(batch)
            state, step = r.next_state, step + 1


@functools.cache
def trained_doc(algorithm: str) -> str:
    lr = make_learner(algorithm, None, MISSION)
    drive(lr, 40, seed=1, own_policy=True)
    # Leave one episode open, so the pending samples travel too.
    lr.update([Transition(41, 3, S.OBSERVE, S.INITIATE, 1.0, S.ENGAGED)])
    return json.dumps(lr.to_state())


def doc(algorithm: str = "hri") -> dict[str, Any]:
    loaded: dict[str, Any] = json.loads(trained_doc(algorithm))
    return loaded


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
class TestRoundTrip:
    def test_identical_learner(self, algorithm: str) -> None:
        original = doc(algorithm)
        lr = learner_from_state(copy.deepcopy(original), MISSION)
        assert lr.algorithm == algorithm
        assert lr.to_state() == original
        assert lr.version == original["version"] > 0
        assert original["pending"], "one episode was left open"
        twin = learner_from_state(copy.deepcopy(original), MISSION)
        obs = Observation(3, S.ENGAGED, 41)
        d1 = lr.select_action(obs, np.random.default_rng(7))
        d2 = twin.select_action(obs, np.random.default_rng(7))
        assert (d1.state, d1.action) == (d2.state, d2.action)
        assert np.array_equal(d1.probabilities, d2.probabilities)

    def test_document_shape(self, algorithm: str) -> None:
        d = doc(algorithm)
        assert d["format"] == FORMAT
        assert d["format_version"] == FORMAT_VERSION
        assert d["algorithm"] == algorithm
        assert d["mission"] == {"name": "office", "fingerprint": MISSION.fingerprint}
        assert d["params"] == make_learner(algorithm, None, MISSION).params.to_dict()
        for name in ("visits", "last", "last_ctx"):
            assert name in d["arrays"]
        for enc in d["arrays"].values():
            assert set(enc) == {"dtype", "shape", "encoding", "data"}


def test_encode_decode_exact() -> None:
    rng = np.random.default_rng(0)
    for arr in (
        rng.normal(size=(3, 4)),
        rng.integers(-9, 9, size=(5,)),
        rng.integers(0, 3, size=(2, 2)).astype(np.int8),
    ):
        enc = encode_array(arr)
        back = decode_array(enc, name="x", dtype=arr.dtype, shape=arr.shape)
        assert back.dtype == arr.dtype
        assert np.array_equal(back, arr)
    with pytest.raises(TypeError):
        encode_array(np.zeros(2, dtype=np.float32))


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def change(d: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        target = d
        for key in parents:
            target = target[key]
        target[last] = value

    return change


def _delete(path: str) -> Callable[[dict[str, Any]], None]:
    def change(d: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        target = d
        for key in parents:
            target = target[key]
        del target[last]

    return change


def _raw(data: bytes) -> str:
    return base64.b64encode(zlib.compress(data)).decode("ascii")


NAN_RS = encode_array(np.full((16, 30, 3), np.nan))
INF_LAST_Q = encode_array(np.full((16, 30), np.inf))

MALFORMED: list[tuple[str, Callable[[dict[str, Any]], None], str]] = [
    ("wrong format", _set("format", "pickle"), "format"),
    ("no format", _delete("format"), "format"),
    ("future version", _set("format_version", 2), "format_version"),
    ("version as text", _set("format_version", "1"), "format_version"),
    ("unknown algorithm", _set("algorithm", "sarsa"), "algorithm"),
    ("other mission", _set("mission.fingerprint", "sha256:0123"), "mission"),
    ("no mission", _delete("mission"), "mission"),
    ("bad params", _set("params.tau", -1.0), "params: tau"),
    ("unknown param", _set("params.temperature", 1.0), "params: temperature"),
    ("negative learner version", _set("version", -1), "version"),
    ("learner version as float", _set("version", 2.5), "version"),
    ("episodes missing", _delete("episodes"), "episodes"),
    ("arrays missing", _delete("arrays"), "arrays"),
    ("array missing", _delete("arrays.visits"), "arrays.visits is missing"),
    ("hri array missing", _delete("arrays.rho"), "arrays.rho is missing"),
    ("wrong shape", _set("arrays.visits.shape", [16, 29]), "arrays.visits.shape"),
    ("wrong dtype", _set("arrays.visits.dtype", "<f8"), "arrays.visits.dtype"),
    ("big-endian dtype", _set("arrays.ns.dtype", ">f8"), "arrays.ns.dtype"),
    ("wrong encoding", _set("arrays.visits.encoding", "raw"), "arrays.visits.encoding"),
    ("bad base64", _set("arrays.visits.data", "not base64!"), "arrays.visits.data"),
    (
        "not zlib",
        _set("arrays.visits.data", base64.b64encode(b"plain").decode()),
        "arrays.visits.data",
    ),
    ("data not a string", _set("arrays.visits.data", 12), "arrays.visits.data"),
    ("too few bytes", _set("arrays.visits.data", _raw(b"\0" * 8)), "arrays.visits.data"),
    ("array not an object", _set("arrays.last", [1, 2, 3]), "arrays.last"),
    ("NaN inside", _set("arrays.rs", NAN_RS), "arrays.rs contains NaN"),
    ("pending not a list", _set("pending", {"0": 1}), "pending"),
    ("short pending row", _set("pending", [[1, 2, 0]]), "pending[0]"),
    ("pending row with text", _set("pending", [["a", 0, 0, 0, 0.0, 17, 0]]), "pending[0]"),
    ("pending action of another state", _set("pending", [[1, 0, 0, 29, 0.0, 17, 0]]), "pending[0]"),
    ("pending impossible successor", _set("pending", [[1, 0, 0, 0, 0.0, 5, 0]]), "pending[0]"),
    ("pending NaN reward", _set("pending", [[1, 0, 0, 0, float("nan"), 17, 2]]), "pending[0]"),
    ("pending bad signal", _set("pending", [[1, 0, 0, 0, 1.0, 4, 9]]), "pending[0]"),
    ("pending context out of range", _set("pending", [[1, 16, 0, 0, 1.0, 4, 1]]), "pending[0]"),
]


@pytest.mark.parametrize(
    ("change", "field"), [pytest.param(c, f, id=name) for name, c, f in MALFORMED]
)
def test_malformed_documents_are_refused_naming_the_field(
    change: Callable[[dict[str, Any]], None], field: str
) -> None:
    d = doc("hri")
    change(d)
    with pytest.raises(StateFormatError) as info:
        learner_from_state(d, MISSION)
    assert field in str(info.value)


def test_nan_in_an_integer_learner_table() -> None:
    d = doc("qlearning")
    d["arrays"]["q"] = INF_LAST_Q
    with pytest.raises(StateFormatError, match="arrays.q contains NaN or infinite"):
        learner_from_state(d, MISSION)


def test_not_an_object() -> None:
    with pytest.raises(StateFormatError, match="JSON object"):
        learner_from_state([1, 2], MISSION)  # type: ignore[arg-type]


def test_algorithm_mismatch_on_a_learner_class() -> None:
    d = doc("rmax")
    with pytest.raises(StateFormatError, match="algorithm must be 'hri'"):
        ALGORITHMS["hri"].from_state(d, MISSION)


def test_state_of_another_mission() -> None:
    data = office_mission().to_dict()
    data["services"][0]["details"] = ["tea", "coffee", "juice"]
    other = Mission.from_dict(data)
    with pytest.raises(StateFormatError, match="mission 'office'"):
        learner_from_state(doc("hri"), other)


def test_state_format_error_is_a_value_error() -> None:
    assert issubclass(StateFormatError, ValueError)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_exported_size_after_10000_episodes(algorithm: str) -> None:
    lr = make_learner(algorithm, None, MISSION)
    drive(lr, 10_000, seed=2, own_policy=False)
    visited = np.count_nonzero(lr.visits)
    assert visited > 0.6 * lr.visits.size  # random actions reached most pairs
    text = json.dumps(lr.to_state())
    assert len(text.encode()) < 64 * 1024, len(text)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_exported_size_with_the_most_open_episodes(algorithm: str) -> None:
    lr = make_learner(algorithm, None, MISSION)
    drive(lr, 2_000, seed=3, own_policy=False)
    tk = S.type_known_state("ProvideDrink")
    dk = S.detail_known_state("ProvideDrink", "coffee")
    query_detail = S.actions_of(tk).start
    query_type = S.actions_of(S.ENGAGED).start
    for k in range(TabularLearner.MAX_OPEN_EPISODES + 50):  # robots that vanished mid-episode
        ep, c = 10**12 + k, k % S.n_contexts
        lr.update([Transition(ep, c, S.OBSERVE, S.INITIATE, 1.0, S.ENGAGED)])
        lr.update([Transition(ep, c, S.ENGAGED, query_type, -0.5, tk)])
        lr.update([Transition(ep, c, tk, query_detail, -0.5, dk)])
    state = lr.to_state()
    assert len(state["pending"]) == 3 * TabularLearner.MAX_OPEN_EPISODES
    assert len(json.dumps(state).encode()) < 64 * 1024


def test_same_state_compares_arrays_by_content() -> None:
    """A document written with another compression level is the same learner; any change of
    content or of a plain field is not."""
    original = doc("hri")
    recompressed = copy.deepcopy(original)
    for array in recompressed["arrays"].values():
        raw = zlib.decompress(base64.b64decode(array["data"]))
        array["data"] = base64.b64encode(zlib.compress(raw, 9)).decode("ascii")
    assert any(
        recompressed["arrays"][n]["data"] != original["arrays"][n]["data"]
        for n in original["arrays"]
    )
    assert same_state(original, recompressed)

    changed = copy.deepcopy(original)
    flipped = bytearray(zlib.decompress(base64.b64decode(changed["arrays"]["visits"]["data"])))
    flipped[0] ^= 1
    changed["arrays"]["visits"]["data"] = base64.b64encode(zlib.compress(bytes(flipped))).decode()
    assert not same_state(original, changed)

    later = copy.deepcopy(original)
    later["version"] += 1
    assert not same_state(original, later)

    missing = copy.deepcopy(original)
    del missing["arrays"]["visits"]
    assert not same_state(original, missing)
