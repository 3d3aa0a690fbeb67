"""How the learners are evaluated: the paper's experiments (docs/method.md §12) as pure, seeded
functions, with the protocols (E1/E2, E3, PA), the methods compared, the per-user run loop and
the paper's metrics. ``app.experiments`` runs them in parallel and writes the reports.

A *run* is one method on one protocol with one seed: ``n_users`` simulated users, each with a
fresh learner, each living through the protocol's event stream. Seeds are split so that methods
share everything but their own draws (common random numbers):

- the users' needs and their drift depend on (seed, user) only, the same in every protocol;
- the event stream and the users' coin flips depend on (seed, user, protocol);
- the learner's generator depends on (seed, user, protocol, method).
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from .learners import make_learner
from .learners.base import TabularLearner
from .mission import Mission
from .negotiation import INTERACTION_CODE, Tally
from .simulation import STEP_COLUMNS, UserProfile, drift, event_stream, random_profile, respond
from .types import Observation

__all__ = [
    "ABLATION_METHODS",
    "E1E2",
    "E3",
    "PA",
    "PAPER_METHODS",
    "Method",
    "Protocol",
    "RunResult",
    "episode_metrics",
    "run",
    "run_user",
    "summarize",
]


@dataclass(frozen=True)
class Method:
    """A named learner configuration."""

    label: str
    algorithm: str
    params: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # Read-only: the method tables below are shared by every run.
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    def __reduce__(self) -> tuple[type[Method], tuple[str, str, dict[str, Any]]]:
        return (Method, (self.label, self.algorithm, dict(self.params)))

    @property
    def key(self) -> int:
        return zlib.crc32(self.label.encode())


@dataclass(frozen=True)
class Protocol:
    """An event stream: ``n_events`` events per user, needs drifting at ``change_at`` (0-based)."""

    name: str
    n_events: int
    change_at: int | None
    stream: int


E1E2 = Protocol("e1e2", 100, 50, stream=1)  # Fig. 2: events 1-50; Fig. 3: events 51-100
E3 = Protocol("e3", 100, 50, stream=2)  # the independent rerun of Table II
PA = Protocol("pa", 200, 100, stream=3)  # the 200-event performance analysis

PAPER_METHODS: tuple[Method, ...] = (
    Method("R-MAX", "rmax"),
    Method("Q-learning", "qlearning"),
    Method("HRI τ=0.01", "hri", {"tau": 0.01}),
    Method("HRI τ=0.005", "hri", {"tau": 0.005}),
    Method("DTS", "dts"),
)

ABLATION_METHODS: tuple[Method, ...] = (
    Method("HRI τ=0.01", "hri", {"tau": 0.01}),
    Method("no exclusion", "hri", {"tau": 0.01, "exclusion": "none"}),
    Method("root-only exclusion", "hri", {"tau": 0.01, "exclusion": "root_only"}),
    Method("M ≡ 0", "hri", {"tau": 0.01, "measure": False}),
    Method("adaptive τ (κ=1)", "hri", {"tau": 0.01, "kappa": 1.0}),
    Method("w_I1 = 1.5", "hri", {"tau": 0.01, "w_i1": 1.5}),
    Method("per-context t", "hri", {"tau": 0.01, "staleness": "context"}),
    Method("Vmax if never tried", "hri", {"tau": 0.01, "unknown": "vmax_if_never_tried"}),
)

# Interaction classes as stored in RunResult.interaction.


@dataclass
class RunResult:
    """Per-event records, shape (users, events) each."""

    method: str
    protocol: str
    seed: int
    reward: np.ndarray  # float64: the episode's total reward (silent steps included)
    initiated: np.ndarray  # bool: the robot chose to initiate
    interaction: np.ndarray  # int8: 0 none, 1 I1, 2 I2, 3 I3
    success: np.ndarray  # bool: a performed service was accepted
    queries: np.ndarray  # int64: query actions in the episode


def _seq(*words: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(w) for w in words]))


def user_profiles(mission: Mission, seed: int, user: int) -> tuple[UserProfile, UserProfile]:
    """The user's needs before and after the change (the same in every protocol)."""
    before = random_profile(mission, _seq(seed, user, 0))
    return before, drift(before, mission, _seq(seed, user, 1))


