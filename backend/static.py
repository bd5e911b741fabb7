"""The built front end (``frontend/dist``) served by the backend: no CDN, no separate server.

- ``/assets/*``: Vite's content-hashed bundles, cached for a year.
- ``/overlay``: the patient's game page (its data comes through the scoped WebSocket).
- Any other ``GET`` outside ``/api``: the dashboard's ``index.html`` (a single-page app
  routes in the browser), or a file of the dist root (``favicon.svg``).

The fallback is a 404 handler rather than a catch-all route, so routes added later (the
live WebSockets) are never shadowed, whatever the order in which they are mounted, and a
404 under ``/api`` stays a JSON error. The pages hold no data: every API call and the live
feed check the session cookie or the overlay token.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.responses import FileResponse, HTMLResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import Scope

log = logging.getLogger(__name__)

DEFAULT_DIST = Path(__file__).resolve().parent.parent / "frontend" / "dist"

# Everything comes from the service itself. The one exception is the 3D view (viser), which
# the dashboard embeds in a frame from its own port on the same host: frame-src names that
# host (any port), taken from the request, never any other host.
CSP_BASE = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'self'; frame-ancestors 'self'; "
    "object-src 'none'; base-uri 'self'; form-action 'self'"
)
_HOSTNAME = re.compile(r"^[A-Za-z0-9](?:[A-Za-z0-9.-]{0,251}[A-Za-z0-9])?$")


def content_security_policy(hostname: str | None) -> str:
    """The pages' policy: ``'self'`` only, plus frames from ``hostname`` on any port (the
    3D view's own port). A host name that is not a plain DNS name or IPv4 address (an IPv6
    literal, garbage in the Host header) gets ``frame-src 'self'`` (the 3D view then works
    only behind a reverse proxy that serves it under the same origin)."""
    frames = "frame-src 'self'"
    if hostname and _HOSTNAME.match(hostname) and ".." not in hostname:
        frames += f" http://{hostname}:* https://{hostname}:*"
    return f"{CSP_BASE}; {frames}"


def page_headers(hostname: str | None) -> dict[str, str]:
    return {
        "Cache-Control": "no-cache",
        "Content-Security-Policy": content_security_policy(hostname),
        "X-Content-Type-Options": "nosniff",
        "Referrer-Policy": "no-referrer",  # the overlay's URL carries its token
    }


NOT_BUILT = """<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>Dashboard not built</title></head><body style="font:18px system-ui;margin:3rem">
<h1>The dashboard is not built</h1>
<p>Run <code>frontend/build.sh</code> (Node 20 and npm), then reload this page.
The API is at <a href="/api/docs">/api/docs</a>.</p></body></html>"""


class _HashedAssets(StaticFiles):
    """Vite's ``assets/`` are content-hashed: cache them for good."""

    async def get_response(self, path: str, scope: Scope) -> Response:
        response = await super().get_response(path, scope)
        if response.status_code == 200:
            response.headers["Cache-Control"] = "public, max-age=31536000, immutable"
            response.headers["X-Content-Type-Options"] = "nosniff"
        return response


def _page(dist: Path, name: str, request: Request) -> Response:
    path = dist / name
    if not path.is_file():
        return HTMLResponse(NOT_BUILT, status_code=503, headers={"Cache-Control": "no-store"})
    return FileResponse(path, media_type="text/html", headers=page_headers(request.url.hostname))


def _root_file(dist: Path, rel: str) -> Path | None:
    """A file directly in the dist root (favicon), never outside it."""
    if not rel or "/" in rel or rel.startswith("."):
        return None
    path = dist / rel
    if path.suffix == ".html" or not path.is_file():
        return None
    return path


def frontend_response(dist: Path, request: Request) -> Response | None:
    """What the front end answers for this request, or ``None`` if it is not its business."""
    if request.method not in {"GET", "HEAD"}:
        return None
    path = request.url.path
    if path == "/api" or path.startswith("/api/"):
        return None
    if path in {"/overlay", "/overlay/", "/overlay.html"}:
        return _page(dist, "overlay.html", request)
    file = _root_file(dist, path.lstrip("/"))
    if file is not None:
        return FileResponse(file, headers={"Cache-Control": "public, max-age=3600"})
    if path.startswith("/assets/"):
        return None  # a missing bundle is a real 404, not the app
    return _page(dist, "index.html", request)


def install_frontend(app: FastAPI, dist: Path | None = None) -> None:
    """Serve the built dashboard and overlay from ``dist`` (default ``frontend/dist``)."""
    root = (dist or DEFAULT_DIST).resolve()
    if (root / "index.html").is_file() and (root / "assets").is_dir():
        app.mount("/assets", _HashedAssets(directory=root / "assets"), name="assets")
    else:
        log.warning("front end not built (%s missing): run frontend/build.sh", root / "index.html")

    async def not_found(request: Request, exc: Any) -> Response:
        if isinstance(exc, StarletteHTTPException) and exc.status_code == 404:
            response = frontend_response(root, request)
            if response is not None:
                return response
        return await http_exception_handler(request, exc)

    app.add_exception_handler(StarletteHTTPException, not_found)
