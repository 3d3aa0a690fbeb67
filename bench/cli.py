"""Benchmark of the command line: does ``--help`` of every command answer in under a second?

    .venv/bin/python bench/cli.py                  # every command, 5 runs each
    .venv/bin/python bench/cli.py --runs 10 --json
    .venv/bin/python bench/cli.py --attune /path/to/venv/bin/attune --target 0.5

Walks the command tree of ``app.cli`` (``attune``, its groups and their commands) and runs
``attune [COMMAND...] --help`` as a separate process --runs times for each, timing each run
from start to exit (what a person typing it waits: interpreter start-up, imports, building
the commands, rendering the help). Prints min / median / max seconds per command and whether
every run of every command met the target (--target, 1 s); exits 1 when one did not. With
--json, prints the same figures as one JSON object instead of the table. Other work on the
machine shows in the max column first: measure on an otherwise idle machine.

Most of what is left is Python, Typer and rich starting up (``attune --help`` itself) and
Typer preparing the command's parameters; the commands import their own dependencies
(SQLAlchemy, numpy, matplotlib, the client) only when they run (tests/cli/test_help.py).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import typer.main
from rich.console import Console
from rich.table import Table

from app.cli import app


def commands(group: Any, path: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    """Every command path under ``group`` (a click-style command that Typer built), the group
    itself first, in help order."""
    found = [path]
    if hasattr(group, "list_commands"):
        context = group.context_class(group, info_name=" ".join(("attune", *path)))
        for name in group.list_commands(context):
            sub = group.get_command(context, name)
            if sub is not None and not sub.hidden:
                found += commands(sub, (*path, name))
    return found


def time_help(attune: str, path: tuple[str, ...], runs: int) -> list[float]:
    """Seconds of ``attune PATH --help``, ``runs`` times; fails loudly if one run fails."""
    env = {**os.environ, "COLUMNS": "100"}
    seconds = []
    for _ in range(runs):
        start = time.perf_counter()
        done = subprocess.run(
            [attune, *path, "--help"],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        seconds.append(time.perf_counter() - start)
        if done.returncode != 0 or "Usage" not in done.stdout:
            raise SystemExit(
                f"attune {' '.join(path)} --help failed ({done.returncode}):\n"
                f"{done.stdout}{done.stderr}"
            )
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=5, help="runs per command (default 5)")
    parser.add_argument("--target", type=float, default=1.0, help="seconds (default 1)")
    parser.add_argument(
        "--attune",
        default=str(Path(sys.executable).with_name("attune")),
        help="the attune executable (default: the one beside this Python)",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be at least 1")

    paths = commands(typer.main.get_command(app))
    rows: list[dict[str, Any]] = []
    for path in paths:
        seconds = time_help(args.attune, path, args.runs)
        rows.append(
            {
                "command": " ".join(("attune", *path, "--help")),
                "runs": len(seconds),
                "min_s": round(min(seconds), 3),
                "median_s": round(statistics.median(seconds), 3),
                "max_s": round(max(seconds), 3),
                "met": max(seconds) < args.target,
            }
        )
    met = all(row["met"] for row in rows)
    if args.json:
        print(
            json.dumps(
                {"target_s": args.target, "cpus": os.cpu_count(), "met": met, "commands": rows},
                indent=2,
            )
        )
    else:
        out = Console(highlight=False)
        table = Table(
            title=f"--help of {len(rows)} commands, {args.runs} runs each ({os.cpu_count()} CPUs)",
            title_justify="left",
        )
        table.add_column("command", no_wrap=True)
        for heading in ("min s", "median s", "max s"):
            table.add_column(heading, justify="right")
        table.add_column(f"< {args.target:g} s")
        for row in rows:
            table.add_row(
                row["command"],
                f"{row['min_s']:.3f}",
                f"{row['median_s']:.3f}",
                f"{row['max_s']:.3f}",
                "met" if row["met"] else "MISSED",
            )
        out.print(table)
        slowest = max(rows, key=lambda row: row["max_s"])
        out.print(
            f"Target: every --help under {args.target:g} s, slowest run included: "
            f"{'met' if met else 'NOT met'} (slowest: {slowest['command']}, "
            f"{slowest['max_s']:.3f} s)."
        )
    sys.exit(0 if met else 1)


if __name__ == "__main__":
    main()
