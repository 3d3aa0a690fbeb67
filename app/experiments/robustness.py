"""The robustness suite (``attune experiment robustness``, docs/method.md §12, "Robustness"):
every learner on families of simulated people, each learner's reward as a share of the
oracle's in windows of events, with 95% intervals over seeds; the table, the CSV and the plot.

One task is one family with one seed: its persons meet the oracle and every learner, on the same
events and coin flips (``app.learning.population.run_family``).

*Share.* For a seed, a learner's share in a window is the sum of its rewards over the window's
events of all the seed's persons, divided by the oracle's sum over the same events. When the
oracle's sum is below :data:`MIN_ORACLE_REWARD` (nothing to earn there), the share of that seed
is undefined and left out; the tables say how many seeds each cell stands on.

*Interval.* Mean of the per-seed shares ± Student's t (95%, seeds − 1 degrees of freedom) times
their standard error.

The files, tables and figure are made with the report kit (``app.experiments.report``).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.learning.evaluation import Method
from app.learning.population import DEFAULT_EVENTS, FAMILIES, FamilyRun, change_event, run_family

from . import report
from .report import MIN_ORACLE_REWARD, interval_text, percent, rounded, window_heading
from .runner import _mission

if TYPE_CHECKING:
    from rich.console import Console

__all__ = [
    "CSV_COLUMNS",
    "DEFAULT_EVENTS",
    "DEFAULT_LEARNERS",
    "DEFAULT_PERSONS",
    "DEFAULT_SEEDS",
    "LEARNERS",
    "MIN_ORACLE_REWARD",
    "RULE",
    "SERVICE_DEFAULT",
    "TARGET_SECONDS",
    "WINDOWS",
    "RobustTask",
    "Window",
    "build_summary",
    "check_targets",
    "choose_default",
    "markdown",
    "plot_shares",
    "print_table",
    "run_robust_task",
    "tasks_for",
    "verdict_lines",
    "window_range",
    "write_csv",
    "write_report",
]

DEFAULT_SEEDS = 8
DEFAULT_PERSONS = 3
TARGET_SECONDS = 120.0  # the default suite must finish within this on 2 cores

LEARNERS: Mapping[str, Method] = {
    "rmax": Method("R-MAX", "rmax"),
    "qlearning": Method("Q-learning", "qlearning"),
    "hri": Method("HRI τ=0.01", "hri", {"tau": 0.01}),
    "hri-0.005": Method("HRI τ=0.005", "hri", {"tau": 0.005}),
    "dts": Method("DTS", "dts"),
    "dts-change": Method("DTS + change test α=0.01", "dts", {"change_alpha": 0.01}),
    "dts-change-0.05": Method("DTS + change test α=0.05", "dts", {"change_alpha": 0.05}),
    "dts-adapt": Method("DTS-adapt", "dts-adapt"),
}
"""The learners the suite can run, by the name ``--learners`` takes."""
DEFAULT_LEARNERS = ("rmax", "qlearning", "hri", "dts", "dts-adapt")
SERVICE_DEFAULT = "dts-adapt"
"""The suite's name of the learner new users of the service get (``LearnerSpec``'s default
algorithm, with that algorithm's default parameters): the learner the rule picks."""
REFERENCE = "dts"
"""The learner whose level before a change the default must keep (issue §3)."""
RULE = (
    "the default learner is the one with the highest mean share over all events, averaged "
    "over every family of the run; a tie (equal whole percentages) goes to the higher "
    "worst-family share over all events"
)
AFTER_TARGET, ALL_TARGET = 0.75, 0.85


@dataclass(frozen=True)
class Window:
    """A window of events: ``key`` (for files), ``label`` (for people)."""

    key: str
    label: str
    needs_change: bool


WINDOWS = (
    Window("first20", "first 20", False),
    Window("before30", "30 before the change", True),
    Window("after15", "15 after the change", True),
    Window("last30", "last 30", False),
    Window("all", "all", False),
)


def window_range(window: Window, n_events: int, change_at: int | None) -> tuple[int, int] | None:
    """Events ``start:stop`` (0-based, half-open) of ``window``; None when it does not apply
    (a window about the change in a family without one, or no event in it)."""
    if window.needs_change and change_at is None:
        return None
    if window.key == "first20":
        start, stop = 0, 20
    elif window.key == "before30":
        assert change_at is not None
        start, stop = change_at - 30, change_at
    elif window.key == "after15":
        assert change_at is not None
        start, stop = change_at, change_at + 15
    elif window.key == "last30":
        start, stop = n_events - 30, n_events
    else:
        start, stop = 0, n_events
    start, stop = max(0, start), min(n_events, stop)
    return (start, stop) if stop > start else None


