"""Commands whose optional dependencies come with an extra of the ``attune`` distribution.

``require(module, extra, command)`` is called first thing in such a command: when ``module``
cannot be imported it prints one line naming the extra to install, to stderr, and exits 2.
"""

from __future__ import annotations

import importlib
import sys

import typer

__all__ = ["missing_extra_message", "require"]


def missing_extra_message(extra: str, command: str) -> str:
    """The line printed when ``command`` lacks the ``extra`` extra."""
    return f"{command} needs the '{extra}' extra: pip install 'attune[{extra}]'"


def require(module: str, extra: str, command: str) -> None:
    """Import ``module``, or tell which extra brings it (one line on stderr) and exit 2."""
    try:
        importlib.import_module(module)
    except ImportError:
        sys.stderr.write(missing_extra_message(extra, command) + "\n")
        raise typer.Exit(2) from None
