"""Where the commands write: tables and JSON on stdout, messages and progress on stderr.

On a terminal a table takes the terminal's width. Elsewhere (a pipe, a file) it is printed at
its full width: no cell is cut or wrapped, so ids can be copied from ``attune keys list | cat``
or parsed by scripts. ``--json`` prints one JSON document on stdout and nothing else there.
"""

from __future__ import annotations

import json
import sys
from typing import Any

from rich.console import Console

__all__ = ["UNBOUNDED_WIDTH", "print_json", "stderr_console", "stdout_console"]

UNBOUNDED_WIDTH = 1_000_000  # wider than any table: rich renders a table at its natural width


def stdout_console() -> Console:
    """A console on stdout: the terminal's width on a terminal, unbounded elsewhere."""
    if sys.stdout.isatty():
        return Console(highlight=False)
    return Console(width=UNBOUNDED_WIDTH, highlight=False)


def stderr_console() -> Console:
    """A console on stderr for messages and progress bars: the terminal's width on a terminal;
    elsewhere (a log file) one message stays on one line."""
    if sys.stderr.isatty():
        return Console(stderr=True, highlight=False)
    return Console(stderr=True, width=UNBOUNDED_WIDTH, highlight=False)


def print_json(document: Any) -> None:
    """``document`` as indented, strict JSON on stdout (one document, nothing else)."""
    sys.stdout.write(json.dumps(document, indent=2, ensure_ascii=False, allow_nan=False) + "\n")
    sys.stdout.flush()