@dataclass(frozen=True)
class RobustTask:
    """One family with one seed, for every learner."""

    family: str
    seed: int
    methods: tuple[Method, ...]
    n_persons: int
    n_events: int
    mission: str | None = None  # canonical JSON; None: the office mission

    def describe(self) -> str:
        return f"{self.family} / seed {self.seed}"


def tasks_for(
    families: Sequence[str],
    methods: Sequence[Method],
    seeds: int,
    n_persons: int,
    n_events: int,
    mission: str | None = None,
) -> list[RobustTask]:
    """Every family x seed, ordered family, seed."""
    return [
        RobustTask(f, s, tuple(methods), n_persons, n_events, mission)
        for f in families
        for s in range(seeds)
    ]


def run_robust_task(task: RobustTask) -> FamilyRun:
    """Do one task (in a worker process)."""
    methods = [(m.label, m.algorithm, dict(m.params)) for m in task.methods]
    return run_family(
        FAMILIES[task.family],
        task.seed,
        methods,
        _mission(task.mission),
        n_persons=task.n_persons,
        n_events=task.n_events,
    )


# -- the numbers ------------------------------------------------------------------------------


def build_summary(
    runs: Sequence[FamilyRun],
    families: Sequence[str],
    learners: Sequence[str],
    n_events: int,
    run_info: Mapping[str, Any],
) -> dict[str, Any]:
    """Every share as plain JSON data: per family, per learner, per window, the mean share, its
    95% interval, and the seeds it stands on."""
    out: dict[str, Any] = {
        "run": dict(run_info),
        "learners": list(learners),
        "windows": {},
        "share": "learner's reward / oracle's reward over the window's events of a seed's "
        "persons; mean over seeds",
        "interval": "95% CI of the mean over seeds (Student's t)",
        "min_oracle_reward": MIN_ORACLE_REWARD,
        "families": {},
    }
    change = change_event(n_events)
    for w in WINDOWS:
        rng = window_range(w, n_events, change)
        out["windows"][w.key] = {
            "label": w.label,
            "needs_change": w.needs_change,
            "events": None if rng is None else [rng[0] + 1, rng[1]],
        }
    for name in families:
        family = FAMILIES[name]
        mine = [r for r in runs if r.family == name]
        change_at = change if family.changes else None
        entry: dict[str, Any] = {
            "description": family.description,
            "change_at_event": None if change_at is None else change_at + 1,
            "seeds": len(mine),
            "oracle_reward_per_event": report.oracle_per_event([r.oracle for r in mine]),
            "learners": {},
        }
        for label in learners:
            cells: dict[str, Any] = {}
            for w in WINDOWS:
                rng = window_range(w, n_events, change_at)
                cells[w.key] = _cell(mine, label, rng)
            entry["learners"][label] = cells
        out["families"][name] = entry
    out["rule"] = choose_default(out)
    out["targets"] = check_targets(out)
    return out


