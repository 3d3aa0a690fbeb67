"""Newcomers and the fleet's prior (``attune experiment newcomers``, docs/method.md §16): what a
new resident earns when their learner starts from the prior of the other residents
(``app.learning.prior.population_prior``) rather than fresh; the table, the CSV, the plot and
the targets of the issue.

*Protocol* (leave-one-out, common random numbers). One task is one family with one seed: its
``residents`` persons (``app.learning.population.people``; in ``home`` they share most
routines) meet the oracle and every learner. Each learner runs **fresh** through each person,
with the generator the robustness suite gives that person and learner; that run is also the
person's fresh newcomer run. Then, for each person i, the prior is built from the final learners
of the *other* residents, and person i is run again from that prior, on the same events, coin
flips and learner generator as its fresh run: the two runs differ by the prior only.

*Share.* As in the robustness suite (``app.experiments.robustness``): per seed, the sum of a
learner's rewards over a window's events of all the seed's persons over the oracle's sum; a seed
whose oracle earned less than :data:`~app.experiments.robustness.MIN_ORACLE_REWARD` there has no
share. Cells are the mean over seeds with a 95 % interval (Student's t).

*Paired difference.* The runs are paired by seed (same people, same flips, same generators), so
"the prior is not worse" is decided on the per-seed differences ``prior share - fresh share``:
their mean and 95 % interval (Student's t, seeds - 1 degrees of freedom); the prior is *below
fresh beyond the intervals* when the interval's upper bound is below 0 (a paired t-test at 5 %,
two-sided, finds it lower).

The files, tables and figure are made with the report kit (``app.experiments.report``).
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.learning import Mission
from app.learning.evaluation import Method
from app.learning.learners import make_learner
from app.learning.population import (
    DEFAULT_EVENTS,
    FAMILIES,
    Family,
    people,
    run_learner,
    run_oracle,
)
from app.learning.prior import DEFAULT_STRENGTH, MIN_SUPPORT, population_prior
from app.learning.space import space_for
from app.learning.types import FloatArray

from . import report
from .report import MIN_ORACLE_REWARD, interval_text, percent, rounded, window_heading
from .runner import _mission

if TYPE_CHECKING:
    from rich.console import Console

__all__ = [
    "ARMS",
    "CSV_COLUMNS",
    "DEFAULT_EVENTS",
    "DEFAULT_FAMILIES",
    "DEFAULT_RESIDENTS",
    "DEFAULT_SEEDS",
    "DEFAULT_STRENGTH",
    "FIRST_TARGET",
    "MIN_SUPPORT",
    "SMOOTHING",
    "WINDOWS",
    "NewcomerRun",
    "NewcomerTask",
    "Span",
    "build_summary",
    "check_targets",
    "markdown",
    "newcomer_rewards",
    "plot_newcomers",
    "print_table",
    "run_newcomer_task",
    "span_range",
    "tasks_for",
    "verdict_lines",
    "write_csv",
    "write_report",
]

DEFAULT_SEEDS = 8
DEFAULT_RESIDENTS = 6  # a home's residents: each newcomer's prior has the other 5
DEFAULT_FAMILIES = ("home", "individual")
FIRST_TARGET = 0.80  # home, from the prior: the share of the oracle in the first 20 events
SMOOTHING = 11  # events in the plot's moving window (centred)
ARMS = ("fresh", "prior")


@dataclass(frozen=True)
class Span:
    """A window of events ``start:stop`` (0-based, half-open; ``stop`` None: to the end)."""

    key: str
    label: str
    start: int
    stop: int | None


WINDOWS = (
    Span("first20", "first 20", 0, 20),
    Span("early", "middle", 20, 100),
    Span("after100", "after 100", 100, None),
    Span("all", "all", 0, None),
)


def span_range(span: Span, n_events: int) -> tuple[int, int] | None:
    """Events ``start:stop`` of ``span`` in a run of ``n_events``; None when it holds none."""
    start = min(span.start, n_events)
    stop = n_events if span.stop is None else min(span.stop, n_events)
    return (start, stop) if stop > start else None


# -- the runs ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class NewcomerTask:
    """One family with one seed, for every learner, fresh and from the prior."""

    family: str
    seed: int
    methods: tuple[Method, ...]
    n_residents: int
    n_events: int
    strength: float = DEFAULT_STRENGTH
    min_support: int = MIN_SUPPORT
    mission: str | None = None  # canonical JSON; None: the office mission

    def describe(self) -> str:
        return f"{self.family} / seed {self.seed}"


@dataclass
class NewcomerRun:
    """Rewards per episode, shape (residents, events): the oracle's, and each learner's fresh
    and from the prior of the other residents."""

    family: str
    seed: int
    oracle: FloatArray
    fresh: dict[str, FloatArray]
    prior: dict[str, FloatArray]


def tasks_for(
    families: Sequence[str],
    methods: Sequence[Method],
    seeds: int,
    n_residents: int,
    n_events: int,
    *,
    strength: float = DEFAULT_STRENGTH,
    min_support: int = MIN_SUPPORT,
    mission: str | None = None,
) -> list[NewcomerTask]:
    """Every family x seed (0..seeds-1), ordered family, seed."""
    return [
        NewcomerTask(f, s, tuple(methods), n_residents, n_events, strength, min_support, mission)
        for f in families
        for s in range(seeds)
    ]


def run_newcomer_task(task: NewcomerTask) -> NewcomerRun:
    """Do one task (in a worker process)."""
    return newcomer_rewards(
        FAMILIES[task.family],
        task.seed,
        task.methods,
        _mission(task.mission),
        n_residents=task.n_residents,
        n_events=task.n_events,
        strength=task.strength,
        min_support=task.min_support,
    )


def _generator(seed: int, family: Family, person: int, label: str) -> np.random.Generator:
    """The learner's generator for ``person``: the robustness suite's (seed, family, person,
    learner), so the fresh runs are the suite's runs of these persons."""
    key = zlib.crc32(label.encode())
    return np.random.default_rng(np.random.SeedSequence([seed, family.key, 2, person, key]))


