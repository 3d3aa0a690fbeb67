"""What if (``attune experiment what-if``, docs/method.md §17): off-policy estimates of other
learners from one learner's logs, checked against those learners' true values.

*Protocol* (common random numbers). One trial is one fleet: ``persons`` simulated persons of one
robustness family (families taken in turn), each through ``events`` events. The *logging*
learner serves them and its decisions are logged (``app.learning.whatif.log_person``); every
*candidate* is replayed over each person's log (``replay``) and, separately, run on-policy
through the same persons, events and coin flips (``app.learning.population.run_learner``): its
*true value* is its mean reward per episode there. The fleet's first ``k`` events per person make
the smaller settings (``k * persons`` episodes per fleet), so every setting of a trial has the
same people.

*Per setting, estimator and candidate*, over trials: coverage (the share of trials whose 95 %
interval holds the true value; a trial that answered "not enough evidence" is counted apart, and
in a second figure as covering, since it claimed nothing), bias and RMSE of the estimate, the
interval's mean width, the effective sample size, the candidate's mass on actions the logger
never takes there (support).

*Ranking*: at the largest setting, every pair of arms (the logging learner's own value, read
from its logs, and each candidate) whose expected values (the mean of their true values over the
trials) differ by at least :data:`RANK_GAP`: the share of trials whose estimates order them so.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.learning.evaluation import Method
from app.learning.learners import make_learner
from app.learning.offpolicy import (
    DEFAULT_CLIP,
    DEFAULT_ESTIMATOR,
    ESTIMATORS,
    Estimate,
    estimate,
    on_policy,
)
from app.learning.population import FAMILIES, people, run_learner
from app.learning.space import space_for
from app.learning.whatif import log_person, replay_all, replay_values, steps_of

from . import report
from .report import rounded
from .runner import _mission

if TYPE_CHECKING:
    from rich.console import Console

__all__ = [
    "CANDIDATES",
    "COVERAGE_TARGET",
    "CSV_COLUMNS",
    "DEFAULT_CANDIDATES",
    "DEFAULT_FAMILIES",
    "DEFAULT_LOGGER",
    "DEFAULT_PERSONS",
    "DEFAULT_SIZES",
    "DEFAULT_TRIALS",
    "RANK_GAP",
    "RANK_TARGET",
    "TARGET_SECONDS",
    "TrialResult",
    "WhatIfTask",
    "build_summary",
    "check_targets",
    "markdown",
    "plot_coverage",
    "print_table",
    "run_trial",
    "tasks_for",
    "verdict_lines",
    "write_csv",
    "write_report",
]

DEFAULT_TRIALS = 200
DEFAULT_PERSONS = 10
DEFAULT_SIZES = (50, 200, 1000)  # episodes per fleet
DEFAULT_FAMILIES = ("individual", "home", "abrupt", "gradual", "noisy", "shy", "refusing")
COVERAGE_TARGET = 0.93
RANK_GAP = 0.1  # reward per episode
RANK_TARGET = 0.90
TARGET_SECONDS = 300.0
CONFIDENCE = 0.95
INTERVALS = ("bootstrap", "bernstein")

CANDIDATES: Mapping[str, Method] = {
    "hri": Method("HRI τ=0.01", "hri", {"tau": 0.01}),
    "hri-0.005": Method("HRI τ=0.005", "hri", {"tau": 0.005}),
    "hri-0.02": Method("HRI τ=0.02", "hri", {"tau": 0.02}),
    "hri-0.1": Method("HRI τ=0.1", "hri", {"tau": 0.1}),
    "dts": Method("DTS", "dts"),
    "dts-adapt": Method("DTS-adapt", "dts-adapt"),
    "dts-routine": Method("DTS-routine", "dts-routine"),
    "qlearning": Method("Q-learning", "qlearning"),
    "rmax": Method("R-MAX", "rmax"),
}
"""The learners the study can log under or estimate, by the name its options take."""
DEFAULT_LOGGER = "hri"
DEFAULT_CANDIDATES = ("hri-0.005", "hri-0.1", "dts")


@dataclass(frozen=True)
class WhatIfTask:
    """One trial: a fleet of ``persons`` of ``family`` for ``seed``."""

    family: str
    seed: int
    persons: int
    sizes: tuple[int, ...]
    logger: Method
    candidates: tuple[Method, ...]
    truth_runs: int = 2
    mission: str | None = None
    replay_value: bool = False

    def describe(self) -> str:
        return f"{self.family} / trial {self.seed}"


def tasks_for(
    trials: int,
    persons: int,
    sizes: Sequence[int],
    logger: Method,
    candidates: Sequence[Method],
    families: Sequence[str] = DEFAULT_FAMILIES,
    truth_runs: int = 2,
    mission: str | None = None,
    replay_value: bool = False,
) -> list[WhatIfTask]:
    """``trials`` fleets, the families taken in turn."""
    return [
        WhatIfTask(
            families[t % len(families)],
            t,
            persons,
            tuple(sizes),
            logger,
            tuple(candidates),
            truth_runs,
            mission,
            replay_value,
        )
        for t in range(trials)
    ]


@dataclass
class TrialResult:
    """One trial's numbers. ``truth[label][k]``: true value per episode at setting ``k``
    (episodes per fleet); ``logged[k]``: the logging learner's own value from its logs (an
    on-policy estimate) and its truth; ``found[(label, estimator, interval)][k]``: the
    estimate's plain dict (``Estimate.to_dict``); ``replayed[label][k]``, with
    ``replay_value``: the candidate's value as the replay teaches it (``replay_values``)."""

    family: str
    seed: int
    truth: dict[str, dict[int, float]]
    found: dict[str, dict[int, dict[str, Any]]]
    replayed: dict[str, dict[int, float]] = field(default_factory=dict)