def choose_default(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The rule (:data:`RULE`) applied to the learners of ``summary``: their ranking, best
    first, and the learner it picks (None when no learner has a share in every family)."""
    ranking = []
    for label in summary["learners"]:
        alls = [fam["learners"][label]["all"]["mean"] for fam in summary["families"].values()]
        if not alls or any(a is None for a in alls):
            continue
        ranking.append(
            {
                "learner": label,
                "mean_all": rounded(float(np.mean(alls))),
                "worst_all": rounded(min(alls)),
            }
        )
    ranking.sort(key=lambda r: (-round(100 * r["mean_all"]), -r["worst_all"]))
    return {
        "text": RULE,
        "ranking": ranking,
        "chosen": ranking[0]["learner"] if ranking else None,
        "service_default": LEARNERS[SERVICE_DEFAULT].label,
    }


def check_targets(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Issue §3's targets for the service's default learner, each met or missed (empty when it
    is not in the run): in every changing family, at least 75 % of the oracle's reward in the
    15 events after the change and no lower a share than DTS's in the 30 before it; in every
    family, at least 85 % over all events."""
    label = LEARNERS[SERVICE_DEFAULT].label
    reference = LEARNERS[REFERENCE].label
    if label not in summary["learners"]:
        return []
    out = []
    for name, fam in summary["families"].items():
        cells = fam["learners"][label]
        checks = [("all", f"≥ {100 * ALL_TARGET:.0f}%", ALL_TARGET)]
        if fam["change_at_event"] is not None:
            checks.insert(0, ("after15", f"≥ {100 * AFTER_TARGET:.0f}%", AFTER_TARGET))
            if reference in fam["learners"]:
                level = fam["learners"][reference]["before30"]["mean"]
                if level is not None:
                    checks.insert(
                        0, ("before30", f"≥ {reference}'s {percent(level)}%", round(level, 2))
                    )
        for key, text, bound in checks:
            mean = cells[key]["mean"]
            out.append(
                {
                    "family": name,
                    "window": key,
                    "learner": label,
                    "target": text,
                    "share": mean,
                    "met": mean is not None and round(mean, 2) >= bound,
                }
            )
    return out


def verdict_lines(summary: Mapping[str, Any]) -> list[str]:
    """The rule's pick and the targets, as plain lines (terminal and markdown alike)."""
    rule = summary.get("rule") or {}
    lines = [f"Rule: {rule.get('text', RULE)}."]
    ranking = rule.get("ranking") or []
    if ranking:
        lines.append(
            "Ranking (mean over families, all events; worst family): "
            + "; ".join(
                f"{r['learner']} {percent(r['mean_all'])}% (worst {percent(r['worst_all'])}%)"
                for r in ranking
            )
            + "."
        )
        chosen = rule["chosen"]
        same = (
            "the service's default"
            if chosen == rule["service_default"]
            else (f"not the service's default ({rule['service_default']})")
        )
        lines.append(f"The rule picks {chosen}: {same}.")
    targets = summary.get("targets") or []
    if targets:
        met = sum(t["met"] for t in targets)
        lines.append(
            f"Issue §3 targets for the default learner ({targets[0]['learner']}): "
            f"{met} of {len(targets)} met."
        )
        for t in targets:
            share = "—" if t["share"] is None else f"{percent(t['share'])}%"
            window = summary["windows"][t["window"]]["label"]
            lines.append(
                f"  {t['family']}, {window}: {share} (target {t['target']}): "
                f"{'met' if t['met'] else 'MISSED'}"
            )
    return lines


def _cell(runs: Sequence[FamilyRun], label: str, rng: tuple[int, int] | None) -> dict[str, Any]:
    """One family x learner x window: shares per seed, their mean and interval."""
    if rng is None:
        return {
            "applicable": False,
            "events": None,
            "mean": None,
            "ci95": None,
            "seeds": 0,
            "undefined_seeds": 0,
            "per_seed": [],
        }
    start, stop = rng
    shares = [
        report.share(
            float(r.learners[label][:, start:stop].sum()), float(r.oracle[:, start:stop].sum())
        )
        for r in runs
    ]
    return {"applicable": True, **report.interval_cell(shares, rng)}


# -- text -------------------------------------------------------------------------------------


def _pct(cell: Mapping[str, Any]) -> str:
    """``62% [55, 69]``; blank when the window does not apply, ``—`` when no seed defines it."""
    return interval_text(cell) if cell["applicable"] else ""


def markdown(summary: Mapping[str, Any]) -> str:
    """robustness.md: one table, a row per family and learner, a column per window."""
    run = summary["run"]
    keys = list(summary["windows"])
    intro = (
        f"{run['seeds']} seeds × {run['persons']} persons per family, {run['events']} events "
        f"per person; the changing families change at event {run['change_at_event']}. Each "
        "cell: mean share over seeds [95% CI, Student's t]; blank: the family has no change. "
        f"A seed whose oracle earned less than {MIN_ORACLE_REWARD:g} in a window has no share "
        "there (noted below the table). The oracle knows every need: it initiates, infers "
        "and performs when a need exists and the person is available, and passes otherwise. "
        f"Ran in {run['seconds']:.1f} s on {run['workers']} worker processes."
    )
    rows = []
    notes = []
    for name, fam in summary["families"].items():
        for i, (label, cells) in enumerate(fam["learners"].items()):
            rows.append([f"**{name}**" if i == 0 else "", label, *(_pct(cells[k]) for k in keys)])
            for k in keys:
                if cells[k]["undefined_seeds"]:
                    notes.append(
                        f"- {name}, {label}, {summary['windows'][k]['label']}: "
                        f"{cells[k]['undefined_seeds']} seed(s) without a share."
                    )
    header = ["Family", "Learner", *(window_heading(summary, k) for k in keys)]
    lines = [
        "# Robustness: reward as a share of the oracle's",
        "",
        intro + report.mission_sentence(run),
        "",
        report.markdown_table(header, rows, left=2),
        *report.family_lines(summary),
    ]
    if notes:
        lines += ["", "Seeds without a share:", "", *dict.fromkeys(notes)]
    lines += report.verdict_section("The default learner", verdict_lines(summary))
    return "\n".join(lines) + "\n"


def print_table(summary: Mapping[str, Any], console: Console) -> None:
    """The table for the terminal (whole, whatever its width)."""
    keys = list(summary["windows"])
    table = report.terminal_table(
        "Robustness: reward as a share of the oracle's (mean [95% CI] over seeds)"
    )
    table.add_column("Family", no_wrap=True)
    table.add_column("Learner", no_wrap=True)
    for k in keys:
        table.add_column(window_heading(summary, k), justify="right", no_wrap=True)
    for name, fam in summary["families"].items():
        for i, (label, cells) in enumerate(fam["learners"].items()):
            table.add_row(
                name if i == 0 else "",
                label,
                *(_pct(cells[k]) for k in keys),
                end_section=i == len(fam["learners"]) - 1,
            )
    report.print_whole(console, table, verdict_lines(summary))


CSV_COLUMNS = (
    "family",
    "learner",
    "window",
    "first_event",
    "last_event",
    "seeds",
    "undefined_seeds",
    "share_mean",
    "ci95_low",
    "ci95_high",
)


def write_csv(summary: Mapping[str, Any], path: Path) -> int:
    """robustness.csv: one row per family x learner x window; blank cells where the window does
    not apply. Returns the rows written."""
    return report.write_csv(path, CSV_COLUMNS, _csv_rows(summary))


def _csv_rows(summary: Mapping[str, Any]) -> Iterator[tuple[object, ...]]:
    for name, fam in summary["families"].items():
        for label, cells in fam["learners"].items():
            for key, cell in cells.items():
                events = cell["events"] or ("", "")
                ci = cell["ci95"] or ("", "")
                yield (
                    name,
                    label,
                    key,
                    events[0],
                    events[1],
                    cell["seeds"] if cell["applicable"] else "",
                    cell["undefined_seeds"] if cell["applicable"] else "",
                    "" if cell["mean"] is None else cell["mean"],
                    *ci,
                )


def plot_shares(summary: Mapping[str, Any], path: Path) -> None:
    """robustness.png: one heatmap per window, families x learners, mean share in each cell
    (grey: the window does not apply)."""
    from matplotlib.colors import Normalize

    keys = list(summary["windows"])
    families = list(summary["families"])
    learners = list(summary["learners"])
    fig = report.figure(3.2 * len(keys) + 1.5, 0.45 * len(families) + 2.2)
    axes = fig.subplots(1, len(keys), sharey=True, squeeze=False)[0]
    norm = Normalize(0.0, 1.0)
    image = None
    for ax, key in zip(axes, keys, strict=True):
        grid = np.full((len(families), len(learners)), np.nan)
        for i, fam in enumerate(families):
            for j, label in enumerate(learners):
                mean = summary["families"][fam]["learners"][label][key]["mean"]
                if mean is not None:
                    grid[i, j] = mean
        ax.set_facecolor("0.85")
        image = ax.imshow(np.ma.masked_invalid(grid), cmap="viridis", norm=norm, aspect="auto")
        report.label_cells(ax, grid, percent, fontsize=8)
        ax.set_xticks(range(len(learners)), learners, rotation=45, ha="right", fontsize=8)
        ax.set_yticks(range(len(families)), families, fontsize=9)
        ax.set_title(window_heading(summary, key), fontsize=10)
    if image is not None:
        fig.colorbar(image, ax=list(axes), shrink=0.8, label="share of the oracle's reward")
    run = summary["run"]
    fig.suptitle(
        f"Reward as a share of the oracle's, % (mean over {run['seeds']} seeds × "
        f"{run['persons']} persons; grey: no change in that family)",
        fontsize=11,
    )
    fig.savefig(path, format="png")


def write_report(summary: Mapping[str, Any], out: Path) -> list[Path]:
    """Write robustness.md, robustness.csv, robustness.png and summary.json into ``out``."""
    return report.write_report(
        summary, out, "robustness", markdown=markdown, table=write_csv, plot=plot_shares
    )
