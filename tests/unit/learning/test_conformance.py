"""Every learner the service ships passes the conformance suite, and the suite can fail."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from app.learning import ALGORITHMS, Mission, office_mission
from app.learning.checks import check_learner
from app.learning.config import PARAMS, HriParams
from app.learning.learners import HriLearner
from app.learning.state import encode_array
from app.learning.types import FloatArray, Transition

TINY = Mission.from_dict(
    {
        "name": "tiny",
        "situations": ["here"],
        "time_slots": [
            {"name": "day", "start": "06:00", "end": "18:00"},
            {"name": "night", "start": "18:00", "end": "06:00"},
        ],
        "services": [
            {"name": "Hug", "details": ["short"]},
            {"name": "Song", "details": ["happy", "sad"]},
        ],
        "rewards": {"positive": 2, "accepted_service": 3, "negative": -1, "query": 0},
        "gamma": 0.5,
    }
)


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_every_learner_conforms(algorithm: str) -> None:
    check_learner(algorithm, office_mission())


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_every_learner_conforms_on_another_mission(algorithm: str) -> None:
    # Every context holds a need, one service has a single detail, integer rewards, gamma 0.5.
    check_learner(algorithm, TINY, seed=3, updates=3_000)


@pytest.mark.parametrize(
    "params",
    [
        {"exclusion": "none"},
        {"exclusion": "root_only"},
        {"measure": False},
        {"kappa": 1.0},
        {"staleness": "context"},
        {"unknown": "vmax_if_never_tried"},
        {"pref_scale": "raw"},
        {"tau": 0.005, "w_i1": 1.5, "m_h": 2.0},
        {"tau": 0.0},
    ],
    ids=lambda p: ",".join(f"{k}={v}" for k, v in p.items()),
)
def test_hri_options_conform(params: dict[str, Any]) -> None:
    check_learner("hri", office_mission(), params, seed=1, updates=4_000)


@pytest.mark.parametrize(
    ("algorithm", "params"),
    [
        ("rmax", {"m": 1, "freeze_known": True}),
        ("qlearning", {"exploration": "boltzmann", "temperature": 0.05}),
        ("qlearning", {"epsilon0": 0.0, "epsilon_min": 0.0}),
        ("dts", {"forgetting": 1.0, "samples": 1, "i1_as_acceptance": False}),
        ("dts", {"change_alpha": 0.05}),
        ("dts", {"change_alpha": 0.5, "change_keep": 0.5, "samples": 2}),
    ],
)
def test_baseline_options_conform(algorithm: str, params: dict[str, Any]) -> None:
    check_learner(algorithm, office_mission(), params, seed=2, updates=3_000)


def test_misuse_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="algorithm"):
        check_learner("nope", office_mission())
    with pytest.raises(ValueError, match="tau"):
        check_learner("hri", office_mission(), {"tau": -1.0})
    with pytest.raises(ValueError, match="updates"):
        check_learner("hri", office_mission(), updates=-1)


# -- the suite catches broken learners --------------------------------------------------------


class NoVersionBump(HriLearner):
    def update(self, transitions: Sequence[Transition]) -> None:
        super().update(transitions)
        self.version -= 1


class DoubleVersionBump(HriLearner):
    def update(self, transitions: Sequence[Transition]) -> None:
        super().update(transitions)
        if len(self._pending) > 3:
            self.version += 1


class Unnormalized(HriLearner):
    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        return super()._policy(plan, context, state, episode) * 1.01


class NegativeProbabilities(HriLearner):
    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        p = super()._policy(plan, context, state, episode).copy()
        p[0] += 0.5
        p[-1] -= 0.5
        return p


class UniformOverAllPairs(HriLearner):
    """Returns a distribution of the wrong length (over every pair, not the state's actions)."""

    def _policy(self, plan: Any, context: int, state: int, episode: int) -> FloatArray:
        return np.full(self.space.n_actions, 1.0 / self.space.n_actions)


class SilentVisibleAction(HriLearner):
    """Stops the silent chain early: the robot would be told to 'infer' out loud."""

    def select_action(self, obs: Any, rng: np.random.Generator) -> Any:
        d = super().select_action(obs, rng)
        if d.chain:
            step = d.chain[-1]
            return dataclasses.replace(
                d,
                state=step.state,
                action=step.action,
                probabilities=step.probabilities,
                chain=d.chain[:-1],
            )
        return d


class WrongStateAction(HriLearner):
    def select_action(self, obs: Any, rng: np.random.Generator) -> Any:
        d = super().select_action(obs, rng)
        if d.state == self.space.OBSERVE:
            return dataclasses.replace(d, action=self.space.n_actions - 1)
        return d


class Unseeded(HriLearner):
    """Draws from a generator of its own instead of the one it is given."""

    _own = np.random.default_rng()

    def _plan(self, context: int, episode: int, rng: np.random.Generator | None) -> Any:
        q = super()._plan(context, episode, rng)
        return q + self._own.normal(size=q.shape)


class ForgetsOnExport(HriLearner):
    """Keeps a table it does not export: an imported copy decides differently."""

    def to_state(self) -> dict[str, Any]:
        doc = super().to_state()
        doc["arrays"]["rho"] = encode_array(np.zeros_like(self.rho))
        return doc


class NanInExplain(HriLearner):
    def _measure(self, context: int, episode: int) -> FloatArray:
        out = super()._measure(context, episode)
        if episode > 10**9:
            out[0] = np.nan
        return out


class OverflowsWhenStale(HriLearner):
    """Computes t^dQ naively, so huge staleness gives infinite preferences."""

    def _pref_parts(
        self, q: FloatArray, context: int, state: int, episode: int
    ) -> tuple[FloatArray, FloatArray]:
        qs, _ = super()._pref_parts(q, context, state, episode)
        t = np.maximum(episode - self.last[context, self.space.actions_of(state).start], 1)
        with np.errstate(over="ignore"):
            m = np.full_like(qs, float(t)) ** (1e3 * (qs - qs.mean()))
        return qs, m


class AcceptsGarbage(HriLearner):
    """Skips validation: a NaN reward goes into the tables."""

    def _check_transition(self, tr: Transition) -> None:
        pass


@dataclasses.dataclass(frozen=True)
class LaxHriParams(HriParams):
    def __post_init__(self) -> None:  # no validation at all
        pass


@pytest.mark.parametrize(
    ("broken", "message"),
    [
        (NoVersionBump, "exactly one"),
        (DoubleVersionBump, "exactly one"),
        (Unnormalized, "sum to"),
        (NegativeProbabilities, "negative"),
        (UniformOverAllPairs, "shape"),
        (SilentVisibleAction, "silent"),
        (WrongStateAction, "not available"),
        (Unseeded, "same seed|imported learner"),
        (ForgetsOnExport, "imported learner"),
        (NanInExplain, "NaN"),
        (OverflowsWhenStale, "probabilities|measure|invalid value"),
        (AcceptsGarbage, "must raise ValueError"),
    ],
)
def test_the_suite_catches_a_broken_learner(
    monkeypatch: pytest.MonkeyPatch, broken: type[HriLearner], message: str
) -> None:
    monkeypatch.setitem(ALGORITHMS, "hri", broken)
    with pytest.raises(AssertionError, match=message):
        check_learner("hri", office_mission(), updates=2_000)


def test_the_suite_catches_unvalidated_parameters(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(PARAMS, "hri", LaxHriParams)
    with pytest.raises(AssertionError, match=r"tau=.*was accepted"):
        check_learner("hri", office_mission(), updates=0)
