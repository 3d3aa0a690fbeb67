"""Who is using the console: a staff or admin key, entered once, kept in a browser-session
cookie.

The cookie holds the key itself (HttpOnly, SameSite=Strict, no Max-Age: it ends with the browser
session) and every request authenticates it again as the v1 API does
(``app.api.deps.principal_of``, without the workers' key cache), so a revoked key stops at
the next click.
State-changing POSTs carry a CSRF token derived from the key (an HMAC, so the page never shows
the key) and must come from the console's own origin.

Behind a reverse proxy on a prefix (``ATTUNE_ROOT_PATH``), every address the console hands the
browser (links, forms, redirects, the cookie's path) is ``console_url(request, ...)``: the
request's root path, then ``/admin``.
"""

from __future__ import annotations

import hashlib
import hmac
from dataclasses import dataclass
from typing import Annotated
from urllib.parse import parse_qsl, urlsplit

from fastapi import Depends, Request

from app.api.deps import principal_of
from app.errors import Forbidden, Unauthorized
from app.services.auth import require_manager
from app.services.context import Principal

__all__ = [
    "COOKIE",
    "Admin",
    "CONSOLE_PATH",
    "AdminDep",
    "FormDep",
    "LoginRequired",
    "PageError",
    "check_post",
    "console_url",
    "csrf_token",
    "safe_next",
    "sign_in",
]

COOKIE = "attune_console"
CONSOLE_PATH = "/admin"
"""Where the console's pages are, under the service's root path."""
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


def console_url(request: Request, path: str = "") -> str:
    """``path`` of the console (``/users``, ``""`` for the console itself) as the browser must
    ask for it: under the root path the reverse proxy serves the service on, if any (the ASGI
    ``root_path``: ``attune serve --root-path``). Also the session cookie's path."""
    scope = request.scope
    root = str(scope.get("app_root_path", scope.get("root_path", ""))).rstrip("/")
    return f"{root}{CONSOLE_PATH}{path}"


def csrf_token(secret: str) -> str:
    return hmac.new(secret.encode("utf-8"), _CSRF_CONTEXT, hashlib.sha256).hexdigest()


async def sign_in(request: Request, secret: str) -> Principal:
    """The staff member or admin behind ``secret``; 401 for an unknown or revoked key, 403 for
    a robot key. A fleet's staff see their fleet only; an admin sees every fleet.

    Read from the database on every page (not from the workers' key cache): a revoked key stops
    at the next click."""
    try:
        principal = await principal_of(request, f"Bearer {secret}", cached=False)
    except Unauthorized:
        raise PageError(
            401,
            "Unknown or revoked key",
            "This key is not known to the service, or it was revoked. Sign in with "
            "a staff or admin key (attune keys create --role staff --fleet NAME).",
            sign_out=True,
        ) from None
    try:
        require_manager(principal)
    except Forbidden:
        raise PageError(
            403,
            "A staff or admin key is needed",
            f"This is a {principal.role} key: robots may use the API, but the console "
            "needs a staff key of the fleet, or an admin key (attune keys create "
            "--role staff --fleet NAME).",
            sign_out=True,
        ) from None
    return principal


async def current_admin(request: Request) -> Admin:
    """The signed-in admin (the key is checked as the API's keys are)."""
    secret = request.cookies.get(COOKIE)
    if not secret:
        path = request.url.path + (f"?{request.url.query}" if request.url.query else "")
        raise LoginRequired(path)
    return Admin(await sign_in(request, secret), csrf_token(secret))


AdminDep = Annotated[Admin, Depends(current_admin)]


async def form_fields(request: Request) -> dict[str, str]:
    """An ``application/x-www-form-urlencoded`` body as a dict (the console's forms are small;
    the service's body limit applies)."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind != "application/x-www-form-urlencoded":
        raise PageError(415, "Not a form", "This page takes a submitted form.")
    body = await request.body()
    try:
        pairs = parse_qsl(
            body.decode("utf-8"),
            keep_blank_values=True,
            max_num_fields=_MAX_FIELDS,
            strict_parsing=False,
        )
    except (UnicodeDecodeError, ValueError):
        raise PageError(400, "Bad form", "The form could not be read; reload the page.") from None
    return dict(pairs)


FormDep = Annotated[dict[str, str], Depends(form_fields)]


_DEFAULT_PORTS = {"http": 80, "https": 443}


def _origin(scheme: str, netloc: str) -> tuple[str, str, int | None] | None:
    """``(scheme, host, port)`` with the scheme's default port filled in; None if unreadable."""
    try:
        parts = urlsplit(f"{scheme}://{netloc}")
        port = parts.port
    except ValueError:
        return None
    if not parts.hostname:
        return None
    return scheme.lower(), parts.hostname.lower(), port or _DEFAULT_PORTS.get(scheme.lower())


def same_origin(request: Request) -> bool:
    """False when the browser says the request comes from another site (Sec-Fetch-Site, or an
    Origin, else a Referer, other than the site it asked); requests with none of them
    (command-line clients) are left to the token.

    The site the browser asked is the request's scheme and Host: behind a trusted reverse
    proxy, its X-Forwarded-Proto and X-Forwarded-Host (``ProxyMiddleware`` puts them there)."""
    site = request.headers.get("sec-fetch-site")
    if site is not None and site not in ("same-origin", "none"):
        return False
    origin = request.headers.get("origin")
    if origin == "null":
        return False
    if origin is None:
        origin = request.headers.get("referer")
        if origin is None:
            return True
    try:
        given = urlsplit(origin)
    except ValueError:  # "http://[x": no origin at all
        return False
    asked = _origin(request.url.scheme, request.headers.get("host", ""))
    return asked is not None and _origin(given.scheme, given.netloc) == asked


def check_post(request: Request, admin: Admin, form: dict[str, str]) -> None:
    """Refuse a state-changing POST that did not come from one of the console's own pages."""
    token = form.get("csrf", "")
    if not same_origin(request) or not hmac.compare_digest(token, admin.csrf):
        raise PageError(
            403,
            "Request refused",
            "This action did not come from a console page (its security token is "
            "missing or stale). Go back, reload the page and try again.",
        )


def safe_next(path: str | None, console: str = CONSOLE_PATH) -> str:
    """Where to go after signing in: a path under ``console`` (``console_url(request)``) only
    (no open redirect)."""
    if (
        not path
        or not path.startswith(console + "/")
        or path.startswith("//")
        or "\\" in path
        or any(ord(ch) < 32 for ch in path)
    ):
        return f"{console}/users"
    return path
