"""Who is using the console: an admin key, entered once, kept in a browser-session cookie.

The cookie holds the key itself (HttpOnly, SameSite=Strict, no Max-Age: it ends with the browser
session) and every request authenticates it again through ``app.services.auth.authenticate``, the
service the v1 API uses, so a revoked key stops working at the next click. State-changing POSTs
carry a CSRF token derived from the key (an HMAC, so the page never shows the key) and must come
from the console's own origin.
"""

from __future__ import annotations

import hashlib
import hmac
from dataclasses import dataclass
from typing import Annotated
from urllib.parse import parse_qsl, urlsplit

from fastapi import Depends, Request

from app import logs
from app.api.deps import SessionDep, single_read
from app.errors import Forbidden, Unauthorized
from app.services.auth import authenticate, require_admin
from app.services.context import Principal

__all__ = ["COOKIE", "Admin", "AdminDep", "FormDep", "LoginRequired", "PageError", "check_post",
           "csrf_token", "safe_next", "sign_in"]

COOKIE = "attune_console"
COOKIE_PATH = "/admin"
_CSRF_CONTEXT = b"attune console csrf v1"
_MAX_FIELDS = 20


class LoginRequired(Exception):
    """No session yet: the page sends the browser to the login form (then back to ``next``)."""

    def __init__(self, next_path: str) -> None:
        super().__init__(next_path)
        self.next_path = next_path


class PageError(Exception):
    """A refusal shown as a page: status, a title and a sentence a person can act on."""

    def __init__(self, status: int, title: str, detail: str, *, sign_out: bool = False) -> None:
        super().__init__(detail)
        self.status, self.title, self.detail, self.sign_out = status, title, detail, sign_out


@dataclass(frozen=True, slots=True)
class Admin:
    principal: Principal
    csrf: str


def csrf_token(secret: str) -> str:
    return hmac.new(secret.encode("utf-8"), _CSRF_CONTEXT, hashlib.sha256).hexdigest()


def sign_in(session: SessionDep, secret: str) -> Principal:
    """The admin behind ``secret``; 401 for an unknown or revoked key, 403 for a robot key."""
    try:
        principal = authenticate(session, f"Bearer {secret}")
    except Unauthorized:
        raise PageError(401, "Unknown or revoked key",
                        "This key is not known to the service, or it was revoked. Sign in with "
                        "an admin key (attune keys create --role admin).", sign_out=True) from None
    try:
        require_admin(principal)
    except Forbidden:
        raise PageError(403, "An admin key is needed",
                        f"This is a {principal.role} key: robots may use the API, but the console "
                        "needs an admin key (attune keys create --role admin).",
                        sign_out=True) from None
    return principal


def current_admin(request: Request) -> Admin:
    """The signed-in admin (the key is read by a statement of its own, as for the API's
    keys)."""
    secret = request.cookies.get(COOKIE)
    if not secret:
        path = request.url.path + (f"?{request.url.query}" if request.url.query else "")
        raise LoginRequired(path)
    with single_read(request) as session:
        principal = sign_in(session, secret)
    ctx = logs.current()
    if ctx is not None:  # for the access line
        ctx.key_id = principal.key_id
    return Admin(principal, csrf_token(secret))


AdminDep = Annotated[Admin, Depends(current_admin)]


async def form_fields(request: Request) -> dict[str, str]:
    """An ``application/x-www-form-urlencoded`` body as a dict (the console's forms are small;
    the service's body limit applies)."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind != "application/x-www-form-urlencoded":
        raise PageError(415, "Not a form", "This page takes a submitted form.")
    body = await request.body()
    try:
        pairs = parse_qsl(body.decode("utf-8"), keep_blank_values=True,
                          max_num_fields=_MAX_FIELDS, strict_parsing=False)
    except (UnicodeDecodeError, ValueError):
        raise PageError(400, "Bad form", "The form could not be read; reload the page.") from None
    return dict(pairs)


FormDep = Annotated[dict[str, str], Depends(form_fields)]


def same_origin(request: Request) -> bool:
    """False when the browser says the request comes from another site (Origin or
    Sec-Fetch-Site); requests without either (command-line clients) are left to the token."""
    site = request.headers.get("sec-fetch-site")
    if site is not None and site not in ("same-origin", "none"):
        return False
    origin = request.headers.get("origin")
    if origin is not None and origin != "null":
        return urlsplit(origin).netloc == request.headers.get("host")
    return origin is None


def check_post(request: Request, admin: Admin, form: dict[str, str]) -> None:
    """Refuse a state-changing POST that did not come from one of the console's own pages."""
    token = form.get("csrf", "")
    if not same_origin(request) or not hmac.compare_digest(token, admin.csrf):
        raise PageError(403, "Request refused",
                        "This action did not come from a console page (its security token is "
                        "missing or stale). Go back, reload the page and try again.")


def safe_next(path: str | None) -> str:
    """Where to go after signing in: a console path only (no open redirect)."""
    if not path or not path.startswith(COOKIE_PATH + "/") or path.startswith("//") \
            or "\\" in path or any(ord(ch) < 32 for ch in path):
        return f"{COOKIE_PATH}/users"
    return path
