"""``attune keys create``, ``list`` and ``revoke``: API keys, made here, shown once, stored
hashed."""

from __future__ import annotations

from typing import Annotated, Any

import typer

from app.errors import AppError

from ._help import Typer
from ._setup import load_settings, open_database, tell

__all__ = ["keys"]

keys = Typer(help="API keys: made here, shown once, stored hashed.", no_args_is_help=True)

JsonOption = Annotated[
    bool, typer.Option("--json", help="Print JSON on stdout instead of a table.")
]


@keys.command("create")
def keys_create(
    role: Annotated[str, typer.Option(help="robot, staff (of one fleet) or admin.")],
    fleet: Annotated[
        str, typer.Option(help="The fleet the key (and the users it creates) belongs to.")
    ] = "default",
    name: Annotated[str | None, typer.Option(help="A label for people, e.g. 'robot7'.")] = None,
) -> None:
    """Make a key; the secret is printed once, alone on the last line."""
    from app.services.auth import create_key

    try:
        with open_database(load_settings()) as database, database.transaction() as session:
            key, secret = create_key(session, role=role, fleet=fleet, name=name)
    except AppError as exc:
        tell(exc.detail, "red")
        raise typer.Exit(2) from None
    tell(
        f"Created {key.role} key {key.id} for fleet {key.fleet!r}. Store the secret now: "
        "it cannot be shown again."
    )
    typer.echo(secret)


@keys.command("list")
def keys_list(json_output: JsonOption = False) -> None:
    """List keys (ids, roles, fleets; never the secrets)."""
    from rich.table import Table

    from app.services.auth import list_keys

    from ._output import print_json, stdout_console

    with open_database(load_settings()) as database, database.transaction(write=False) as session:
        rows: list[dict[str, Any]] = [
            {
                "id": k.id,
                "role": k.role,
                "fleet": k.fleet,
                "name": k.name,
                "prefix": k.prefix,
                "created_at": k.created_at.isoformat(timespec="seconds"),
                "revoked_at": k.revoked_at.isoformat(timespec="seconds") if k.revoked_at else None,
            }
            for k in list_keys(session)
        ]
    if json_output:
        print_json(rows)
        return
    table = Table("id", "role", "fleet", "name", "prefix", "created", "revoked")
    # The ids are what `keys revoke` takes: never cut, even on a narrow terminal.
    table.columns[0].no_wrap = True
    table.columns[0].min_width = max((len(r["id"]) for r in rows), default=2)
    for r in rows:
        table.add_row(
            r["id"],
            r["role"],
            r["fleet"],
            r["name"] or "",
            r["prefix"] + "…",
            r["created_at"],
            r["revoked_at"] or "",
        )
    stdout_console().print(table)


@keys.command("revoke")
def keys_revoke(key_id: Annotated[str, typer.Argument(help="The key's id (keys list).")]) -> None:
    """Revoke a key: its requests get 401 from now on. Revoking a revoked key changes nothing.
    Exit 2 if there is no such key."""
    from app.services.auth import revoke_key

    try:
        with open_database(load_settings()) as database, database.transaction() as session:
            key, changed = revoke_key(session, key_id)
    except AppError as exc:
        tell(exc.detail, "red")
        raise typer.Exit(2) from None
    if not changed:
        assert key.revoked_at is not None
        tell(
            f"Key {key_id} was already revoked at "
            f"{key.revoked_at.isoformat(timespec='seconds')}; nothing changed."
        )
        return
    tell(f"Revoked {key_id}: its requests get 401 from now on.")
