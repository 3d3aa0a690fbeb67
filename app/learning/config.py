"""Hyperparameters of every learner: frozen dataclasses, validated at construction.

Each invalid value raises ``ValueError`` with a sentence naming the parameter. ``from_dict`` is the
one way in from plain data (a request body, an exported state): unknown keys are refused too.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Self, TypeVar

__all__ = [
    "DtsAdaptParams",
    "DtsParams",
    "DtsRoutineParams",
    "HriParams",
    "Params",
    "QLearningParams",
    "RmaxParams",
]


def _number(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {value!r}.")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise ValueError(f"{name} must be a finite number, got {value!r}.")
    return number


def _in_range(
    name: str,
    value: object,
    low: float,
    high: float,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> None:
    v = _number(name, value)
    too_low = v <= low if low_open else v < low
    too_high = v >= high if high_open else v > high
    if too_low or too_high:
        lo = "(" if low_open else "["
        hi = ")" if high_open else "]"
        raise ValueError(f"{name} must be in {lo}{low:g}, {high:g}{hi}, got {value!r}.")


def _integer(name: str, value: object, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be a whole number, got {value!r}.")
    if not low <= value <= high:
        raise ValueError(f"{name} must be between {low} and {high}, got {value!r}.")


def _choice(name: str, value: object, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(allowed)}; got {value!r}.")


def _flag(name: str, value: object) -> None:
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be true or false, got {value!r}.")


P = TypeVar("P", bound="Params")


@dataclass(frozen=True)
class Params:
    """Base of the parameter objects: plain-data round trip with strict validation."""

    algorithm: ClassVar[str] = ""

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> Self:
        if data is not None and not isinstance(data, Mapping):
            raise ValueError(f"params of {cls.algorithm} must be an object of parameter values.")
        data = dict(data or {})
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ValueError(
                f"{unknown[0]} is not a parameter of {cls.algorithm}; allowed: {', '.join(names)}."
            )
        for f in dataclasses.fields(cls):
            # JSON has one number type: accept 2 for a float parameter, keep ints as ints.
            value = data.get(f.name)
            if (
                f.type in ("float", float)
                and isinstance(value, int)
                and not isinstance(value, bool)
                and abs(value) < 2**53
            ):
                data[f.name] = float(value)
        return cls(**data)

    def to_dict(self) -> dict[str, Any]:
        # The fields are scalars, so a shallow copy is the whole of it (asdict deep-copies).
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


@dataclass(frozen=True)
class HriParams(Params):
    """The paper's HRI-based learner (docs/method.md §4-§5).

    tau: Gibbs temperature tau0 (paper: 0.01 "HRI-based 100", 0.005 "HRI-based 200").
    kappa: context factor, tau(c) = tau0 * (1 + kappa * U(c)), U = share of unvisited pairs in c.
    m_h: filtered count n' from which a pair's model is trusted (eqs. 2-3).
    w_i1: weight of samples from human-initiated (I1) episodes.
    unknown: "neutral" (R0 = 0, unknown -> END) or "vmax_if_never_tried" (Q = Vmax when n = 0).
    exclusion: recency exclusion scope: "per_pair" (root by context, in-mission per pair),
        "root_only" (literal eq. 1), or "none" (ablation: no exclusion).
    measure: use the temporal measure M = t^dQ (False: plain Gibbs on Q, an ablation).
    pref_scale: "vmax" (Q / Vmax in dQ and Pref) or "raw".
    staleness: count t over all episodes ("global") or over the context's episodes ("context").
    vi_tol, vi_max_sweeps: value-iteration stopping rule.
    """

    algorithm: ClassVar[str] = "hri"
    tau: float = 0.01
    kappa: float = 0.0
    m_h: float = 1.0
    w_i1: float = 1.0
    unknown: str = "neutral"
    exclusion: str = "per_pair"
    measure: bool = True
    pref_scale: str = "vmax"
    staleness: str = "global"
    vi_tol: float = 1e-8
    vi_max_sweeps: int = 500

    def __post_init__(self) -> None:
        _in_range("tau", self.tau, 0.0, 100.0)
        _in_range("kappa", self.kappa, 0.0, 100.0)
        _in_range("m_h", self.m_h, 0.0, 1e6, low_open=True)
        _in_range("w_i1", self.w_i1, 0.0, 100.0, low_open=True)
        _choice("unknown", self.unknown, ("neutral", "vmax_if_never_tried"))
        _choice("exclusion", self.exclusion, ("per_pair", "root_only", "none"))
        _flag("measure", self.measure)
        _choice("pref_scale", self.pref_scale, ("vmax", "raw"))
        _choice("staleness", self.staleness, ("global", "context"))
        _in_range("vi_tol", self.vi_tol, 0.0, 1.0, low_open=True)
        _integer("vi_max_sweeps", self.vi_max_sweeps, 1, 100_000)


@dataclass(frozen=True)
class RmaxParams(Params):
    """R-MAX (Brafman & Tennenholtz 2002), discounted form; greedy with a seeded tie-break.

    m: visits from which a pair is known (below it, Q = optimism * Vmax).
    freeze_known: canonical R-MAX stops counting a pair once it is known.
    optimism: the value of an unknown pair as a share of Vmax (1: the literature's Vmax; 0.1 in
        the office mission: the largest one-step reward, a tighter bound on a short negotiation).
    """

    algorithm: ClassVar[str] = "rmax"
    m: int = 2
    freeze_known: bool = False
    optimism: float = 1.0
    vi_tol: float = 1e-8
    vi_max_sweeps: int = 500

    def __post_init__(self) -> None:
        _integer("m", self.m, 1, 1_000_000)
        _flag("freeze_known", self.freeze_known)
        _in_range("optimism", self.optimism, 0.0, 1.0, low_open=True)
        _in_range("vi_tol", self.vi_tol, 0.0, 1.0, low_open=True)
        _integer("vi_max_sweeps", self.vi_max_sweeps, 1, 100_000)


@dataclass(frozen=True)
class QLearningParams(Params):
    """Tabular Q-learning (Watkins 1989) over the same states.

    q0: initial Q; alpha_min: step size floor, alpha = max(alpha_min, 1 / n(s, a)).
    exploration: "epsilon" (epsilon_e = max(epsilon_min, epsilon0 * epsilon_decay^(e-1)) over the
        user's episode index e) or "boltzmann" (softmax of Q / temperature).
    """

    algorithm: ClassVar[str] = "qlearning"
    q0: float = 0.0
    alpha_min: float = 0.1
    exploration: str = "epsilon"
    epsilon0: float = 0.3
    epsilon_decay: float = 0.93
    epsilon_min: float = 0.01
    temperature: float = 1.0

    def __post_init__(self) -> None:
        _in_range("q0", self.q0, -1e6, 1e6)
        _in_range("alpha_min", self.alpha_min, 0.0, 1.0, low_open=True)
        _choice("exploration", self.exploration, ("epsilon", "boltzmann"))
        _in_range("epsilon0", self.epsilon0, 0.0, 1.0)
        _in_range("epsilon_decay", self.epsilon_decay, 0.0, 1.0)
        _in_range("epsilon_min", self.epsilon_min, 0.0, 1.0)
        _in_range("temperature", self.temperature, 0.0, 1e6, low_open=True)


@dataclass(frozen=True)
class DtsParams(Params):
    """Discounted Thompson sampling over the negotiation MDP (our learner for drifting wishes).

    forgetting: per-pair discount lambda of the counts, n <- lambda * n + 1 (1 = no forgetting).
    prior_count: Dirichlet pseudo-count per possible successor of a human-facing action.
    reward_prior: prior mean of a pair's reward (a little below 0: an untried service is more
        likely wrong than right); reward_prior_count: its weight in samples.
    reward_sd: spread of one reward around its mean (the posterior's noise scale).
    samples: posterior models drawn per decision; the action distribution is their argmax share.
    i1_as_acceptance: a human-initiated episode in a context also counts as an accepted
        initiation there (the person wanted service in that context).
    change_alpha: significance level of the per-context change test on performed services
        (docs/method.md §8, "Adapting after a change"): when a run of rejected services in a
        context is less likely than change_alpha given that context's earlier answers, what the
        context learned about services starts over. 0 = no test.
    change_keep: the share of such a context's discounted counts kept when its test fires
        (0 = its service-facing pairs start over; its offers and other contexts are kept).
    change_on_questions: the change test also counts a detail question the person ended (a
        question about a service they no longer want) as a rejection.
    trust_answers: answers are truthful (docs/method.md §8, "Trusted answers"): doing as asked
        is expected to pay what an accepted service pays before it was ever tried; a detail
        question about a service nobody named is answered with prior chance 1/K; and a service
        the person named is followed by a detail question that is answered.
    """

    algorithm: ClassVar[str] = "dts"
    forgetting: float = 0.8
    prior_count: float = 0.25
    reward_prior: float = -1.0
    reward_prior_count: float = 1.0
    reward_sd: float = 1.0
    samples: int = 16
    i1_as_acceptance: bool = True
    change_alpha: float = 0.0
    change_keep: float = 0.0
    trust_answers: bool = False
    change_on_questions: bool = False
    vi_tol: float = 1e-8
    vi_max_sweeps: int = 500

    def __post_init__(self) -> None:
        _in_range("forgetting", self.forgetting, 0.0, 1.0, low_open=True)
        _in_range("change_alpha", self.change_alpha, 0.0, 0.5)
        _in_range("change_keep", self.change_keep, 0.0, 1.0, high_open=True)
        _in_range("prior_count", self.prior_count, 0.0, 1e3, low_open=True)
        _in_range("reward_prior", self.reward_prior, -1e3, 1e3)
        _in_range("reward_prior_count", self.reward_prior_count, 0.0, 1e3, low_open=True)
        _in_range("reward_sd", self.reward_sd, 0.0, 1e3, low_open=True)
        _integer("samples", self.samples, 1, 4096)
        _flag("i1_as_acceptance", self.i1_as_acceptance)
        _flag("trust_answers", self.trust_answers)
        _flag("change_on_questions", self.change_on_questions)
        _in_range("vi_tol", self.vi_tol, 0.0, 1.0, low_open=True)
        _integer("vi_max_sweeps", self.vi_max_sweeps, 1, 100_000)


@dataclass(frozen=True)
class DtsAdaptParams(DtsParams):
    """DTS that adapts after a change (docs/method.md §8, "Adapting after a change"): the same
    learner and parameters as ``dts``, with other defaults: slower forgetting (0.95), the change
    test at 0.05 counting ended detail questions too, and trusted answers. Its own algorithm
    name, so that learners stored as ``dts`` (whose parameters predate the new ones) keep their
    behaviour."""

    algorithm: ClassVar[str] = "dts-adapt"
    forgetting: float = 0.95
    change_alpha: float = 0.05
    change_on_questions: bool = True
    trust_answers: bool = True


@dataclass(frozen=True)
class DtsRoutineParams(DtsParams):
    """DTS with the person's routine per context (docs/method.md §8, "``dts-routine``"): the
    defaults of ``dts-adapt`` (slower forgetting, trusted answers) without its change test, and
    a routine per context, learned from the person's own answers, that steers the negotiation.

    routine: follow a trusted routine (the service and detail the person last took in the
        context, not refused since): infer its service and detail instead of drawing.
    ask_in_doubt: once the routine of a context was refused, ask (which service, then which
        detail) before guessing there again, until the person takes a service again.
    ask_unknown: where no routine is held yet, ask rather than guess.
    routine_offers: offer service where a trusted routine is held and the latest offer there
        was not turned down (elsewhere the posterior draws decide, as in DTS).
    offer_alpha: the routine of a context is dropped (the person no longer wants anything there)
        when the run of offers turned down there since the last one taken is less likely than
        offer_alpha given the context's earlier answers to offers (0: never dropped).
    """

    algorithm: ClassVar[str] = "dts-routine"
    forgetting: float = 0.95
    trust_answers: bool = True
    routine: bool = True
    ask_in_doubt: bool = True
    ask_unknown: bool = True
    routine_offers: bool = True
    offer_alpha: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        _flag("routine", self.routine)
        _flag("ask_in_doubt", self.ask_in_doubt)
        _flag("ask_unknown", self.ask_unknown)
        _flag("routine_offers", self.routine_offers)
        _in_range("offer_alpha", self.offer_alpha, 0.0, 0.5)


PARAMS: dict[str, type[Params]] = {
    cls.algorithm: cls
    for cls in (HriParams, RmaxParams, QLearningParams, DtsParams, DtsAdaptParams, DtsRoutineParams)
}
