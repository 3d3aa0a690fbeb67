"""Commands whose optional dependencies come with an extra of the ``attune`` distribution.

``require(module, extra, command)`` is called first thing in such a command: when ``module``
cannot be imported it prints one line naming the extra and the command that installs it, to
stderr, and exits 2.

Attune is installed from a clone (it is on no package index, and a package of the same name on
PyPI is not this one), so the line names the install from the clone's folder: ``pip install
'.[EXTRA]'``, with the client's folder beside it for an extra that needs the client, as the
README's "With pip" says.
"""

from __future__ import annotations

import importlib
import sys

import typer

__all__ = ["install_command", "missing_extra_message", "require"]

# The extras that need the client (clients/python): pip must be given its folder in the same
# command, since it is on no package index either.
_WITH_CLIENT = frozenset({"fleet", "dev"})


def install_command(extra: str) -> str:
    """The command that installs ``extra``, run in the folder of an Attune clone."""
    client = "./clients/python " if extra in _WITH_CLIENT else ""
    return f"pip install {client}'.[{extra}]'"


def missing_extra_message(extra: str, command: str) -> str:
    """The line printed when ``command`` lacks the ``extra`` extra."""
    return (
        f"{command} needs the '{extra}' extra: in the folder of the Attune clone, run "
        f"{install_command(extra)}"
    )


def require(module: str, extra: str, command: str) -> None:
    """Import ``module``, or tell which extra brings it (one line on stderr) and exit 2."""
    try:
        importlib.import_module(module)
    except ImportError:
        sys.stderr.write(missing_extra_message(extra, command) + "\n")
        raise typer.Exit(2) from None
