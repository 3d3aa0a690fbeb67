"""Benchmark of the learning core: decision + update latency vs history length, state size, and
the wall time of the paper's experiments.

    python bench/learner.py                  # every learner, the full experiment at 20 seeds
    python bench/learner.py --quick          # fewer repetitions, no 100,000-episode history
    python bench/learner.py --no-experiment  # skip the `attune experiment paper` timing

Targets (issue "learning core"): one decision plus one update under 0.5 ms for a user of the
office mission, flat in history length (10, 1,000 and 100,000 past episodes); the exported state
under 64 KiB; `attune experiment paper --seeds 20` under 60 s on a 2-core machine.

A "decision plus update" is the service's hot path with a cold cache: the learner plans the
context from its tables (value iteration for the model-based learners), draws the action, and
learns the person's response (a rejection or a pass also closes the episode, so the per-episode
aggregation is among the timed updates).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.learning import ALGORITHMS, Observation, Transition, make_learner, office_mission  # noqa: E402
from app.learning.evaluation import _seq, run_user, user_profiles  # noqa: E402
from app.learning.simulation import STEP_COLUMNS, event_stream, respond  # noqa: E402

TARGET_MS = 0.5
TARGET_STATE = 64 * 1024
TARGET_EXPERIMENT_S = 60.0


def grown_learner(algorithm: str, episodes: int):  # type: ignore[no-untyped-def]
    """A learner that has lived through ``episodes`` events of a simulated office user."""
    mission = office_mission()
    learner = make_learner(algorithm, None, mission)
    before, after = user_profiles(mission, 0, 0)
    # Needs drift every 1,000 events, so long histories hold contradicting samples.
    profiles = [before if (i % 2 == 0) else after for i in range(max(1, episodes // 1000 + 1))]
    points = [i * 1000 for i in range(len(profiles))]
    contexts = event_stream(profiles, points, mission, episodes, _seq(0, 0, 2, 9))
    uniforms = _seq(0, 0, 3, 9).random((episodes, STEP_COLUMNS))
    run_user(learner, profiles, points, contexts, uniforms, _seq(0, 0, 4, 9))
    return learner, profiles[-1]


def time_decision_update(learner, profile, reps: int) -> float:  # type: ignore[no-untyped-def]
    """Median milliseconds of one cold decision plus the update that closes its episode."""
    space = learner.space
    rng = np.random.default_rng(1)
    uniforms = np.random.default_rng(2).random((reps, 2))
    contexts = np.random.default_rng(3).integers(0, space.n_contexts, size=reps)
    samples = []
    for i in range(reps):
        episode = learner.episodes + 1
        context = int(contexts[i])
        start = time.perf_counter_ns()
        learner._cache.clear()  # cold: plan from the tables, as after a fresh load
        decision = learner.select_action(Observation(context, space.OBSERVE, episode), rng)
        reaction = respond(space, profile, context, decision.state, decision.action, uniforms[i])
        batch = decision.transitions(episode, reaction.reward, reaction.next_state, reaction.signal)
        learner.update(batch)
        samples.append((time.perf_counter_ns() - start) / 1e6)
        if reaction.next_state != space.END:  # finish the episode outside the timed region
            learner.update(
                [
                    Transition(
                        episode,
                        context,
                        reaction.next_state,
                        space.actions_of(reaction.next_state).start,
                        0.0,
                        space.END,
                    )
                ]
            )
    return statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="fewer reps, no 100,000 history")
    parser.add_argument("--no-experiment", action="store_true", help="skip the experiment timing")
    parser.add_argument("--reps", type=int, default=2000, help="timed events per cell")
    parser.add_argument("--algorithms", nargs="*", default=sorted(ALGORITHMS))
    args = parser.parse_args()
    histories = [10, 1_000] if args.quick else [10, 1_000, 100_000]
    reps = 300 if args.quick else args.reps

    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, numpy {np.__version__}"
    )
    print(
        f"\nmedian ms of one decision + one update (cold plan), {reps} events per cell; "
        f"target < {TARGET_MS} ms, flat in history"
    )
    cols = "".join(f"{h:>12,}" for h in histories)
    print(f"{'learner':<10}{cols}{'state KiB':>12}{'ratio max/min':>15}")
    worst, largest = 0.0, 0
    for algorithm in args.algorithms:
        cells, size = [], 0
        for h in histories:
            learner, profile = grown_learner(algorithm, h)
            cells.append(time_decision_update(learner, profile, reps))
            size = len(json.dumps(learner.to_state()).encode())
        worst, largest = max(worst, *cells), max(largest, size)
        print(
            f"{algorithm:<10}"
            + "".join(f"{c:>12.3f}" for c in cells)
            + f"{size / 1024:>12.1f}{max(cells) / min(cells):>15.2f}"
        )
    print(
        f"\nworst decision+update: {worst:.3f} ms  (target < {TARGET_MS} ms: "
        f"{'met' if worst < TARGET_MS else 'NOT met'})"
    )
    print(
        f"largest exported state: {largest / 1024:.1f} KiB after {histories[-1]:,} episodes "
        f"(target < 64 KiB: {'met' if largest < TARGET_STATE else 'NOT met'})"
    )

    if not args.no_experiment:
        attune = Path(sys.executable).with_name("attune")
        cmd = [str(attune) if attune.exists() else "attune", "experiment", "paper", "--seeds", "20"]
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            subprocess.run([*cmd, "--out", out], check=True, stdout=subprocess.DEVNULL)
            wall = time.perf_counter() - start
        verdict = "met" if wall < TARGET_EXPERIMENT_S else "NOT met"
        print(
            f"`attune experiment paper --seeds 20`: {wall:.1f} s wall "
            f"(target < {TARGET_EXPERIMENT_S:.0f} s: {verdict})"
        )


if __name__ == "__main__":
    main()
