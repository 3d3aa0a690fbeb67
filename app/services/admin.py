"""The deployment's administration over HTTP: API keys and the fleets (admin keys only).

Keys are made, listed and revoked through the same use cases as ``attune keys ...``, so both are
audited alike; a key revoked here stops at once in the worker that revoked it (the others, and
keys revoked on the command line, within ``ATTUNE_KEY_CACHE_SECONDS``).
"""

from __future__ import annotations

from sqlalchemy.orm import Session

from app.db.repositories import keys as keys_repo
from app.db.repositories import users as users_repo
from app.db.repositories.keys import KeyRow
from app.schemas.admin import FleetList, FleetOut, KeyCreated, KeyIn, KeyList, KeyOut

from .auth import create_key, list_keys, require_admin, revoke_key
from .context import Principal, ServiceContext

__all__ = ["add_key", "fleets", "keys", "remove_key"]


def _out(key: KeyRow) -> KeyOut:
    return KeyOut(
        key_id=key.id,
        role=key.role,
        fleet=key.fleet,
        name=key.name,
        prefix=key.prefix,
        created_at=key.created_at,
        revoked_at=key.revoked_at,
    )


def add_key(session: Session, principal: Principal, body: KeyIn) -> KeyCreated:
    """A new key; its secret is in this answer only."""
    require_admin(principal)
    key, secret = create_key(
        session, role=body.role, fleet=body.fleet, name=body.name, actor=principal
    )
    return KeyCreated(**_out(key).model_dump(), secret=secret)


def keys(session: Session, principal: Principal) -> KeyList:
    require_admin(principal)
    return KeyList(items=[_out(k) for k in list_keys(session)])


def remove_key(session: Session, ctx: ServiceContext, principal: Principal, key_id: str) -> None:
    """Revoke a key; revoking a revoked key changes nothing (404: no such key)."""
    require_admin(principal)
    revoke_key(session, key_id, actor=principal, keys=ctx.keys)


def fleets(session: Session, principal: Principal) -> FleetList:
    """Every fleet that has users or live keys, with their counts."""
    require_admin(principal)
    users = users_repo.fleet_counts(session)
    live = keys_repo.live_counts(session)
    names = sorted(set(users) | set(live))
    return FleetList(
        items=[
            FleetOut(
                fleet=f,
                users=users.get(f, (0, 0))[0],
                keys=live.get(f, 0),
                episodes=users.get(f, (0, 0))[1],
            )
            for f in names
        ]
    )
