"""``attune missions show``, ``list`` and ``set``: each fleet's mission and its versions, read and
changed at the machine (as an admin key would through the API)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Annotated, Any

import typer

from app.errors import AppError

from ._help import Typer
from ._setup import load_settings, open_database, tell

__all__ = ["missions"]

missions = Typer(
    help="Each fleet's mission: what its robots offer, in which situations "
    "and time slots, and its versions.",
    no_args_is_help=True,
)

FleetOption = Annotated[str, typer.Option(help="The fleet.")]
JsonOption = Annotated[bool, typer.Option("--json", help="Print JSON on stdout instead of text.")]


def _summary(doc: dict[str, Any]) -> list[str]:
    """The mission in a few plain lines."""
    lines = [
        "  services: "
        + "; ".join(f"{s['name']} ({', '.join(s['details'])})" for s in doc["services"])
    ]
    quiet = set(doc.get("unavailable_situations", []))
    lines.append(
        "  situations: "
        + ", ".join(f"{s} (do not disturb)" if s in quiet else s for s in doc["situations"])
    )
    lines.append(
        "  time slots: "
        + ", ".join(f"{t['name']} {t['start']}-{t['end']}" for t in doc["time_slots"])
    )
    rewards = ", ".join(f"{k} {v:g}" for k, v in doc["rewards"].items())
    lines.append(f"  rewards: {rewards}; gamma {doc['gamma']:g}")
    return lines


@missions.command("show")
def missions_show(
    fleet: FleetOption = "default",
    version: Annotated[
        int | None,
        typer.Option(help="A stored version (default: the one in force).", show_default=False),
    ] = None,
    json_output: JsonOption = False,
) -> None:
    """Print a fleet's mission (the version in force, or --version N). With --json, the mission
    document as `missions set` takes it."""
    from app.services import audit
    from app.services import missions as service
    from app.services.context import ServiceContext

    from ._output import print_json

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    with open_database(settings) as database, database.transaction(write=False) as session:
        listed = service.list_missions(session, ctx, audit.CLI, fleet)
    chosen = listed["current_version"] if version is None else version
    found = [item for item in listed["items"] if item["version"] == chosen]
    if not found:
        tell(
            f"Fleet {fleet!r} has no mission version {chosen} (it has "
            f"{', '.join(str(i['version']) for i in listed['items'])}).",
            "red",
        )
        raise typer.Exit(2)
    item = found[0]
    if json_output:
        print_json(item["mission"])
        return
    state = "in force" if chosen == listed["current_version"] else "replaced"
    stored = (
        "" if item["stored"] else " (the deployment's default; stored with the fleet's first user)"
    )
    typer.echo(f"Fleet {fleet!r}, mission {item['name']!r} version {chosen} ({state}){stored}:")
    for line in _summary(item["mission"]):
        typer.echo(line)


@missions.command("list")
def missions_list(fleet: FleetOption = "default", json_output: JsonOption = False) -> None:
    """List the versions of a fleet's mission, newest first."""
    from rich.table import Table

    from app.services import audit
    from app.services import missions as service
    from app.services.context import ServiceContext

    from ._output import print_json, stdout_console

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    with open_database(settings) as database, database.transaction(write=False) as session:
        listed = service.list_missions(session, ctx, audit.CLI, fleet)
    if json_output:
        print_json(listed)
        return
    table = Table("version", "name", "set", "by", "change id", "renames")
    for item in listed["items"]:
        renames = "; ".join(
            f"{old} -> {new}"
            for section in (item["renames"] or {}).values()
            for old, new in section.items()
        )
        table.add_row(
            str(item["version"]),
            item["name"],
            item["created_at"] or "(default)",
            item["set_by"] or "",
            item["change_id"] or "",
            renames,
        )
    stdout_console().print(table)


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        tell(f"Cannot read the {what} {path}: {exc.strerror or exc}.", "red")
    except (ValueError, UnicodeDecodeError) as exc:
        tell(f"The {what} {path} is not JSON: {exc}.", "red")
    raise typer.Exit(2)


@missions.command("set")
def missions_set(
    file: Annotated[
        Path,
        typer.Argument(
            help="The mission, a JSON file (as `missions show --json` prints one).",
            show_default=False,
        ),
    ],
    fleet: FleetOption = "default",
    renames: Annotated[
        Path | None,
        typer.Option(
            help="A JSON file of renames that carry what was learned across a rename, e.g. "
            '{"details": {"cha": "tea"}}.',
            show_default=False,
        ),
    ] = None,
    change_id: Annotated[
        str | None,
        typer.Option(
            help="Makes the change idempotent (default: derived from the files' contents, so "
            "running the same command twice is one change).",
            show_default=False,
        ),
    ] = None,
    json_output: JsonOption = False,
) -> None:
    """Give a fleet a new mission version. Every user's model of the fleet is carried to it in
    the same transaction: what exists in both versions keeps what was learned, new services,
    details, situations and time slots start fresh, removed ones leave the models (their
    history stays). Conversations open in the fleet are closed as interrupted. Exit 2 with the
    reason if the mission or the renames are not valid."""
    from app.services import audit
    from app.services import missions as service
    from app.services.context import ServiceContext

    from ._output import print_json

    doc = _read_json(file, "mission file")
    renamed = _read_json(renames, "renames file") if renames is not None else None
    if change_id is None:
        canonical = json.dumps({"mission": doc, "renames": renamed}, sort_keys=True)
        change_id = "cli-" + hashlib.sha256(canonical.encode()).hexdigest()[:24]
    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    try:
        with open_database(settings) as database, database.transaction() as session:
            out, replayed = service.set_mission(
                session,
                ctx,
                audit.CLI,
                fleet,
                change_id=change_id,
                mission_doc=doc,
                renames_doc=renamed,
            )
    except AppError as exc:
        tell(exc.detail, "red")
        raise typer.Exit(2) from None
    if json_output:
        print_json({**out, "replayed": replayed})
        return
    if replayed:
        tell(
            f"This change ({change_id}) was made before: fleet {fleet!r} is at version "
            f"{out['version']}; nothing changed."
        )
    elif not out["changed"]:
        tell(
            f"Fleet {fleet!r} already has this mission (version {out['version']}); nothing changed."
        )
    else:
        tell(
            f"Fleet {fleet!r} is now at mission version {out['version']}: "
            f"{out['users_moved']} models carried over, {out['episodes_interrupted']} open "
            "episodes interrupted."
        )
        for line in _diff_lines(out.get("diff")):
            tell(line)


def _diff_lines(diff: dict[str, Any] | None) -> list[str]:
    if not diff:
        return []
    lines = []
    for what in ("time_slots", "situations", "services", "details"):
        part = diff.get(what) or {}
        words = []
        for verb in ("added", "removed"):
            if part.get(verb):
                words.append(f"{verb} {', '.join(map(str, part[verb]))}")
        if part.get("renamed"):
            words.append(
                "renamed "
                + ", ".join(
                    f"{r['old']} -> {r['new']}" if isinstance(r, dict) else str(r)
                    for r in part["renamed"]
                )
            )
        if words:
            lines.append(f"  {what.replace('_', ' ')}: {'; '.join(words)}")
    return lines
