"""HTTP hardening around the app (docs/security.md): the client address behind the clinic's
proxy, bounded request bodies, Origin checks, response headers, validation errors that echo
nothing, and overlay tokens kept out of the logs.

All are plain ASGI middlewares: a body is refused while it arrives, never buffered first.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterable
from typing import Any
from urllib.parse import urlsplit

import orjson
from fastapi import FastAPI, HTTPException, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from uvicorn.middleware.proxy_headers import ProxyHeadersMiddleware

from backend.settings import Settings

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
MAX_ERRORS = 20  # validation errors reported per request
MAX_MSG = 200


async def _reply(send: Send, code: int, detail: str) -> None:
    body = orjson.dumps({"detail": detail})
    await send(
        {
            "type": "http.response.start",
            "status": code,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"x-content-type-options", b"nosniff"),
                (b"cache-control", b"no-store"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", ()):
        if key == name:
            return bytes(value).decode("latin-1")
    return None


class BodyTooLarge(HTTPException):
    def __init__(self) -> None:
        super().__init__(status.HTTP_413_CONTENT_TOO_LARGE, "request body too large")


class BodyLimit:
    """413 for a body over ``max_bytes``: at once if Content-Length says so, else as soon as
    the received chunks pass it (the rest is never read)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = _header(scope, b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.max_bytes):
            await _reply(send, status.HTTP_413_CONTENT_TOO_LARGE, "request body too large")
            return
        received = 0
        started = False

        async def limited() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise BodyTooLarge()  # an HTTPException: FastAPI answers 413
            return message

        async def tracked(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, limited, tracked)
        except BodyTooLarge:
            if not started:  # read outside a route (a middleware): answer here
                await _reply(send, status.HTTP_413_CONTENT_TOO_LARGE, "request body too large")


class OriginCheck:
    """Browsers name the page that sent a request. A state change (POST, PUT, PATCH, DELETE)
    or a WebSocket from another site is refused: 403, or close 1008 for a WebSocket.

    Allowed: the service's own origin (Origin's host equals Host), ``cors_origins``, and
    requests without Origin and without ``Sec-Fetch-Site: cross-site|same-site`` (scripts,
    curl: no browser, so no ambient cookie to abuse)."""

    def __init__(self, app: ASGIApp, allowed: Iterable[str]) -> None:
        self.app = app
        self.allowed = frozenset(o.rstrip("/").lower() for o in allowed)

    def _ok(self, scope: Scope) -> bool:
        origin = _header(scope, b"origin")
        if origin is not None:
            origin = origin.strip().rstrip("/").lower()
            if origin in self.allowed:
                return True
            host = (_header(scope, b"host") or "").strip().lower()
            parts = urlsplit(origin)
            return parts.scheme in ("http", "https") and bool(host) and parts.netloc == host
        site = (_header(scope, b"sec-fetch-site") or "").strip().lower()
        return site not in ("cross-site", "same-site")

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] not in SAFE_METHODS:
            if not self._ok(scope):
                await _reply(send, status.HTTP_403_FORBIDDEN, "cross-origin request refused")
                return
        elif scope["type"] == "websocket" and not self._ok(scope):
            # Accepted, then closed: the page sees 1008 like any other refusal.
            await receive()
            await send({"type": "websocket.accept"})
            await send({"type": "websocket.close", "code": 1008, "reason": "origin not allowed"})
            return
        await self.app(scope, receive, send)


class SecurityHeaders:
    """nosniff and no referrer everywhere; ``Cache-Control: no-store`` on the API (patient
    data must not stay in a shared workstation's cache). HSTS is the TLS proxy's job."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        api = str(scope.get("path", "")).startswith("/api/")

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = [
                    (k, v)
                    for k, v in message.get("headers", [])
                    if not (api and k.lower() == b"cache-control")
                ]
                present = {k.lower() for k, _ in headers}
                # the pages set their own (backend/static.py): added where missing, never twice
                for name, value in ((b"x-content-type-options", b"nosniff"),
                                    (b"referrer-policy", b"no-referrer")):  # fmt: skip
                    if name not in present:
                        headers.append((name, value))
                if api:
                    headers.append((b"cache-control", b"no-store"))
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers)


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """422 with where and why, never the input (a 5 MB field must not come back)."""
    errors: list[dict[str, Any]] = []
    if isinstance(exc, RequestValidationError):
        for e in exc.errors()[:MAX_ERRORS]:
            errors.append(
                {
                    "type": str(e.get("type", "")),
                    "loc": [x if isinstance(x, int) else str(x)[:64] for x in e.get("loc", ())],
                    "msg": str(e.get("msg", ""))[:MAX_MSG],
                }
            )
    return JSONResponse({"detail": errors}, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


_TOKEN = re.compile(r"(token=)[^&\s\"']+")


class RedactTokens(logging.Filter):
    """Overlay links carry their token in the query (``?token=``): uvicorn's access log
    (and its WebSocket "accepted" lines) would keep it; the value becomes ``[redacted]``."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple) and any(
            isinstance(a, str) and "token=" in a for a in record.args
        ):
            record.args = tuple(
                _TOKEN.sub(r"\1[redacted]", a) if isinstance(a, str) else a for a in record.args
            )
        if isinstance(record.msg, str) and "token=" in record.msg:
            record.msg = _TOKEN.sub(r"\1[redacted]", record.msg)
        return True


def install_log_redaction() -> None:
    for name in ("uvicorn.access", "uvicorn.error"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactTokens) for f in logger.filters):
            logger.addFilter(RedactTokens())


def harden(app: FastAPI, settings: Settings) -> None:
    """Install the above on ``app``. Middlewares added last run first: the proxy's client
    address, then the body limit, the Origin check and the headers."""
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_middleware(SecurityHeaders)
    app.add_middleware(OriginCheck, allowed=settings.cors_origins)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(ProxyHeadersMiddleware, trusted_hosts=settings.forwarded_allow_ips)
    install_log_redaction()
