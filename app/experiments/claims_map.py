"""The map of the paper's claims (``attune experiment claims-map``, docs/method.md §13, "A map
of the claims"): the paper's experiments E1/E2 and E3 swept over the reconstruction's open
choices (``app.learning.claims_map.AXES``), each claim decided under every setting by
``app.learning.claims.check_claims``; the table, the CSV and the plot.

One job is one method variant on one protocol with one seed, in one world (the runner's
:class:`~app.experiments.runner.Job`); every setting is decided from the jobs it combines, so
the runs grow with the worlds and the method variants, not with the settings.

*Confirmation.* A sweep on few seeds picks its best setting partly by chance. The default
setting and the best ones are run again on held-out seeds (the ones after the sweep's) and
decided there.

The files, table and figure are made with the report kit (``app.experiments.report``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.learning import Mission, office_mission
from app.learning.claims_map import (
    AXES,
    ClaimMap,
    Grid,
    RunKey,
    Setting,
    World,
    build_map,
    method_key,
    setting_methods,
)
from app.learning.evaluation import E1E2, E3, Method, Protocol, RunResult

from . import report
from .report import rounded
from .runner import Job, run_jobs

if TYPE_CHECKING:
    from rich.console import Console

__all__ = [
    "DEFAULT_CONFIRM_SEEDS",
    "DEFAULT_SEEDS",
    "DEFAULT_USERS",
    "MAX_CONFIRMED",
    "PROTOCOLS",
    "QUICK_SEEDS",
    "QUICK_USERS",
    "TARGET_SECONDS",
    "build_summary",
    "confirm",
    "confirmed_settings",
    "markdown",
    "plan",
    "plot_map",
    "print_table",
    "sweep",
    "write_csv",
    "write_report",
]

DEFAULT_SEEDS = 2  # per setting: 12 simulated users; the best settings are confirmed after
DEFAULT_CONFIRM_SEEDS = 10
DEFAULT_USERS = 6
QUICK_SEEDS = 1
QUICK_USERS = 2
MAX_CONFIRMED = 3  # best settings confirmed on held-out seeds, besides the default
TARGET_SECONDS = 300.0  # the default map, sweep and confirmation, on 2 CPUs
PROTOCOLS = (E1E2, E3)  # what check_claims decides on


def _job(
    world: World, method: Method, protocol: Protocol, seed: int, users: int, base: Mission
) -> Job:
    """The runner's job for one method variant in ``world`` (the office mission is passed as
    None, as ``attune experiment paper`` does, so its default runs are the same)."""
    mission = world.mission(base)
    document = None if mission == base else json.dumps(mission.to_dict(), sort_keys=True)
    return Job(method, protocol, seed, users, tuple(sorted(world.user_params().items())), document)


def plan(
    settings: Sequence[Setting], seeds: Sequence[int], users: int, base: Mission | None = None
) -> list[tuple[RunKey, Job]]:
    """Every job the settings need, each once: world x method variant x protocol x seed,
    ordered world, protocol, method, seed."""
    base = base or office_mission()
    needed: dict[RunKey, Method] = {}
    for setting in settings:
        for method in setting_methods(setting):
            needed.setdefault((setting.world(), method_key(method)), method)
    worlds = sorted({world for world, _ in needed})
    out = []
    for world in worlds:
        for protocol in PROTOCOLS:
            for key, method in needed.items():
                if key[0] == world:
                    out += [
                        (key, _job(world, method, protocol, seed, users, base)) for seed in seeds
                    ]
    return out


def _run(
    todo: Sequence[tuple[RunKey, Job]],
    workers: int,
    description: str,
    console: Console | None,
    progress: bool,
) -> dict[RunKey, list[RunResult]]:
    results = run_jobs(
        [job for _, job in todo],
        workers,
        description=description,
        console=console,
        progress=progress,
    )
    runs: dict[RunKey, list[RunResult]] = {}
    for (key, _), result in zip(todo, results, strict=True):
        runs.setdefault(key, []).append(result)
    return runs


def sweep(
    grid: Grid,
    seeds: int,
    users: int,
    workers: int,
    *,
    console: Console | None = None,
    progress: bool = True,
) -> tuple[ClaimMap, int]:
    """Run the grid on seeds 0..seeds-1 and decide every setting; returns the map and the
    number of runs."""
    settings = grid.settings()
    todo = plan(settings, range(seeds), users)
    runs = _run(todo, workers, "Claims map", console, progress)
    return build_map(settings, runs), len(todo)


def confirm(
    settings: Sequence[Setting],
    first_seed: int,
    seeds: int,
    users: int,
    workers: int,
    *,
    console: Console | None = None,
    progress: bool = True,
) -> tuple[ClaimMap, int]:
    """Decide ``settings`` again on the held-out seeds first_seed..first_seed+seeds-1."""
    todo = plan(settings, range(first_seed, first_seed + seeds), users)
    runs = _run(todo, workers, "Held-out seeds", console, progress)
    return build_map(settings, runs), len(todo)


def confirmed_settings(claim_map: ClaimMap) -> list[Setting]:
    """The default and up to :data:`MAX_CONFIRMED` best settings, each once."""
    return list(dict.fromkeys([Setting.default(), *claim_map.best()[:MAX_CONFIRMED]]))


# -- the numbers ------------------------------------------------------------------------------


def _setting(claim_map: ClaimMap, setting: Setting) -> dict[str, Any]:
    return {
        "label": setting.label(),
        "values": setting.as_dict(),
        "held": claim_map.held(setting),
        "claims": claim_map.verdicts[setting],
    }


def build_summary(
    claim_map: ClaimMap, confirmed: ClaimMap | None, grid: Grid, run_info: Mapping[str, Any]
) -> dict[str, Any]:
    """Every number as plain JSON data."""
    default = Setting.default()
    best = claim_map.best()
    n = len(claim_map.claims)
    summary: dict[str, Any] = {
        "run": dict(run_info),
        "axes": [
            {
                "key": a.key,
                "label": a.label,
                "scope": a.scope,
                "default": a.default,
                "values": list(grid.values[a.key]),
            }
            for a in AXES
        ],
        "claims": [],
        "settings_count": len(claim_map.settings),
        "histogram": claim_map.histogram(),
        "default": _setting(claim_map, default) if default in claim_map.verdicts else None,
        "best": [_setting(claim_map, s) for s in best],
        "marginals": {
            a.key: {
                str(v): {
                    "mean_share": rounded(claim_map.marginal(a.key, v)),
                    "per_claim": [rounded(claim_map.marginal(a.key, v, i)) for i in range(n)],
                }
                for v in grid.values[a.key]
            }
            for a in AXES
        },
        "confirmation": None,
        "settings": [_setting(claim_map, s) for s in claim_map.settings],
    }
    for i, (key, text) in enumerate(claim_map.claims):
        summary["claims"].append(
            {
                "key": key,
                "text": text,
                "share": rounded(claim_map.share(i)),
                "settings_held": sum(v[i] for v in claim_map.verdicts.values()),
            }
        )
    if confirmed is not None:
        summary["confirmation"] = {
            "seeds": [
                run_info["confirm_first_seed"],
                run_info["confirm_first_seed"] + run_info["confirm_seeds"] - 1,
            ],
            "settings": [
                {**_setting(confirmed, s), "evidence": confirmed.evidence[s]}
                for s in confirmed.settings
            ],
        }
    return summary


# -- text -------------------------------------------------------------------------------------


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.0f}%"


def _mark(held: bool) -> str:
    return "✓" if held else "✗"


def _value(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _confirmed(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    return list((summary.get("confirmation") or {}).get("settings", []))


def _name(summary: Mapping[str, Any], confirmed: Mapping[str, Any]) -> str:
    """``default``, or ``best N``: the setting's place among the best of the sweep."""
    if confirmed["label"] == "default":
        return "default"
    labels = [b["label"] for b in summary["best"]]
    return f"best {labels.index(confirmed['label']) + 1}"


