"""API keys: random secrets shown once, stored as SHA-256, with a role and a fleet."""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets

from sqlalchemy.orm import Session

from app.db.repositories import keys as repo
from app.db.repositories.keys import KeyRow
from app.db.types import utcnow
from app.errors import Forbidden, NotFound, Unauthorized, ValidationFailed
from app.schemas.common import DOT_SEGMENTS

from . import audit
from .context import KeyCache, Principal, after_commit

__all__ = [
    "ROLES",
    "authenticate",
    "bearer_digest",
    "create_key",
    "hash_secret",
    "list_keys",
    "require_admin",
    "require_manager",
    "revoke_key",
]

ROLES = ("robot", "staff", "admin")
_FLEET = re.compile(r"^[A-Za-z0-9._:-]{1,128}$")
SECRET_PREFIX = "att_"


def hash_secret(secret: str) -> str:
    # The secrets carry 256 random bits, so a plain SHA-256 is enough (no password stretching).
    return hashlib.sha256(secret.encode("utf-8")).hexdigest()


def create_key(
    session: Session,
    *,
    role: str,
    fleet: str = "default",
    name: str | None = None,
    actor: Principal | None = None,
) -> tuple[KeyRow, str]:
    """A new key and its secret; the secret is not stored and cannot be shown again.

    ``actor`` is the admin making it (``None``: an operator on the command line); the audit log
    records who made which key.
    """
    actor = actor or audit.CLI
    require_admin(actor)
    if role not in ROLES:
        raise ValidationFailed(f"role must be one of {', '.join(ROLES)}; got {role!r}.")
    if not _FLEET.match(fleet) or fleet in DOT_SEGMENTS:
        raise ValidationFailed(
            "fleet must match ^[A-Za-z0-9._:-]{1,128}$ and be neither '.' nor '..' (in a URL "
            "path they mean this path and the one above it)."
        )
    secret = SECRET_PREFIX + secrets.token_urlsafe(32)
    key = KeyRow(
        id="key_" + secrets.token_hex(8),
        prefix=secret[:12],
        secret_hash=hash_secret(secret),
        role=role,
        fleet=fleet,
        name=name,
        created_at=utcnow(),
        revoked_at=None,
    )
    repo.add(session, key)
    audit.record(
        session,
        actor,
        "key.create",
        target=key.id,
        fleet=fleet,
        detail={"role": role, "name": name},
    )
    return key, secret


def list_keys(session: Session) -> list[KeyRow]:
    return repo.list_all(session)


def revoke_key(
    session: Session, key_id: str, *, actor: Principal | None = None, keys: KeyCache | None = None
) -> tuple[KeyRow, bool]:
    """Revoke a key (its requests get 401 from now on); ``actor`` as for ``create_key``.
    Returns the key and whether this call revoked it (False: it was revoked already).

    ``keys``: the calling worker's key cache, which forgets the key once this commits (other
    workers, and a revocation from the command line, wait out their cache's bound)."""
    actor = actor or audit.CLI
    require_admin(actor)
    key = repo.get(session, key_id)
    if key is None:
        raise NotFound(
            f"No key {key_id!r}; GET /v1/admin/keys and `attune keys list` show the ids."
        )
    if key.revoked_at is None:
        key.revoked_at = utcnow()
        repo.revoke(session, key.id, key.revoked_at)
        audit.record(session, actor, "key.revoke", target=key.id, fleet=key.fleet)
        if keys is not None:
            cache = keys
            after_commit(session, lambda: cache.drop(key_id))
        return key, True
    return key, False


def bearer_digest(authorization: str | None) -> str:
    """The SHA-256 of the key in an ``Authorization: Bearer <key>`` header (401 if none)."""
    if not authorization:
        raise Unauthorized("Send your API key as 'Authorization: Bearer <key>'.")
    scheme, _, secret = authorization.partition(" ")
    if scheme.lower() != "bearer" or not secret.strip():
        raise Unauthorized("Send your API key as 'Authorization: Bearer <key>'.")
    return hash_secret(secret.strip())


def authenticate(session: Session, authorization: str | None) -> Principal:
    """The caller of a request from its ``Authorization: Bearer <key>`` header."""
    digest = bearer_digest(authorization)
    key = repo.by_hash(session, digest)
    # The lookup goes through the unique index on the SHA-256 of the secret, so what the
    # database compares (and what its timing could reveal) is the digest, never the secret: a
    # prefix of a digest says nothing about the secret that makes it. The final equality is
    # checked with compare_digest, whose time does not depend on where two values differ, so
    # no step of the check compares the secret itself byte by byte with an early exit.
    if (
        key is None
        or not hmac.compare_digest(key.secret_hash, digest)
        or key.revoked_at is not None
    ):
        raise Unauthorized("Unknown or revoked API key.")
    return Principal(key.id, key.role, key.fleet)


def require_admin(principal: Principal) -> None:
    """Deployment-wide actions (keys, fleets): admins only."""
    if not principal.is_admin:
        raise Forbidden("This needs an admin key.")


def require_manager(principal: Principal) -> None:
    """Looking after a fleet's users (reset, export, import, delete, the audit log): the
    fleet's staff, and admins."""
    if not principal.manages:
        raise Forbidden("This needs a staff or admin key.")