def newcomer_rewards(
    family: Family,
    seed: int,
    methods: Sequence[Method],
    mission: Mission,
    *,
    n_residents: int,
    n_events: int,
    strength: float = DEFAULT_STRENGTH,
    min_support: int = MIN_SUPPORT,
) -> NewcomerRun:
    """The protocol (the module's docstring) for one family and seed: the oracle, and every
    method fresh and from the leave-one-out prior, through the same persons and flips."""
    space = space_for(mission)
    persons, flips = people(family, mission, seed, n_residents, n_events)
    oracle = np.stack([run_oracle(space, p, u) for p, u in zip(persons, flips, strict=True)])
    fresh: dict[str, FloatArray] = {}
    prior: dict[str, FloatArray] = {}
    for method in methods:
        finals = []
        rows = []
        for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
            learner = make_learner(method.algorithm, method.params, mission)
            rows.append(run_learner(learner, person, u, _generator(seed, family, i, method.label)))
            finals.append(learner)
        fresh[method.label] = np.stack(rows)
        rows = []
        for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
            others = [f for j, f in enumerate(finals) if j != i]
            learner = population_prior(
                method.algorithm,
                method.params,
                mission,
                others,
                strength=strength,
                min_support=min_support,
            )
            rows.append(run_learner(learner, person, u, _generator(seed, family, i, method.label)))
        prior[method.label] = np.stack(rows)
    return NewcomerRun(family.name, seed, oracle, fresh, prior)


# -- the numbers ------------------------------------------------------------------------------


def _shares(
    runs: Sequence[NewcomerRun], arm: str, label: str, start: int, stop: int
) -> list[float]:
    """Per seed: the learner's reward over events start:stop of all persons / the oracle's."""
    return [
        report.share(
            float(getattr(r, arm)[label][:, start:stop].sum()), float(r.oracle[:, start:stop].sum())
        )
        for r in runs
    ]


def _curve(runs: Sequence[NewcomerRun], arm: str, label: str, n_events: int) -> list[float | None]:
    """Per event: the learner's reward over a centred window of :data:`SMOOTHING` events, over
    all seeds and persons, divided by the oracle's (None where the oracle earned too little)."""
    learner = sum(getattr(r, arm)[label].sum(axis=0) for r in runs)
    oracle = sum(r.oracle.sum(axis=0) for r in runs)
    half = SMOOTHING // 2
    out: list[float | None] = []
    for e in range(n_events):
        lo, hi = max(0, e - half), min(n_events, e + half + 1)
        o = float(np.sum(oracle[lo:hi]))
        out.append(rounded(float(np.sum(learner[lo:hi])) / o) if o >= MIN_ORACLE_REWARD else None)
    return out