def _intro(summary: Mapping[str, Any]) -> str:
    run = summary["run"]
    sizes = " × ".join(str(len(a["values"])) for a in summary["axes"])
    text = (
        f"{summary['settings_count']} settings ({sizes}, axes below), each decided on the "
        f"paper's experiments E1/E2 and E3 with {run['seeds']} seed(s) × {run['users']} "
        f"simulated users; {run['runs']} runs in {run['worlds']} worlds."
    )
    if summary.get("confirmation"):
        first, last = summary["confirmation"]["seeds"]
        text += (
            f" The default and the best settings were run again on held-out seeds "
            f"{first}–{last} ({run['confirm_runs']} runs)."
        )
    text += (
        f" Ran in {run['seconds']:.1f} s on {run['workers']} worker processes (load "
        f"average {run['load_average']:.1f}"
    )
    cpu = run.get("cpu_seconds")
    text += ")." if cpu is None else f"; {cpu:.0f} s of CPU time)."
    if run.get("quick"):
        text += " Quick mode: a reduced grid, for checks only."
    command = (
        f"attune experiment claims-map{' --quick' if run.get('quick') else ''} --seeds "
        f"{run['seeds']} --confirm-seeds {run['confirm_seeds']} --users {run['users']}"
    )
    return text + f" Made by `{command}`."