def _seq(*words: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(w) for w in words]))


def _key(label: str) -> int:
    return zlib.crc32(label.encode())


def found_key(label: str, estimator: str, interval: str) -> str:
    return f"{label}|{estimator}|{interval}"


def run_trial(task: WhatIfTask) -> TrialResult:
    """Log, replay, estimate and measure the truth for one fleet (in a worker process)."""
    mission = _mission(task.mission)
    space = space_for(mission)
    family = FAMILIES[task.family]
    n_events = max(task.sizes) // task.persons
    persons, flips = people(family, mission, task.seed, task.persons, n_events)
    logs = []
    for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
        learner = make_learner(task.logger.algorithm, dict(task.logger.params), mission)
        logs.append(log_person(learner, person, u, _seq(task.seed, family.key, 5, i)))
    sizes = {k: k // task.persons for k in task.sizes}

    def true_values(m: Method) -> dict[int, float]:
        """``m``'s mean reward per episode on-policy, over ``truth_runs`` runs of its own."""
        rows = []
        for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
            runs = []
            for r in range(task.truth_runs):
                fresh = make_learner(m.algorithm, dict(m.params), mission)
                rng = _seq(task.seed, family.key, 7, i, _key(m.label), r)
                runs.append(run_learner(fresh, person, u, rng))
            rows.append(np.mean(runs, axis=0))
        rewards = np.stack(rows)
        return {k: float(rewards[:, :e].mean()) for k, e in sizes.items()}

    truth: dict[str, dict[int, float]] = {task.logger.label: true_values(task.logger)}
    found: dict[str, dict[int, dict[str, Any]]] = {}
    boot = _seq(task.seed, family.key, 9)
    for k, e in sizes.items():
        steps = steps_of(logs, [_identity(log) for log in logs], space.actions_of, events=e)
        for interval in INTERVALS:
            found.setdefault(found_key(task.logger.label, "logged", interval), {})[k] = (
                on_policy(steps, interval=interval, rng=boot, reward_range=_range(mission))
            ).to_dict()
    # Each person's log replayed into every candidate at once: candidates that learn alike
    # (HRI at other temperatures) learn once (replay_all).
    by_person = [
        replay_all(
            log,
            [make_learner(m.algorithm, dict(m.params), mission) for m in task.candidates],
            [_seq(task.seed, family.key, 6, i, _key(m.label)) for m in task.candidates],
        )
        for i, log in enumerate(logs)
    ]
    replayed: dict[str, dict[int, float]] = {}
    for c, m in enumerate(task.candidates):
        replays = [person[c] for person in by_person]
        truth[m.label] = true_values(m)
        if task.replay_value:
            rows = np.stack(
                [
                    replay_values(
                        log,
                        make_learner(m.algorithm, dict(m.params), mission),
                        person,
                        u,
                        _seq(task.seed, family.key, 8, i, _key(m.label)),
                    )
                    for i, (log, person, u) in enumerate(zip(logs, persons, flips, strict=True))
                ]
            )
            replayed[m.label] = {k: float(rows[:, :e].mean()) for k, e in sizes.items()}
        for k, e in sizes.items():
            steps = steps_of(logs, replays, space.actions_of, events=e)
            for estimator in ESTIMATORS:
                for interval in INTERVALS:
                    result: Estimate = estimate(
                        steps,
                        estimator,
                        interval=interval,
                        confidence=CONFIDENCE,
                        rng=boot,
                        reward_range=_range(mission),
                    )
                    found.setdefault(found_key(m.label, estimator, interval), {})[k] = (
                        result.to_dict()
                    )
    return TrialResult(task.family, task.seed, truth, found, replayed)


def _identity(log: Any) -> Any:
    """The logging learner "replayed" as itself: its own probabilities, full support, no model
    (only its rewards matter to an on-policy estimate)."""
    from app.learning.whatif import Replayed

    n = log.n_steps
    return Replayed(np.ones(n), np.zeros(n), np.zeros(n), np.zeros(n))


MAX_VISIBLE_STEPS = 4  # a negotiation has at most four visible steps, each after a silent one


def _range(mission: Any) -> tuple[float, float]:
    """A sure range of an episode's total reward: every step at the worst or the best a step
    can earn (loose, as a range for a bound that holds always must be)."""
    space = space_for(mission)
    rewards = mission.rewards
    silent = space.silent_reward[space.silent]
    worst = min(rewards.negative, rewards.query, 0.0) + min(0.0, float(silent.min()))
    best = rewards.max_step + max(0.0, float(silent.max()))
    return MAX_VISIBLE_STEPS * worst, MAX_VISIBLE_STEPS * best


# -- the numbers ------------------------------------------------------------------------------


def _cell(pairs: Sequence[tuple[Mapping[str, Any], float]]) -> dict[str, Any]:
    """Coverage, bias, RMSE, width, ESS and support of (estimate, truth) pairs over trials."""
    answered = [(f, t) for f, t in pairs if f["enough"]]
    errors = np.asarray([f["value"] - t for f, t in answered], dtype=np.float64)
    covered = sum(1 for f, t in answered if f["low"] <= t <= f["high"])
    n = len(pairs)

    def mean(values: Sequence[float]) -> float | None:
        return rounded(float(np.mean(values))) if len(values) else None

    return {
        "trials": n,
        "answered": len(answered),
        "coverage": rounded(covered / len(answered)) if answered else None,
        "coverage_or_silent": rounded((covered + n - len(answered)) / n) if n else None,
        "bias": rounded(float(errors.mean())) if len(errors) else None,
        "rmse": rounded(float(np.sqrt((errors**2).mean()))) if len(errors) else None,
        "width": mean([f["high"] - f["low"] for f, _ in answered]),
        "ess": mean([f["ess"] for f, _ in pairs]),
        "unsupported": mean([f["unsupported_mean"] for f, _ in pairs]),
        "weight_mean": mean([f["weight_mean"] for f, _ in pairs]),
        "truth": mean([t for _, t in pairs]),
    }


def _flat(found: Mapping[str, Any]) -> dict[str, Any]:
    """An estimate's dict with its interval flattened into low and high."""
    interval = found.get("interval") or {}
    return {
        "value": found.get("value"),
        "low": interval.get("low"),
        "high": interval.get("high"),
        "enough": bool(found.get("enough")),
        "ess": found.get("ess", 0.0),
        "unsupported_mean": found.get("unsupported_mean", 0.0),
        "weight_mean": found.get("weight_mean", 1.0),
    }


def build_summary(
    results: Sequence[TrialResult],
    logger: Method,
    candidates: Sequence[Method],
    sizes: Sequence[int],
    info: Mapping[str, Any],
) -> dict[str, Any]:
    """Every setting's cells, the ranking, the targets and the run's facts."""
    cells: list[dict[str, Any]] = []
    arms = [(logger.label, "logged"), *((m.label, e) for m in candidates for e in ESTIMATORS)]
    for k in sizes:
        for label, estimator in arms:
            for interval in INTERVALS:
                pairs = [
                    (_flat(r.found[found_key(label, estimator, interval)][k]), r.truth[label][k])
                    for r in results
                ]
                cells.append(
                    {
                        "episodes": k,
                        "arm": label,
                        "estimator": estimator,
                        "interval": interval,
                        "logger": label == logger.label,
                        **_cell(pairs),
                    }
                )
    summary: dict[str, Any] = {
        "study": "what-if",
        "logger": logger.label,
        "candidates": [m.label for m in candidates],
        "sizes": list(sizes),
        "default_estimator": DEFAULT_ESTIMATOR,
        "clip": DEFAULT_CLIP,
        "confidence": CONFIDENCE,
        "cells": cells,
        "ranking": _ranking(results, logger, candidates, max(sizes)),
        "approximation": _approximation(results, candidates, sizes),
        "run": dict(info),
    }
    summary["targets"] = check_targets(summary)
    return summary


def _approximation(
    results: Sequence[TrialResult], candidates: Sequence[Method], sizes: Sequence[int]
) -> list[dict[str, Any]]:
    """With ``replay_value``, per setting and candidate, means over the trials: the truth,
    the replay's value (what the estimates aim at) and the approximation (replay value -
    truth); then over the trials the default estimator answered, the same two and the
    estimate's own error against the replay's value, so that over those trials its bias
    against the truth is the approximation plus its own error. Empty without."""
    out: list[dict[str, Any]] = []

    def mean(values: Sequence[float]) -> float | None:
        return rounded(float(np.mean(values))) if len(values) else None

    for k in sizes:
        for m in candidates:
            had = [r for r in results if m.label in r.replayed]
            if not had:
                continue
            answered = [
                (f, r)
                for r in had
                if (f := _flat(r.found[found_key(m.label, DEFAULT_ESTIMATOR, "bootstrap")][k]))[
                    "enough"
                ]
            ]
            truth = [r.truth[m.label][k] for r in had]
            value = [r.replayed[m.label][k] for r in had]
            a_truth = [r.truth[m.label][k] for _, r in answered]
            a_value = [r.replayed[m.label][k] for _, r in answered]
            out.append(
                {
                    "episodes": k,
                    "arm": m.label,
                    "trials": len(had),
                    "truth": mean(truth),
                    "replay_value": mean(value),
                    "approximation": mean([v - t for v, t in zip(value, truth, strict=True)]),
                    "answered": len(answered),
                    "answered_truth": mean(a_truth),
                    "answered_replay_value": mean(a_value),
                    "estimator_error": mean(
                        [f["value"] - v for (f, _), v in zip(answered, a_value, strict=True)]
                    ),
                    "covers_replay_value": mean(
                        [
                            float(f["low"] <= v <= f["high"])
                            for (f, _), v in zip(answered, a_value, strict=True)
                        ]
                    ),
                }
            )
    return out


def _approximation_lines(summary: Mapping[str, Any]) -> list[str]:
    rows = summary.get("approximation") or []
    if not rows:
        return []
    lines = [
        "The replay's approximation (--replay-value): per setting and candidate, over all trials "
        "the truth and the value of the candidate as the replay teaches it (what the estimates "
        "aim at), with their difference; over the trials the "
        f"{summary['default_estimator']} estimate answered, the same two, the estimate's own "
        "error against the replay's value and how often its interval holds it:"
    ]
    for row in rows:
        lines.append(
            f"{row['episodes']} {row['arm']}: truth {_num(row['truth'])}, replay value "
            f"{_num(row['replay_value'])} ({_num(row['approximation'], signed=True)}); "
            f"of the {row['answered']} answered: truth {_num(row['answered_truth'])}, replay "
            f"value {_num(row['answered_replay_value'])}, estimate "
            f"{_num(row['estimator_error'], signed=True)} from it, interval holds it "
            f"{_pct(row['covers_replay_value'])}"
        )
    return lines


def _ranking(
    results: Sequence[TrialResult], logger: Method, candidates: Sequence[Method], k: int
) -> dict[str, Any]:
    """Per estimator, at ``k`` episodes, how often the estimates order two arms (the logging
    learner, read from its logs, and each candidate) as they are in expectation, where they
    are RANK_GAP or more apart.

    "Apart" is judged per family of people: an arm may serve one kind of people better and
    another worse (DTS and HRI swap places for people who refuse), so a fleet is ranked against
    its own family's expectation (the mean over the family's trials of the two arms' true
    values; one trial's truths carry the noise of a few runs), not against the mean over
    families it does not belong to. Two arms are apart in a family when that mean differs by
    RANK_GAP or more and by twice its standard error or more (the family's trials show the
    order; with one trial, its truths alone). A pair gives a row per direction: the families
    where one arm is better so, the share of their trials whose estimates put the pair in that
    order (``ordered``; a trial where an arm had not enough evidence does not order the pair: it
    is counted apart, ``silent``), the share whose own truths do (``truth``, ties a half), and
    the same per family (``families``)."""
    arms = [logger.label, *(m.label for m in candidates)]
    out: dict[str, Any] = {"episodes": k, "gap": RANK_GAP, "pairs": []}
    by_family: dict[str, list[TrialResult]] = {}
    for r in results:
        by_family.setdefault(r.family, []).append(r)
    out["families"] = list(by_family)

    def value(r: TrialResult, label: str, estimator: str) -> float | None:
        kind = "logged" if label == logger.label else estimator
        f = _flat(r.found[found_key(label, kind, "bootstrap")][k])
        return float(f["value"]) if f["enough"] and f["value"] is not None else None

    def shares(trials: Sequence[TrialResult], better: str, worse: str) -> dict[str, Any]:
        sign = [np.sign(r.truth[better][k] - r.truth[worse][k]) for r in trials]
        row: dict[str, Any] = {
            "truth": {
                "trials": len(trials),
                "ordered": rounded(float(np.mean([(x + 1) / 2 for x in sign]))),
            }
        }
        for estimator in ESTIMATORS:
            right = silent = 0
            for r in trials:
                vb, vw = value(r, better, estimator), value(r, worse, estimator)
                if vb is None or vw is None:
                    silent += 1
                else:
                    right += vb > vw
            answered = len(trials) - silent
            row[estimator] = {
                "trials": answered,
                "silent": silent,
                "ordered": rounded(right / answered) if answered else None,
            }
        return row

    for i, a in enumerate(arms):
        for b in arms[i + 1 :]:
            ways: dict[tuple[str, str], list[tuple[str, float]]] = {}
            for family, trials in by_family.items():
                gaps = np.asarray([r.truth[a][k] - r.truth[b][k] for r in trials])
                gap = float(gaps.mean())
                # apart by RANK_GAP, and by twice the standard error of the family's mean gap
                # (a few fleets of near twins can be RANK_GAP apart by the truths' noise alone)
                se = float(gaps.std(ddof=1) / np.sqrt(len(gaps))) if len(gaps) > 1 else 0.0
                if abs(gap) >= max(RANK_GAP, 2 * se):
                    ways.setdefault((a, b) if gap > 0 else (b, a), []).append((family, gap))
            for (better, worse), families in ways.items():
                trials = [r for family, _ in families for r in by_family[family]]
                gap = float(np.mean([r.truth[better][k] - r.truth[worse][k] for r in trials]))
                row: dict[str, Any] = {"better": better, "worse": worse, "gap": rounded(gap)}
                row.update(shares(trials, better, worse))
                row["families"] = [
                    {
                        "family": family,
                        "gap": rounded(abs(g)),
                        **shares(by_family[family], better, worse),
                    }
                    for family, g in families
                ]
                out["pairs"].append(row)
    return out


def _default_cells(summary: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    return [
        c
        for c in summary["cells"]
        if not c["logger"]
        and c["estimator"] == summary["default_estimator"]
        and c["interval"] == "bootstrap"
    ]


def check_targets(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The issue's targets, met or missed: per setting, the coverage of the default estimator's
    95 % bootstrap interval over every candidate's answered trials (a trial that said "not
    enough evidence" claimed nothing); at the largest setting, the ranking of arms
    RANK_GAP-3 RANK_GAP apart whose estimates were both given."""
    out: list[dict[str, Any]] = []
    cells = _default_cells(summary)
    for k in summary["sizes"]:
        mine = [c for c in cells if c["episodes"] == k]
        answered = sum(c["answered"] for c in mine)
        covered = sum(round((c["coverage"] or 0.0) * c["answered"]) for c in mine)
        cov = rounded(covered / answered) if answered else None
        out.append(
            {
                "target": f"coverage ≥ {COVERAGE_TARGET:.0%} at {k} episodes per fleet "
                f"({answered} answers of {sum(c['trials'] for c in mine)})",
                "value": cov,
                "met": cov is not None and cov >= COVERAGE_TARGET,
            }
        )
    default = summary["default_estimator"]
    for pair in summary["ranking"]["pairs"]:
        cell = pair[default]
        value = cell["ordered"]
        out.append(
            {
                "target": f"ranked right ≥ {RANK_TARGET:.0%}: {pair['worse']} below "
                f"{pair['better']} (worse by {pair['gap']:.2f}"
                f"{_families_words(summary, pair)}) at "
                f"{summary['ranking']['episodes']} episodes ({cell['trials']} trials, "
                f"{cell['silent']} with not enough evidence)",
                "value": value,
                "met": value is not None and value >= RANK_TARGET,
            }
        )
    return out


def _families_words(summary: Mapping[str, Any], pair: Mapping[str, Any]) -> str:
    """Where a ranked pair holds: "" in every family of the run, else the families named."""
    names = [f["family"] for f in pair.get("families", ())]
    if not names or set(names) == set(summary["ranking"].get("families", ())):
        return ""
    return ", for " + ", ".join(names)


# -- words, tables, files ----------------------------------------------------------------------


def _num(x: float | None, digits: int = 2, *, signed: bool = False) -> str:
    if x is None:
        return "—"
    return f"{x:+.{digits}f}" if signed else f"{x:.{digits}f}"


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.0f}%"


HEADER = (
    "episodes",
    "arm",
    "estimator",
    "interval",
    "coverage",
    "answered",
    "bias",
    "RMSE",
    "width",
    "ESS",
    "unsupported",
    "weights",
    "truth",
)


def _rows(summary: Mapping[str, Any]) -> list[list[str]]:
    return [
        [
            str(c["episodes"]),
            c["arm"],
            c["estimator"]
            + (" (default)" if c["estimator"] == summary["default_estimator"] else ""),
            c["interval"],
            _pct(c["coverage"]),
            f"{c['answered']}/{c['trials']}",
            _num(c["bias"], signed=True),
            _num(c["rmse"]),
            _num(c["width"]),
            _num(c["ess"], 0),
            _pct(c["unsupported"]),
            _num(c["weight_mean"]),
            _num(c["truth"]),
        ]
        for c in summary["cells"]
    ]


def verdict_lines(summary: Mapping[str, Any]) -> list[str]:
    lines = [
        f"{'met' if t['met'] else 'MISSED'}: {t['target']} — "
        + (_pct(t["value"]) if t["value"] is not None else "no answer")
        for t in summary["targets"]
    ]
    for pair in summary["ranking"]["pairs"]:
        lines.append(
            f"{pair['worse']} below {pair['better']}{_families_words(summary, pair)}: "
            + ", ".join(
                f"{estimator} {_pct(pair[estimator]['ordered'])} of {pair[estimator]['trials']}"
                for estimator in ESTIMATORS
            )
            + (
                f"; the fleets' own truths {_pct(pair['truth']['ordered'])} of "
                f"{pair['truth']['trials']}"
                if "truth" in pair
                else ""
            )
        )
    if not summary["ranking"]["pairs"]:
        lines.append(f"no two arms' expected values differ by {RANK_GAP} or more: no ranking")
    return lines


FAMILY_HEADER = ("family", "worse", "better", "gap", "truths", *ESTIMATORS)


def _family_rows(summary: Mapping[str, Any]) -> list[list[str]]:
    return [
        [
            f["family"],
            pair["worse"],
            pair["better"],
            _num(f["gap"]),
            f"{_pct(f['truth']['ordered'])} of {f['truth']['trials']}",
            *(
                f"{_pct(f[estimator]['ordered'])} of {f[estimator]['trials']}"
                for estimator in ESTIMATORS
            ),
        ]
        for pair in summary["ranking"]["pairs"]
        for f in pair.get("families", ())
    ]


def markdown(summary: Mapping[str, Any]) -> str:
    run = summary["run"]
    parts = [
        "# What if: off-policy estimates against the truth",
        "",
        f"Logged under **{summary['logger']}**; candidates: {', '.join(summary['candidates'])}. "
        f"{run.get('trials')} trials (fleets of {run.get('persons')} persons, families "
        f"{', '.join(run.get('families', []))} in turn); settings of "
        f"{', '.join(str(k) for k in summary['sizes'])} episodes per fleet. Default estimator: "
        f"{summary['default_estimator']}, weights clipped at {summary['clip']}; 95 % intervals.",
        "",
        report.markdown_table(HEADER, _rows(summary), left=4),
        "",
        *report.verdict_section("Targets", verdict_lines(summary)),
    ]
    by_family = _family_rows(summary)
    if by_family:
        parts += [
            "",
            "## Ranking by family",
            "",
            f"At {summary['ranking']['episodes']} episodes, per family of people: the pairs "
            f"{RANK_GAP} or more apart in that family's expectation, how far apart, how often "
            "the family's fleets' own truths order them so, and how often each estimator does "
            "(of the fleets it gave both values).",
            "",
            report.markdown_table(FAMILY_HEADER, by_family, left=3),
        ]
    approximation = _approximation_lines(summary)
    if approximation:
        parts += ["", "## The replay's approximation", "", approximation[0], ""]
        parts += [f"- {line}" for line in approximation[1:]]
    return "\n".join(parts) + "\n"


def print_table(summary: Mapping[str, Any], console: Console) -> None:
    table = report.terminal_table(
        f"What if: logged under {summary['logger']}, {summary['run'].get('trials')} trials"
    )
    for name in HEADER:
        table.add_column(
            name, justify="left" if name in ("arm", "estimator", "interval") else "right"
        )
    for row in _rows(summary):
        table.add_row(*row)
    report.print_whole(console, table, [*verdict_lines(summary), *_approximation_lines(summary)])


CSV_COLUMNS = (
    "episodes",
    "arm",
    "estimator",
    "interval",
    "trials",
    "answered",
    "coverage",
    "coverage_or_silent",
    "bias",
    "rmse",
    "width",
    "ess",
    "unsupported",
    "weight_mean",
    "truth",
)


def _csv_rows(summary: Mapping[str, Any]) -> Iterator[tuple[object, ...]]:
    for c in summary["cells"]:
        yield tuple(c[name] for name in CSV_COLUMNS)


def write_csv(summary: Mapping[str, Any], path: Path) -> int:
    return report.write_csv(path, CSV_COLUMNS, _csv_rows(summary))


def plot_coverage(summary: Mapping[str, Any], path: Path) -> None:
    """Coverage (left) and RMSE (right) per setting, one line per candidate and estimator
    (bootstrap intervals), the coverage target dashed."""
    fig = report.figure(11, 4.2)
    left, right = fig.subplots(1, 2)
    sizes = summary["sizes"]
    for label in summary["candidates"]:
        for estimator in ESTIMATORS:
            cells = {
                c["episodes"]: c
                for c in summary["cells"]
                if c["arm"] == label
                and c["estimator"] == estimator
                and c["interval"] == "bootstrap"
            }
            style = "-" if estimator == summary["default_estimator"] else ":"
            name = f"{label}, {estimator}"
            for ax, key in ((left, "coverage"), (right, "rmse")):
                ys = [np.nan if cells[k][key] is None else cells[k][key] for k in sizes]
                ax.plot(sizes, ys, style, marker="o", label=name)
    left.axhline(COVERAGE_TARGET, color="grey", linestyle="--", linewidth=1)
    left.set_title("coverage of the 95 % interval")
    right.set_title("RMSE (reward per episode)")
    for ax in (left, right):
        ax.set_xscale("log")
        ax.set_xlim(min(sizes) / 1.25, max(sizes) * 1.25)  # also when no candidate had a value
        ax.set_xlabel("episodes per fleet")
        ax.set_xticks(sizes, [str(k) for k in sizes])
    left.set_ylim(0, 1.02)
    right.legend(fontsize=7, loc="upper right")
    fig.savefig(path, dpi=120, bbox_inches="tight")


def write_report(summary: Mapping[str, Any], out: Path) -> list[Path]:
    return report.write_report(
        summary, out, "whatif", markdown=markdown, table=write_csv, plot=plot_coverage
    )
