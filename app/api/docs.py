"""``/docs`` (Swagger UI) and ``/redoc`` (Redoc), with their scripts and styles served by the
service itself from ``/static/docs/`` (``app/api/static/docs``, vendored with their licences):
the pages work where there is no internet, as robots' and care homes' networks often are.

Both pages carry a Content-Security-Policy that lets them load nothing from elsewhere, so a
browser that can reach the internet sends it nothing either. Neither page asks for anything
from elsewhere in the first place: the vendored Redoc bundle has its sidebar's logo, which it
would fetch from its maker's CDN, left out (``static/docs/redoc/README.md``).
"""

from __future__ import annotations

import base64
import hashlib
import re
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

from app.logs import REQUEST_ID_PATTERN

__all__ = ["REQUEST_ID_HEADER", "STATIC_URL", "install_docs"]

STATIC = Path(__file__).parent / "static" / "docs"
STATIC_URL = "/static/docs"
REQUEST_ID_HEADER = {
    "description": "The request's id: the caller's X-Request-ID when it sent a valid one (1 to "
    "128 letters, digits and . _ : -), else one made by the service (32 "
    "lowercase hexadecimal characters). Error bodies carry it as request_id.",
    "schema": {"type": "string", "pattern": REQUEST_ID_PATTERN},
}


def _csp(html: bytes) -> str:
    """A policy allowing the page's own files and its inline scripts, by their hashes."""
    hashes = " ".join(
        "'sha256-" + base64.b64encode(hashlib.sha256(script).digest()).decode() + "'"
        for script in re.findall(rb"<script>(.*?)</script>", html, flags=re.S)
    )
    return (
        f"default-src 'self'; script-src 'self' {hashes}; ".replace(" ;", ";")
        # Both render with inline styles; Redoc searches in a worker made from a blob.
        + "style-src 'self' 'unsafe-inline'; img-src 'self' data:; font-src 'self' data:; "
        "worker-src 'self' blob:; connect-src 'self'; object-src 'none'; "
        "base-uri 'none'; frame-ancestors 'none'"
    )


def _page(response: HTMLResponse) -> HTMLResponse:
    response.headers["Content-Security-Policy"] = _csp(bytes(response.body))
    response.headers["X-Content-Type-Options"] = "nosniff"
    return response


def _with_request_id(app: FastAPI) -> None:
    """Declare the X-Request-ID header on every response of the OpenAPI document."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        schema = generate()  # FastAPI's own, cached until the routes change
        for item in schema.get("paths", {}).values():
            for operation in item.values():
                for response in operation.get("responses", {}).values():
                    response.setdefault("headers", {}).setdefault("X-Request-ID", REQUEST_ID_HEADER)
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def install_docs(app: FastAPI) -> None:
    """Serve the two documentation pages of ``app.openapi_url`` and their assets (the app is
    made with ``docs_url=None, redoc_url=None``, so FastAPI's CDN-loading pages are off)."""
    _with_request_id(app)
    app.mount(STATIC_URL, StaticFiles(directory=STATIC), name="docs-static")
    openapi_url = app.openapi_url or "/openapi.json"

    # Behind a proxy on a prefix (ATTUNE_ROOT_PATH), the pages load the schema and their files
    # from under the prefix; the schema's `servers` names it too (FastAPI adds it).
    def root(request: Request) -> str:
        return str(request.scope.get("root_path", "")).rstrip("/")

    @app.get("/docs", include_in_schema=False)
    def swagger_ui(request: Request) -> HTMLResponse:
        static = root(request) + STATIC_URL
        return _page(
            get_swagger_ui_html(
                openapi_url=root(request) + openapi_url,
                title=f"{app.title} API",
                swagger_js_url=f"{static}/swagger-ui/swagger-ui-bundle.js",
                swagger_css_url=f"{static}/swagger-ui/swagger-ui.css",
                swagger_favicon_url=f"{static}/swagger-ui/favicon-32x32.png",
                oauth2_redirect_url=None,
                # No validator badge: it would send the schema to an online validator.
                swagger_ui_parameters={"validatorUrl": None},
            )
        )

    @app.get("/redoc", include_in_schema=False)
    def redoc(request: Request) -> HTMLResponse:
        static = root(request) + STATIC_URL
        return _page(
            get_redoc_html(
                openapi_url=root(request) + openapi_url,
                title=f"{app.title} API reference",
                redoc_js_url=f"{static}/redoc/redoc.standalone.js",
                redoc_favicon_url=f"{static}/swagger-ui/favicon-32x32.png",
                with_google_fonts=False,
            )
        )