def run_user(
    learner: TabularLearner[Any],
    profiles: Sequence[UserProfile],
    change_points: Sequence[int],
    contexts: np.ndarray,
    uniforms: np.ndarray,
    rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """One learner through one user's event stream; returns the per-event records."""
    space = learner.space
    n = len(contexts)
    out = {
        "reward": np.zeros(n, dtype=np.float64),
        "initiated": np.zeros(n, dtype=bool),
        "interaction": np.zeros(n, dtype=np.int8),
        "success": np.zeros(n, dtype=bool),
        "queries": np.zeros(n, dtype=np.int64),
    }
    active = 0
    for e in range(n):
        while active + 1 < len(change_points) and change_points[active + 1] <= e:
            active += 1
        profile, context, episode = profiles[active], int(contexts[e]), e + 1
        state, step = space.OBSERVE, 0
        tally = Tally()
        while state != space.END:
            # Visible steps happen in OBSERVE, ENGAGED, TYPE_KNOWN and DETAIL_KNOWN at most.
            assert 2 * step + 2 <= uniforms.shape[1], "an episode longer than a negotiation"
            decision = learner.select_action(Observation(context, state, episode), rng)
            reaction = respond(
                space,
                profile,
                context,
                decision.state,
                decision.action,
                uniforms[e, 2 * step : 2 * step + 2],
            )
            batch = decision.transitions(
                episode, reaction.reward, reaction.next_state, reaction.signal
            )
            learner.update(batch)
            for t in batch:
                tally.step(space, t.state, t.action, t.reward, t.next_state, t.signal)
            state, step = reaction.next_state, step + 1
        out["reward"][e] = tally.reward
        out["initiated"][e] = tally.initiated
        out["interaction"][e] = INTERACTION_CODE[tally.interaction]
        out["success"][e] = tally.success
        out["queries"][e] = tally.queries
    return out


def run(
    method: Method,
    protocol: Protocol,
    seed: int,
    mission: Mission,
    *,
    n_users: int = 6,
    user_params: Mapping[str, float] | None = None,
) -> RunResult:
    """One method through one protocol for ``n_users`` simulated users.

    ``user_params`` overrides the simulated users' response parameters (``UserProfile`` fields
    such as ``p_self`` or ``eps_fb``) for every user.
    """
    records: dict[str, list[np.ndarray]] = {}
    for user in range(n_users):
        before, after = user_profiles(mission, seed, user)
        if user_params:
            before = replace(before, **user_params)  # type: ignore[arg-type]
            after = replace(after, **user_params)  # type: ignore[arg-type]
        if protocol.change_at is None:
            profiles, points = [before], [0]
        else:
            profiles, points = [before, after], [0, protocol.change_at]
        contexts = event_stream(
            profiles, points, mission, protocol.n_events, _seq(seed, user, 2, protocol.stream)
        )
        uniforms = _seq(seed, user, 3, protocol.stream).random((protocol.n_events, STEP_COLUMNS))
        learner = make_learner(method.algorithm, method.params, mission)
        rng = _seq(seed, user, 4, protocol.stream, method.key)
        for name, values in run_user(learner, profiles, points, contexts, uniforms, rng).items():
            records.setdefault(name, []).append(values)
    stacked = {name: np.stack(values) for name, values in records.items()}
    return RunResult(method.label, protocol.name, seed, **stacked)


def episode_metrics(
    initiated: np.ndarray,
    interaction: np.ndarray,
    success: np.ndarray,
    queries: np.ndarray,
    reward: np.ndarray,
) -> dict[str, float]:
    """The paper's metrics over a block of episodes (1-D arrays of one user, or flattened).

    interaction_rate = episodes where the robot chose initiate / episodes;
    success_rate = missions (I1, I2 or I3) with an accepted service / missions;
    success_rate_engaged = the same over I1 and I2 missions only;
    queries_per_mission = query actions / missions.
    """
    episodes = len(initiated)
    missions = int(np.count_nonzero(interaction > 0))
    engaged = int(np.count_nonzero((interaction == 1) | (interaction == 2)))
    successes = int(np.count_nonzero(success))
    nan = float("nan")
    return {
        "episodes": float(episodes),
        "missions": float(missions),
        "interaction_rate": float(np.count_nonzero(initiated)) / episodes if episodes else nan,
        "success_rate": successes / missions if missions else nan,
        "success_rate_engaged": successes / engaged if engaged else nan,
        "queries_per_mission": float(np.sum(queries)) / missions if missions else nan,
        "total_reward": float(np.sum(reward)),
    }


def summarize(
    results: Iterable[RunResult], start: int = 0, stop: int | None = None
) -> dict[str, dict[str, tuple[float, float]]]:
    """Mean and standard deviation of each metric per method, over users x seeds, for the
    events ``start:stop``. NaNs (a user with no mission in the block) are left out."""
    per_method: dict[str, list[dict[str, float]]] = {}
    for res in results:
        for u in range(res.reward.shape[0]):
            sl = slice(start, stop)
            per_method.setdefault(res.method, []).append(
                episode_metrics(
                    res.initiated[u, sl],
                    res.interaction[u, sl],
                    res.success[u, sl],
                    res.queries[u, sl],
                    res.reward[u, sl],
                )
            )
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for method, rows in per_method.items():
        out[method] = {}
        for key in rows[0]:
            values = np.asarray([row[key] for row in rows], dtype=np.float64)
            values = values[np.isfinite(values)]
            out[method][key] = (
                (float(values.mean()), float(values.std())) if values.size else (float("nan"),) * 2
            )
    return out