def build_summary(
    runs: Sequence[NewcomerRun],
    families: Sequence[str],
    learners: Sequence[str],
    n_events: int,
    run_info: Mapping[str, Any],
) -> dict[str, Any]:
    """Every number as plain JSON data: per family, learner and window, the fresh and the
    prior's shares and their paired difference (mean, 95 % interval, per seed); the smoothed
    curves of the plot; the targets, met or missed."""
    out: dict[str, Any] = {
        "run": dict(run_info),
        "learners": list(learners),
        "arms": {
            "fresh": "a new learner",
            "prior": "a learner from the prior of the other "
            "residents of the seed (app.learning.prior.population_prior)",
        },
        "windows": {},
        "share": "learner's reward / oracle's reward over the window's events of a seed's "
        "persons; mean over seeds",
        "interval": "95% CI of the mean over seeds (Student's t)",
        "difference": "per seed: prior's share - fresh share; mean and 95% CI over seeds "
        "(paired; Student's t)",
        "min_oracle_reward": MIN_ORACLE_REWARD,
        "smoothing_events": SMOOTHING,
        "families": {},
    }
    for w in WINDOWS:
        rng = span_range(w, n_events)
        out["windows"][w.key] = {
            "label": w.label,
            "events": None if rng is None else [rng[0] + 1, rng[1]],
        }
    for name in families:
        mine = [r for r in runs if r.family == name]
        entry: dict[str, Any] = {
            "description": FAMILIES[name].description,
            "seeds": len(mine),
            "oracle_reward_per_event": report.oracle_per_event([r.oracle for r in mine]),
            "learners": {},
        }
        for label in learners:
            cells: dict[str, Any] = {"fresh": {}, "prior": {}, "difference": {}}
            for w in WINDOWS:
                rng = span_range(w, n_events)
                if rng is None:
                    continue
                fresh = _shares(mine, "fresh", label, *rng)
                prior = _shares(mine, "prior", label, *rng)
                cells["fresh"][w.key] = report.interval_cell(fresh, rng)
                cells["prior"][w.key] = report.interval_cell(prior, rng)
                cells["difference"][w.key] = report.interval_cell(
                    [p - f for p, f in zip(prior, fresh, strict=True)], rng
                )
            cells["curves"] = {arm: _curve(mine, arm, label, n_events) for arm in ARMS}
            entry["learners"][label] = cells
        out["families"][name] = entry
    out["targets"] = check_targets(out)
    return out


