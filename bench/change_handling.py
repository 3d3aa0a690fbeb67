"""Paired figures of a learner variant against a base, on the robustness suite's families.

    .venv/bin/python bench/change_handling.py                  # dts-routine against DTS
    .venv/bin/python bench/change_handling.py --seeds 0-5,6-11 --families paper,abrupt
    .venv/bin/python bench/change_handling.py --base dts --variant dts:change_alpha=0.01

Each person of a family meets the base and the variant on the same events, the same coin flips
(as in ``attune experiment robustness``) and, unlike the suite, the same learner generator
(common random numbers): two variants that decide alike for a while draw alike too, so their
difference is the variant's own effect and not the luck of two generators. For each seed range,
family and window (the suite's windows), it prints both learners' mean share of the oracle's
reward and the paired difference in points with its 95 % interval (Student's t over seeds).
The default ranges are seeds 0-11 (the range the defaults of ``dts-adapt`` and ``dts-routine``
were chosen on) and 12-23 (held out: nothing was chosen on them). The windows ``*_bound`` are
shares of the one-miss oracle's reward (``app.learning.population.run_one_miss``).

A learner is ``NAME`` of the suite (``attune experiment robustness --learners``) or
``ALGORITHM:KEY=VALUE,...`` (``dts:change_alpha=0.05,forgetting=0.9``).
"""

from __future__ import annotations

import argparse
import json
import sys
import zlib
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.experiments.robustness import LEARNERS, SERVICE_DEFAULT, WINDOWS, window_range
from app.experiments.statistics import mean_ci95
from app.learning import make_learner, office_mission
from app.learning.population import (
    DEFAULT_EVENTS,
    DEFAULT_FAMILIES,
    FAMILIES,
    change_event,
    people,
    run_learner,
    run_one_miss,
    run_oracle,
)
from app.learning.space import space_for

CHANGING = tuple(name for name, family in FAMILIES.items() if family.changes)
Spec = tuple[str, dict[str, Any]]


def parse_learner(text: str) -> tuple[str, Spec]:
    """``(label, (algorithm, params))`` of a suite name or ``ALGORITHM:KEY=VALUE,...``."""
    if text in LEARNERS:
        method = LEARNERS[text]
        return method.label, (method.algorithm, dict(method.params))
    algorithm, _, rest = text.partition(":")
    params: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        key, _, raw = item.partition("=")
        params[key] = json.loads(raw)
    return text, (algorithm, params)


def parse_seeds(text: str) -> list[range]:
    """``0-11,12-23`` -> [range(0, 12), range(12, 24)]."""
    out = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        out.append(range(int(low), int(high or low) + 1))
    return out


def run_pair(
    job: tuple[str, int, Spec, Spec, int, int],
) -> tuple[str, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One family and seed: rewards (persons, events) of the oracle, the base, the variant and
    the one-miss oracle, each person's learners drawing from one generator seed."""
    name, seed, base, variant, n_persons, n_events = job
    mission = office_mission()
    space = space_for(mission)
    family = FAMILIES[name]
    persons, flips = people(family, mission, seed, n_persons, n_events)
    oracle = np.stack([run_oracle(space, p, u) for p, u in zip(persons, flips, strict=True)])
    bound = np.stack([run_one_miss(space, p, u) for p, u in zip(persons, flips, strict=True)])
    rows: list[list[np.ndarray]] = [[], []]
    for i, (person, u) in enumerate(zip(persons, flips, strict=True)):
        words = [seed, zlib.crc32(name.encode()), 3, i]
        for j, (algorithm, params) in enumerate((base, variant)):
            learner = make_learner(algorithm, params, mission)
            rng = np.random.default_rng(np.random.SeedSequence(words))
            rows[j].append(run_learner(learner, person, u, rng))
    return name, seed, oracle, np.stack(rows[0]), np.stack(rows[1]), bound


def shares(oracle: np.ndarray, learner: np.ndarray, rng: tuple[int, int]) -> float:
    start, stop = rng
    total = float(oracle[:, start:stop].sum())
    return float(learner[:, start:stop].sum()) / total if total >= 1.0 else float("nan")


def report(
    results: Sequence[tuple[str, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
    families: Sequence[str],
    n_events: int,
) -> dict[str, Any]:
    """Per family and window: the mean shares of base and variant, the paired difference."""
    out: dict[str, Any] = {}
    for name in families:
        mine = [r for r in results if r[0] == name]
        change_at = change_event(n_events) if FAMILIES[name].changes else None
        cells: dict[str, Any] = {}
        for w in WINDOWS:
            rng = window_range(w, n_events, change_at)
            if rng is None:
                continue
            bound = w.reference == "bound"  # a share of the one-miss oracle's reward
            base = [shares(r[5] if bound else r[2], r[3], rng) for r in mine]
            variant = [shares(r[5] if bound else r[2], r[4], rng) for r in mine]
            diff = [v - b for b, v in zip(base, variant, strict=True)]
            stats = mean_ci95(diff)
            cells[w.key] = {
                "base": float(np.nanmean(base)),
                "variant": float(np.nanmean(variant)),
                "diff": None if stats is None else list(stats),
            }
        out[name] = cells
    return out


def print_report(summary: Mapping[str, Any], seeds: range, base: str, variant: str) -> None:
    print(
        f"\nSeeds {seeds.start}-{seeds.stop - 1}: base {base!r}, variant {variant!r}; "
        "mean share base -> variant, paired difference in points [95% CI]"
    )
    keys = [w.key for w in WINDOWS]
    print(f"{'family':<11}" + "".join(f"{k:>24}" for k in keys))
    for name, cells in summary.items():
        row = f"{name:<11}"
        for k in keys:
            cell = cells.get(k)
            if cell is None:
                row += f"{'':>24}"
                continue
            d = cell["diff"]
            text = f"{100 * cell['base']:.0f}->{100 * cell['variant']:.0f}"
            if d is not None:
                text += f" {100 * d[0]:+.0f}[{100 * d[1]:+.0f},{100 * d[2]:+.0f}]"
            row += f"{text:>24}"
        print(row)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", default="dts", help="the learner to compare against")
    parser.add_argument(
        "--variant",
        default=SERVICE_DEFAULT,
        help="the learner compared (default: the service's default learner)",
    )
    parser.add_argument(
        "--seeds",
        default="0-11,12-23",
        help="seed ranges, each reported apart (a tuning and a held-out range)",
    )
    parser.add_argument(
        "--families",
        default=",".join(DEFAULT_FAMILIES),
        help="families, separated by commas (default: all but the held-out ones)",
    )
    parser.add_argument("--persons", type=int, default=3)
    parser.add_argument("--events", type=int, default=DEFAULT_EVENTS)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path, help="also write every figure to this file")
    args = parser.parse_args(argv)
    base_label, base = parse_learner(args.base)
    variant_label, variant = parse_learner(args.variant)
    families = [f for f in args.families.split(",") if f]
    ranges = parse_seeds(args.seeds)
    everything: dict[str, Any] = {"base": [base_label, *base], "variant": [variant_label, *variant]}
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for seeds in ranges:
            jobs = [
                (f, s, base, variant, args.persons, args.events) for f in families for s in seeds
            ]
            results = list(pool.map(run_pair, jobs))
            summary = report(results, families, args.events)
            print_report(summary, seeds, base_label, variant_label)
            everything[f"{seeds.start}-{seeds.stop - 1}"] = summary
    if args.json:
        args.json.write_text(json.dumps(everything, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
