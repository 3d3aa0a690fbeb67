"""The admin console: web pages at ``/admin`` over the services behind the v1 API.

``mount_console(app)`` adds the pages and their static files (bundled here, nothing is loaded from
elsewhere: care homes and robots often run without internet). Only ``app.main`` imports this
package.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from .routes import router

__all__ = ["mount_console"]

STATIC = Path(__file__).parent / "static"


def mount_console(app: FastAPI) -> None:
    """Serve the console's static files at ``/admin/static`` and its pages at ``/admin``."""
    # Before the router: its catch-all 404 page would otherwise shadow the static files.
    app.mount("/admin/static", StaticFiles(directory=STATIC), name="console-static")
    app.include_router(router)