def markdown(summary: Mapping[str, Any]) -> str:
    """claims-map.md: the claims with their share of settings, the default and the best
    settings, the held-out check, and the share of claims per value of each axis."""
    best = summary["best"]
    confirmed = _confirmed(summary)
    default = summary["default"]
    lines = [
        "# A map of the paper's claims over the reconstruction's choices",
        "",
        "Under the **default** setting every command's choices are those of docs/method.md "
        "(§2–§11); any other setting is **a reading** of the paper, not the paper. ✓: the "
        "claim holds, ✗: it does not. " + _intro(summary),
        "",
    ]
    head = ["Claim", "share of settings"]
    if default is not None:
        head.append("default")
    head.append("best")
    head += [f"{_name(summary, c)}, held-out seeds" for c in confirmed]
    rows = []
    for i, claim in enumerate(summary["claims"]):
        row = [f"**{claim['key']}**: {claim['text']}", _pct(claim["share"])]
        if default is not None:
            row.append(_mark(default["claims"][i]))
        row.append(_mark(best[0]["claims"][i]))
        row += [_mark(c["claims"][i]) for c in confirmed]
        rows.append(row)
    total = ["**claims that hold**", ""]
    if default is not None:
        total.append(f"**{default['held']}**")
    total.append(f"**{best[0]['held']}**")
    total += [f"**{c['held']}**" for c in confirmed]
    lines.append(report.markdown_table(head, [*rows, total]))
    n = len(summary["claims"])
    lines += [
        "",
        f"Best settings ({best[0]['held']} of {n} claims; {len(best)} tied, fewest "
        "changes from the default first):",
        "",
    ]
    lines += [f"{i + 1}. {b['label']}" for i, b in enumerate(best[:10])]
    if confirmed:
        first, last = summary["confirmation"]["seeds"]
        lines += [
            "",
            f"On the held-out seeds {first}–{last}: "
            + "; ".join(f"{_name(summary, c)}, {c['held']} of {n}" for c in confirmed)
            + ". Deciding many settings on few seeds and keeping the best favours "
            "settings that were lucky; the held-out seeds say what is left of it.",
        ]
    if len(best) > 10:
        lines.append(f"- … and {len(best) - 10} more (summary.json, claims-map.csv).")
    hist = ", ".join(f"{k}: {c}" for k, c in enumerate(summary["histogram"]) if c)
    lines += [
        "",
        f"Settings by the number of claims that hold ({hist}).",
        "",
        "Mean share of the claims that hold, per value of each choice (the default's "
        "value in bold):",
        "",
    ]
    marginals = []
    for axis in summary["axes"]:
        for j, v in enumerate(axis["values"]):
            text = _value(v)
            shown = f"**{text}**" if v == axis["default"] else text
            share = summary["marginals"][axis["key"]][str(v)]["mean_share"]
            marginals.append([axis["label"] if j == 0 else "", shown, _pct(share)])
    lines.append(
        report.markdown_table(["Choice", "value", "mean share of claims"], marginals, left=2)
    )
    return "\n".join(lines) + "\n"


