"""The help of every command: its paragraphs as written, wrapped at the terminal's width.

Typer renders help with rich by default, and three things went wrong there: a docstring's
paragraphs kept their source line breaks and were wrapped again at the terminal's width
(ragged lines); every flag showed a type, ``--json <bool>``, as if it took a value; and the
options' table cut words that did not fit its column with an ellipsis
(``docs/examples/care-hom…``, ``[default: results/claims-ma…]``). Click's plain formatter, the
other one Typer has, breaks paths and option names at their hyphens instead
(``care-home-`` / ``mission.json``, ``--confirm-`` / ``seeds``).

So the commands render their help here, from what each command and parameter says of itself
(``get_help_record``, ``collect_usage_pieces``, ``list_commands``: Click's public interface):
each paragraph is joined into one line and wrapped at the terminal's width, up to
:data:`MAX_WIDTH` columns, only at spaces (a word longer than a line stays whole); a flag shows
no type; nothing is cut; a group lists the whole first paragraph of each command. A paragraph
that starts with ``\\b`` keeps its lines, as in Click.

:class:`Typer` is ``typer.Typer`` with these classes for its commands and groups; every
``attune`` command is made with it.
"""

from __future__ import annotations

import inspect
import textwrap
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import typer
from typer.core import MarkupMode, TyperCommand, TyperGroup

__all__ = ["MAX_WIDTH", "HelpCommand", "HelpGroup", "Typer", "paragraphs", "render_help"]

F = TypeVar("F", bound=Callable[..., Any])

MAX_WIDTH = 100
"""The widest help, in columns, however wide the terminal (lines longer than this are harder to
read); narrower terminals get their width, down to 50."""
INDENT = "  "
NAMES_WIDTH = 30  # a longer name (``--progress / --no-progress``) has its help on the next line


def paragraphs(text: str | None) -> list[str]:
    """The paragraphs of a help text (a docstring or a ``help=``): dedented, up to a ``\\f``,
    split at blank lines, each joined into one line (a ``\\b`` paragraph keeps its lines)."""
    found = []
    for block in inspect.cleandoc(text or "").partition("\f")[0].split("\n\n"):
        if block.startswith("\b"):
            found.append(block.removeprefix("\b").strip("\n"))
        elif block.strip():
            found.append(" ".join(block.split()))
    return found


def _wrap(text: str, width: int, indent: str, first: str | None = None) -> list[str]:
    """``text`` wrapped at ``width`` at spaces only; lines after a ``\\b`` paragraph's first keep
    their breaks."""
    wrapper = textwrap.TextWrapper(
        width=width,
        initial_indent=indent if first is None else first,
        subsequent_indent=indent,
        break_long_words=False,
        break_on_hyphens=False,
    )
    lines: list[str] = []
    for line in text.split("\n"):
        lines += wrapper.wrap(line) or [wrapper.initial_indent.rstrip()]
        wrapper.initial_indent = indent
    return lines


def _definitions(rows: Sequence[tuple[str, str]], width: int) -> list[str]:
    """Names and their help in two columns, the help wrapped in its own."""
    if not rows:
        return []
    names = min(max(len(name) for name, _ in rows), NAMES_WIDTH)
    column = len(INDENT) + names + 2
    lines = []
    for name, text in rows:
        start = INDENT + name
        if len(name) > names:
            lines.append(start)
            start = ""
        lines += _wrap(text, max(width, column + 20), " " * column, start.ljust(column))
    return lines


def render_help(command: Any, ctx: typer.Context, width: int) -> str:
    """The help page of ``command`` (a command or a group) in ``ctx``, ``width`` columns wide
    (at most :data:`MAX_WIDTH`)."""
    width = min(width, MAX_WIDTH)
    pieces = " ".join(command.collect_usage_pieces(ctx))
    usage = f"Usage: {ctx.command_path} "
    lines = _wrap(pieces, width, " " * len(usage), usage)
    for paragraph in paragraphs(command.help):
        lines += ["", *_wrap(paragraph, width, INDENT)]
    records = [(p, p.get_help_record(ctx)) for p in command.get_params(ctx)]
    for title, kind in (("Arguments", "argument"), ("Options", "option")):
        rows = [record for p, record in records if record and p.param_type_name == kind]
        if rows:
            lines += [
                "",
                f"{title}:",
                *_definitions([(n, " ".join(h.split())) for n, h in rows], width),
            ]
    if isinstance(command, TyperGroup):
        rows = []
        for name in command.list_commands(ctx):
            sub = command.get_command(ctx, name)
            if sub is not None and not sub.hidden:
                rows.append((name, (paragraphs(sub.short_help or sub.help) or [""])[0]))
        if rows:
            lines += ["", "Commands:", *_definitions(rows, width)]
    return "\n".join(lines) + "\n"


class HelpCommand(TyperCommand):
    """A Typer command whose help is :func:`render_help`'s."""

    def format_help(self, ctx: Any, formatter: Any) -> None:
        formatter.write(render_help(self, ctx, formatter.width))


class HelpGroup(TyperGroup):
    """A Typer group whose help is :func:`render_help`'s."""

    def format_help(self, ctx: Any, formatter: Any) -> None:
        formatter.write(render_help(self, ctx, formatter.width))


class Typer(typer.Typer):
    """``typer.Typer`` whose groups and commands render their help with :func:`render_help`
    (unless given another class), and whose usage errors are plain text too (Typer's rich mode
    off: ``rich_markup_mode=None``): a box drawn around an error helps no one reading a log, and
    in rich mode a group called without a command (``attune experiment``) relies on rich's own
    help to print anything. A traceback shows no local variables: one may hold a database's
    password or key."""

    def __init__(
        self,
        *,
        cls: type[TyperGroup] | None = HelpGroup,
        rich_markup_mode: MarkupMode = None,
        pretty_exceptions_show_locals: bool = False,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            cls=cls,
            rich_markup_mode=rich_markup_mode,
            pretty_exceptions_show_locals=pretty_exceptions_show_locals,
            **kwargs,
        )

    def command(
        self,
        name: str | None = None,
        *,
        cls: type[TyperCommand] | None = HelpCommand,
        **kwargs: Any,
    ) -> Callable[[F], F]:
        return super().command(name, cls=cls, **kwargs)
