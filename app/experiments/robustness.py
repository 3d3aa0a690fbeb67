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

*The one-miss oracle* (``app.learning.population.run_one_miss``): the oracle, except that it
loses the first visit of each changed context after the change. The windows after the change
are also given as a share of it (``after15_bound``, ``after30_bound``).

*Changes detected.* Per family and learner, the changes decided for the persons (the learner's
own mechanism, or the profile's belief for a learner without one: ``app.learning.changes``)
counted against their true changes: caught, within how many visits, how late, and false alarms
per person per 500 events.

The files, tables and figure are made with the report kit (``app.experiments.report``).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.learning.evaluation import Method
from app.learning.population import (
    CAUGHT_TARGET,
    CAUGHT_VISITS,
    DEFAULT_EVENTS,
    DEFAULT_FAMILIES,
    EVENTS_PER_MONTH,
    FALSE_ALARMS_TARGET,
    FAMILIES,
    Detection,
    FamilyRun,
    change_event,
    run_family,
)

from . import report
from .report import MIN_ORACLE_REWARD, interval_text, percent, rounded, window_heading
from .runner import _mission

if TYPE_CHECKING:
    from rich.console import Console

__all__ = [
    "CAUGHT_VISITS",
    "CSV_COLUMNS",
    "DEFAULT_EVENTS",
    "DEFAULT_FAMILIES",
    "EVENTS_PER_MONTH",
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
    "dts-routine": Method("DTS-routine", "dts-routine"),
}
"""The learners the suite can run, by the name ``--learners`` takes."""
DEFAULT_LEARNERS = ("rmax", "qlearning", "hri", "dts", "dts-adapt", "dts-routine")
SERVICE_DEFAULT = "dts-routine"
"""The suite's name of the learner new users of the service get (``LearnerSpec``'s default
algorithm, with that algorithm's default parameters): the learner the rule picks."""
PREVIOUS = "dts-adapt"
"""The service's previous default: no family may be worse with the default by more than its
interval."""
RULE = (
    "the default learner is the one with the highest mean share over all events, averaged "
    "over every family of the run; a tie (equal whole percentages) goes to the higher "
    "worst-family share over all events"
)
BOUND_TARGET = 0.90  # of the one-miss oracle: 15 after a switch, 30 after a drift
BEFORE_TARGET = 0.90  # of the oracle, the 30 events before the change
ALL_TARGET = 0.85  # of the oracle, all events, in every family without random answers
# The detection targets (CAUGHT_TARGET, CAUGHT_VISITS, FALSE_ALARMS_TARGET, EVENTS_PER_MONTH)
# are the learning core's (app.learning.population), shared with ``attune fleet simulate``.


@dataclass(frozen=True)
class Window:
    """A window of events: ``key`` (for files), ``label`` (for people); ``span`` names its
    events (by default its key) and ``reference`` the reward it is a share of: the oracle's
    or the one-miss oracle's (``"bound"``)."""

    key: str
    label: str
    needs_change: bool
    span: str = ""
    reference: str = "oracle"


WINDOWS = (
    Window("first20", "first 20", False),
    Window("before30", "30 before the change", True),
    Window("after15", "15 after the change", True),
    Window("after30", "30 after the change", True),
    Window("last30", "last 30", False),
    Window("all", "all", False),
    Window("after15_bound", "15 after, of the one-miss oracle", True, "after15", "bound"),
    Window("after30_bound", "30 after, of the one-miss oracle", True, "after30", "bound"),
)
PLOT_WINDOWS = ("first20", "before30", "after15_bound", "after30_bound", "last30", "all")


def window_range(window: Window, n_events: int, change_at: int | None) -> tuple[int, int] | None:
    """Events ``start:stop`` (0-based, half-open) of ``window``; None when it does not apply
    (a window about the change in a family without one, or no event in it)."""
    if window.needs_change and change_at is None:
        return None
    span = window.span or window.key
    if span == "first20":
        start, stop = 0, 20
    elif span == "before30":
        assert change_at is not None
        start, stop = change_at - 30, change_at
    elif span in ("after15", "after30"):
        assert change_at is not None
        start, stop = change_at, change_at + (15 if span == "after15" else 30)
    elif span == "last30":
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
        "persons; mean over seeds (windows *_bound: / the one-miss oracle's reward)",
        "one_miss_oracle": "the oracle, except at the first visit of each changed context "
        "after the change, where it acts on the old routine",
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
            "reference": w.reference,
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
                cells[w.key] = _cell(mine, label, rng, w.reference)
            entry["learners"][label] = cells
        entry["detection"] = {label: _detection(mine, label) for label in learners}
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


def _detection(runs: Sequence[FamilyRun], label: str) -> dict[str, Any]:
    """The changes decided for a family's persons by one learner, counted against their true
    changes over every seed."""
    total = Detection()
    for r in runs:
        if label in r.detection:
            total.add(r.detection[label])
    caught = total.caught
    events = [e for e, _ in caught]
    visits = [v for _, v in caught]
    within = total.caught_within(CAUGHT_VISITS)
    rate = total.false_alarms_per(EVENTS_PER_MONTH)
    return {
        "source": total.source or None,
        "true": total.true,
        "caught": len(caught),
        "caught_share": rounded(len(caught) / total.true) if total.true else None,
        "within_visits": CAUGHT_VISITS,
        "caught_within": within,
        "caught_within_share": rounded(within / total.true) if total.true else None,
        "median_events_late": float(np.median(events)) if events else None,
        "median_visits": float(np.median(visits)) if visits else None,
        "mean_visits": rounded(float(np.mean(visits))) if visits else None,
        "false_alarms": total.false_alarms,
        "persons": total.persons,
        "events": total.events,
        "false_alarms_per_person_month": None if rate is None else rounded(rate),
    }


def check_targets(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The issue's targets for the service's default learner, each met or missed (empty when it
    is not in the run):

    - every changing family: at least :data:`BOUND_TARGET` of the one-miss oracle's reward in
      the 15 events after a switch (30 after a gradual drift), and at least
      :data:`BEFORE_TARGET` of the oracle's in the 30 events before the change;
    - every family without random answers: at least :data:`ALL_TARGET` over all events;
    - every family: over all events, no lower than the previous default's (:data:`PREVIOUS`)
      share by more than its interval (the default's mean at least the lower bound of the
      previous default's 95 % interval), when the previous default is in the run;
    - ``abrupt``: at least :data:`CAUGHT_TARGET` of its changes caught within
      :data:`CAUGHT_VISITS` visits of the changed context;
    - every family without a change: at most :data:`FALSE_ALARMS_TARGET` false alarm per
      person per :data:`EVENTS_PER_MONTH` events.
    """
    label = LEARNERS[SERVICE_DEFAULT].label
    previous = LEARNERS[PREVIOUS].label
    if label not in summary["learners"]:
        return []
    out: list[dict[str, Any]] = []

    def add(name: str, window: str, text: str, value: float | None, met: bool) -> None:
        out.append(
            {
                "family": name,
                "window": window,
                "learner": label,
                "target": text,
                "share": value,
                "met": met,
            }
        )

    for name, fam in summary["families"].items():
        family = FAMILIES[name]
        cells = fam["learners"][label]
        checks: list[tuple[str, str, float]] = []
        if fam["change_at_event"] is not None:
            key = "after30_bound" if family.gradual else "after15_bound"
            checks.append(
                (key, f"≥ {100 * BOUND_TARGET:.0f}% of the one-miss oracle", BOUND_TARGET)
            )
            checks.append(("before30", f"≥ {100 * BEFORE_TARGET:.0f}%", BEFORE_TARGET))
        if not family.random_answers:
            checks.append(("all", f"≥ {100 * ALL_TARGET:.0f}%", ALL_TARGET))
        for key, text, bound in checks:
            mean = cells[key]["mean"]
            add(name, key, text, mean, mean is not None and round(mean, 2) >= bound)
        if previous in fam["learners"] and previous != label:
            cell = fam["learners"][previous]["all"]
            low = None if cell["ci95"] is None else cell["ci95"][0]
            mean = cells["all"]["mean"]
            if low is not None and cell["mean"] is not None:
                add(
                    name,
                    "all",
                    f"no worse than {previous}'s {interval_text(cell)} beyond its interval",
                    mean,
                    mean is not None and round(mean, 2) >= round(low, 2),
                )
        det = fam["detection"][label]
        if name == "abrupt" and det["true"]:
            share = det["caught_within_share"]
            add(
                name,
                "detection",
                f"≥ {100 * CAUGHT_TARGET:.0f}% of the changes caught within "
                f"{CAUGHT_VISITS} visits of the changed context",
                share,
                share is not None and share >= CAUGHT_TARGET,
            )
        if fam["change_at_event"] is None and det["events"]:
            rate = det["false_alarms_per_person_month"]
            add(
                name,
                "false_alarms",
                f"≤ {FALSE_ALARMS_TARGET:g} false alarm per person per {EVENTS_PER_MONTH} events",
                rate,
                rate is not None and rate <= FALSE_ALARMS_TARGET,
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
            f"Targets for the default learner ({targets[0]['learner']}): "
            f"{met} of {len(targets)} met."
        )
        for t in targets:
            if t["window"] == "false_alarms":
                value = "—" if t["share"] is None else f"{t['share']:.2f}"
                window = f"false alarms per person per {EVENTS_PER_MONTH} events"
            elif t["window"] == "detection":
                value = "—" if t["share"] is None else f"{percent(t['share'])}%"
                window = "changes detected"
            else:
                value = "—" if t["share"] is None else f"{percent(t['share'])}%"
                window = summary["windows"][t["window"]]["label"]
            lines.append(
                f"  {t['family']}, {window}: {value} (target {t['target']}): "
                f"{'met' if t['met'] else 'MISSED'}"
            )
    return lines


def detection_rows(summary: Mapping[str, Any]) -> list[list[str]]:
    """The changes decided, per family and learner: source, true changes, caught, within
    :data:`CAUGHT_VISITS` visits, median lateness (events, visits), false alarms."""
    rows = []
    for name, fam in summary["families"].items():
        for i, (label, det) in enumerate(fam.get("detection", {}).items()):
            true = det["true"]
            rows.append(
                [
                    name if i == 0 else "",
                    label,
                    det["source"] or "",
                    str(true) if true else "",
                    f"{det['caught']} ({percent(det['caught_share'])}%)" if true else "",
                    f"{det['caught_within']} ({percent(det['caught_within_share'])}%)"
                    if true
                    else "",
                    ""
                    if det["median_events_late"] is None
                    else f"{det['median_events_late']:g} / {det['median_visits']:g}",
                    ""
                    if det["false_alarms_per_person_month"] is None
                    else f"{det['false_alarms']} ({det['false_alarms_per_person_month']:.2f})",
                ]
            )
    return rows


DETECTION_HEADER = [
    "Family",
    "Learner",
    "decided by",
    "true changes",
    "caught",
    f"within {CAUGHT_VISITS} visits",
    "median late (events / visits)",
    f"false alarms (per person per {EVENTS_PER_MONTH} events)",
]


def _cell(
    runs: Sequence[FamilyRun], label: str, rng: tuple[int, int] | None, reference: str = "oracle"
) -> dict[str, Any]:
    """One family x learner x window: shares per seed (of the oracle's reward, or of the
    one-miss oracle's with ``reference="bound"``), their mean and interval."""
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
            float(r.learners[label][:, start:stop].sum()),
            float(_reference(r, reference)[:, start:stop].sum()),
        )
        for r in runs
    ]
    return {"applicable": True, **report.interval_cell(shares, rng)}


def _reference(run: FamilyRun, reference: str) -> np.ndarray:
    if reference == "bound":
        return run.oracle if run.bound is None else run.bound
    return run.oracle


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
        "",
        "## Changes detected",
        "",
        "Per family and learner, the changes decided for the persons (by the learner's own "
        "mechanism, or by the profile's belief for a learner without one) against their true "
        "changes (a routine replaced or ended), over every seed: caught before the next change "
        f"or the end, caught within {CAUGHT_VISITS} visits of the changed context, the median "
        "lateness (events after the change / visits of the context up to the one whose update "
        "decided it), and the changes decided that match no true change (false alarms), with "
        f"their rate per person per {EVENTS_PER_MONTH} events.",
        "",
        report.markdown_table(DETECTION_HEADER, detection_rows(summary), left=3),
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
    detection = report.terminal_table("Changes detected (over every seed)")
    for i, heading in enumerate(DETECTION_HEADER):
        detection.add_column(heading, justify="left" if i < 3 else "right", no_wrap=i < 3)
    for row in detection_rows(summary):
        detection.add_row(*row)
    report.print_whole(console, table)
    report.print_whole(console, detection, verdict_lines(summary))


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

    keys = [k for k in PLOT_WINDOWS if k in summary["windows"]]
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