def print_table(summary: Mapping[str, Any], console: Console) -> None:
    """The claims, their share of settings, the default and the best setting, for the terminal
    (whole, whatever its width)."""
    best = summary["best"]
    default = summary["default"]
    confirmed = _confirmed(summary)
    table = report.terminal_table(
        f"The paper's claims over {summary['settings_count']} settings of the "
        "reconstruction's choices"
    )
    table.add_column("Claim", no_wrap=True)
    table.add_column("share of settings", justify="right")
    if default is not None:
        table.add_column("default", justify="center")
    table.add_column("best", justify="center")
    for c in confirmed:
        table.add_column(f"{_name(summary, c)}, held-out", justify="center")
    for i, claim in enumerate(summary["claims"]):
        row = [claim["key"], _pct(claim["share"])]
        if default is not None:
            row.append(_mark(default["claims"][i]))
        row.append(_mark(best[0]["claims"][i]))
        row += [_mark(c["claims"][i]) for c in confirmed]
        table.add_row(*row)
    total = ["claims that hold", ""]
    if default is not None:
        total.append(str(default["held"]))
    total.append(str(best[0]["held"]))
    total += [str(c["held"]) for c in confirmed]
    table.add_row(*total, style="bold")
    lines = [
        f"Best setting ({best[0]['held']} of {len(summary['claims'])}; {len(best)} "
        f"tied): {best[0]['label']}"
    ]
    for c in confirmed:
        what = "default" if c["label"] == "default" else f"{_name(summary, c)} ({c['label']})"
        lines.append(f"On held-out seeds, {what}: {c['held']} hold.")
    report.print_whole(console, table, lines)


def write_csv(summary: Mapping[str, Any], path: Path) -> int:
    """claims-map.csv: one row per setting: the axes' values, its label, how many claims hold,
    then one 0/1 column per claim. Returns the rows written."""
    keys = [c["key"] for c in summary["claims"]]
    axes = [a["key"] for a in summary["axes"]]
    rows = (
        [*(s["values"][a] for a in axes), s["label"], s["held"], *(int(v) for v in s["claims"])]
        for s in summary["settings"]
    )
    return report.write_csv(path, [*axes, "label", "held", *keys], rows)


def plot_map(summary: Mapping[str, Any], path: Path) -> None:
    """claims-map.png: left, claims × settings (settings sorted by the claims that hold, the
    default marked); right, per claim, the share of settings where it holds per value of each
    choice."""
    from matplotlib.colors import ListedColormap, Normalize

    claims = [c["key"] for c in summary["claims"]]
    settings = sorted(summary["settings"], key=lambda s: -s["held"])
    grid = np.array([[float(v) for v in s["claims"]] for s in settings]).T  # claims x settings
    columns = [(a, v) for a in summary["axes"] for v in a["values"]]
    shares = np.array(
        [
            [
                summary["marginals"][a["key"]][str(v)]["per_claim"][i]
                if summary["marginals"][a["key"]][str(v)]["per_claim"][i] is not None
                else np.nan
                for a, v in columns
            ]
            for i in range(len(claims))
        ]
    )
    fig = report.figure(16, 0.42 * len(claims) + 3.2)
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.0, 1.3]})
    left.imshow(
        grid,
        cmap=ListedColormap(["#d9d9d9", "#1b7837"]),
        aspect="auto",
        interpolation="nearest",
        vmin=0,
        vmax=1,
    )
    left.set_yticks(range(len(claims)), claims, fontsize=8)
    left.set_xlabel(f"{len(settings)} settings, most claims held first")
    left.set_xticks([])
    default = [i for i, s in enumerate(settings) if s["label"] == "default"]
    for i in default:
        left.axvline(i, color="#d73027", linewidth=1.5)
    left.set_title("Claims that hold (green) under each setting; red: the default", fontsize=10)
    image = right.imshow(shares, cmap="viridis", norm=Normalize(0.0, 1.0), aspect="auto")
    report.label_cells(right, shares, lambda v: f"{100 * v:.0f}", fontsize=7)
    right.set_yticks(range(len(claims)), claims, fontsize=8)
    right.set_xticks(
        range(len(columns)),
        [f"{a['key']}={_value(v)}" + (" *" if v == a["default"] else "") for a, v in columns],
        rotation=60,
        ha="right",
        fontsize=8,
    )
    right.set_title(
        "Share of settings where the claim holds, per value of each choice (* default)", fontsize=10
    )
    fig.colorbar(image, ax=right, shrink=0.8, label="share of settings")
    run = summary["run"]
    fig.suptitle(
        f"The paper's claims over the reconstruction's choices ({run['seeds']} seed(s) "
        f"× {run['users']} users per setting)",
        fontsize=11,
    )
    fig.savefig(path, format="png")


def write_report(summary: Mapping[str, Any], out: Path) -> list[Path]:
    """Write claims-map.md, claims-map.csv, claims-map.png and summary.json into ``out``."""
    return report.write_report(
        summary, out, "claims-map", markdown=markdown, table=write_csv, plot=plot_map
    )