def check_targets(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The issue's targets, per learner, each met or missed:

    (a) ``home``: from the prior, at least :data:`FIRST_TARGET` of the oracle's reward in the
        first 20 events (the mean share, in whole percentages as printed);
    (b) ``individual``: the prior not below fresh beyond the intervals in the first 20 events
        and over all events;
    (c) every family: the prior not below fresh beyond the intervals after event 100.

    "Not below fresh beyond the intervals": the upper bound of the 95 % interval of the paired
    per-seed difference (prior - fresh) is at least 0. A target whose family or window is not in
    the run is left out.
    """
    out: list[dict[str, Any]] = []
    families = summary["families"]
    learners = summary["learners"]
    home = families.get("home")
    for label in learners if home is not None else ():
        cell = home["learners"][label]["prior"].get("first20")
        if cell is None:
            continue
        mean = cell["mean"]
        out.append(
            {
                "id": "a",
                "family": "home",
                "window": "first20",
                "learner": label,
                "target": f"from the prior ≥ {100 * FIRST_TARGET:.0f}% of the oracle",
                "share": mean,
                "difference": None,
                "ci95": None,
                "met": mean is not None and round(mean, 2) >= FIRST_TARGET,
            }
        )
    checks: list[tuple[str, str, str]] = []
    if "individual" in families:
        checks += [("b", "individual", "first20"), ("b", "individual", "all")]
    checks += [("c", name, "after100") for name in families]
    for target_id, name, key in checks:
        for label in learners:
            cells = families[name]["learners"][label]
            if key not in cells["difference"]:
                continue
            diff = cells["difference"][key]
            high = None if diff["ci95"] is None else diff["ci95"][1]
            out.append(
                {
                    "id": target_id,
                    "family": name,
                    "window": key,
                    "learner": label,
                    "target": "prior not below fresh (paired 95% CI of the difference reaches 0)",
                    "share": cells["prior"][key]["mean"],
                    "difference": diff["mean"],
                    "ci95": diff["ci95"],
                    "met": high is not None and high >= 0.0,
                }
            )
    return out


# -- text -------------------------------------------------------------------------------------


def _pct(cell: Mapping[str, Any] | None, *, signed: bool = False) -> str:
    """``62% [55, 69]`` (``+12 [5, 19]`` for a difference, in points); ``—`` without seeds;
    blank where the window holds no event."""
    return "" if cell is None else interval_text(cell, signed=signed)


_ROWS = (("fresh", "fresh"), ("prior", "prior"), ("difference", "prior − fresh (points)"))


def _rows(summary: Mapping[str, Any]) -> list[tuple[str, str, str, list[str]]]:
    """(family, learner, row name, cells): three rows per family and learner."""
    keys = list(summary["windows"])
    out = []
    for name, fam in summary["families"].items():
        for label, cells in fam["learners"].items():
            for arm, row in _ROWS:
                out.append(
                    (
                        name,
                        label,
                        row,
                        [_pct(cells[arm].get(k), signed=arm == "difference") for k in keys],
                    )
                )
    return out


def verdict_lines(summary: Mapping[str, Any]) -> list[str]:
    """The targets, met or missed, as plain lines (terminal and markdown alike)."""
    targets = summary.get("targets") or []
    if not targets:
        return ["No target applies to the families of this run."]
    met = sum(t["met"] for t in targets)
    lines = [
        f"Targets (issue §2): {met} of {len(targets)} met. (a) home, from the prior, "
        f"first 20 events ≥ {100 * FIRST_TARGET:.0f}% of the oracle; (b) individual, "
        "first 20 and all: the prior not below fresh; (c) every family, after event 100: "
        "the prior not below fresh. Not below: the upper bound of the paired 95% CI of "
        "the per-seed difference (prior − fresh) is ≥ 0."
    ]
    for t in targets:
        window = summary["windows"][t["window"]]["label"]
        verdict = "met" if t["met"] else "MISSED"
        if t["id"] == "a":
            share = "—" if t["share"] is None else f"{percent(t['share'])}%"
            lines.append(
                f"  ({t['id']}) {t['family']}, {t['learner']}, {window}: prior {share} "
                f"(target ≥ {100 * FIRST_TARGET:.0f}%): {verdict}"
            )
        else:
            diff = (
                "—"
                if t["difference"] is None
                else (f"{_pct({'mean': t['difference'], 'ci95': t['ci95']}, signed=True)} points")
            )
            lines.append(
                f"  ({t['id']}) {t['family']}, {t['learner']}, {window}: prior − fresh "
                f"{diff} (target: upper bound ≥ 0): {verdict}"
            )
    return lines


def markdown(summary: Mapping[str, Any]) -> str:
    """newcomers.md: one table (three rows per family and learner), the families, the targets."""
    run = summary["run"]
    keys = list(summary["windows"])
    intro = (
        f"{run['seeds']} seeds × {run['residents']} residents per family, {run['events']} "
        "events per person. Leave-one-out: each resident is run fresh, then again from the "
        "prior of the other residents' final learners (strength "
        f"{run['strength']:g}, at least {run['min_support']} contributors per pair) on the same "
        "events, coin flips and learner generator. Each cell: the share of the oracle's reward, "
        "mean over seeds [95% CI, Student's t]; the third row is the paired per-seed "
        "difference, in percentage points [95% CI]. A seed whose oracle earned less than "
        f"{MIN_ORACLE_REWARD:g} in a window has no share there. Ran in {run['seconds']:.1f} s "
        f"on {run['workers']} worker processes."
    )
    if run.get("cpu_seconds") is not None:
        intro = intro[:-1] + f" ({run['cpu_seconds']:.1f} s of CPU time)."
    rows = []
    last: tuple[str, str] | None = None
    for name, label, row, cells in _rows(summary):
        fam = f"**{name}**" if last is None or last[0] != name else ""
        learner = label if last != (name, label) else ""
        rows.append([fam, learner, row, *cells])
        last = (name, label)
    header = ["Family", "Learner", "Start", *(window_heading(summary, k) for k in keys)]
    lines = [
        "# Newcomers: fresh, and from the fleet's prior",
        "",
        intro + report.mission_sentence(run),
        "",
        report.markdown_table(header, rows, left=3),
        *report.family_lines(summary),
        *report.verdict_section("Targets", verdict_lines(summary)),
    ]
    return "\n".join(lines) + "\n"


def print_table(summary: Mapping[str, Any], console: Console) -> None:
    """The table and the targets for the terminal (whole, whatever its width)."""
    keys = list(summary["windows"])
    table = report.terminal_table(
        "Newcomers: share of the oracle's reward, fresh and from the fleet's "
        "prior (mean [95% CI] over seeds; difference in points, paired by seed)"
    )
    for heading in ("Family", "Learner", "Start"):
        table.add_column(heading, no_wrap=True)
    for k in keys:
        table.add_column(window_heading(summary, k), justify="right", no_wrap=True)
    rows = _rows(summary)
    last: tuple[str, str] | None = None
    for i, (name, label, row, cells) in enumerate(rows):
        end = i + 1 == len(rows) or rows[i + 1][1] != label or rows[i + 1][0] != name
        table.add_row(
            name if last is None or last[0] != name else "",
            label if last != (name, label) else "",
            row,
            *cells,
            end_section=end,
        )
        last = (name, label)
    report.print_whole(console, table, verdict_lines(summary))


CSV_COLUMNS = (
    "family",
    "learner",
    "start",
    "window",
    "first_event",
    "last_event",
    "seeds",
    "undefined_seeds",
    "mean",
    "ci95_low",
    "ci95_high",
)


def write_csv(summary: Mapping[str, Any], path: Path) -> int:
    """newcomers.csv: one row per family x learner x start (fresh, prior, difference) x window;
    shares as fractions of the oracle's (the difference too). Returns the rows written."""
    return report.write_csv(path, CSV_COLUMNS, _csv_rows(summary))


def _csv_rows(summary: Mapping[str, Any]) -> Iterator[tuple[object, ...]]:
    for name, fam in summary["families"].items():
        for label, cells in fam["learners"].items():
            for arm, _ in _ROWS:
                for key, cell in cells[arm].items():
                    ci = cell["ci95"] or ("", "")
                    yield (
                        name,
                        label,
                        arm,
                        key,
                        *cell["events"],
                        cell["seeds"],
                        cell["undefined_seeds"],
                        "" if cell["mean"] is None else cell["mean"],
                        *ci,
                    )


def plot_newcomers(summary: Mapping[str, Any], path: Path) -> None:
    """newcomers.png: one panel per family, the share of the oracle's reward per event
    (smoothed over :data:`SMOOTHING` events, over all seeds and persons) of every learner,
    fresh (dashed) and from the prior (solid); the first 20 events shaded."""
    families = list(summary["families"])
    learners = list(summary["learners"])
    fig = report.figure(5.2 * len(families) + 1.0, 4.4)
    axes = fig.subplots(1, len(families), sharey=True, squeeze=False)[0]
    colors = [f"C{i % 10}" for i in range(len(learners))]
    for ax, name in zip(axes, families, strict=True):
        fam = summary["families"][name]
        ax.axvspan(0.5, 20.5, color="0.92", zorder=0)
        if name == "home":
            ax.axhline(FIRST_TARGET, color="0.5", linewidth=0.8, linestyle=":")
            ax.text(
                21.5,
                FIRST_TARGET + 0.01,
                f"target in the first 20: {100 * FIRST_TARGET:.0f}%",
                fontsize=7,
                color="0.4",
                va="bottom",
            )
        for color, label in zip(colors, learners, strict=True):
            curves = fam["learners"][label]["curves"]
            for arm, style in (("fresh", "--"), ("prior", "-")):
                y = np.asarray([np.nan if v is None else v for v in curves[arm]])
                ax.plot(
                    np.arange(1, y.size + 1),
                    y,
                    style,
                    color=color,
                    linewidth=1.3,
                    label=f"{label}, {arm}",
                )
        ax.set_title(f"{name} ({fam['seeds']} seeds)", fontsize=10)
        ax.set_xlabel("event (grey: the first 20)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"share of the oracle's reward ({SMOOTHING}-event window)")
    axes[-1].legend(fontsize=7, loc="lower right", ncol=2)
    run = summary["run"]
    fig.suptitle(
        f"Newcomers: fresh (dashed) and from the other {run['residents'] - 1} "
        "residents' prior (solid)",
        fontsize=11,
    )
    fig.savefig(path, format="png")


def write_report(summary: Mapping[str, Any], out: Path) -> list[Path]:
    """Write newcomers.md, newcomers.csv, newcomers.png and summary.json into ``out``."""
    return report.write_report(
        summary, out, "newcomers", markdown=markdown, table=write_csv, plot=plot_newcomers
    )
