"""Route guards: the logged-in therapist, admins only, and the overlay's scoped token."""

from __future__ import annotations

import asyncio
import json
from typing import Annotated, NamedTuple

from fastapi import Depends, HTTPException, WebSocket, WebSocketException, status
from fastapi.security import HTTPBearer
from sqlalchemy import select
from starlette.requests import HTTPConnection
from starlette.websockets import WebSocketDisconnect

from backend.auth.logins import login_alive, touch
from backend.auth.tokens import InvalidToken
from backend.db.base import utcnow
from backend.db.models import Device, Login, Session, Therapist
from backend.deps import DB, AppState, State


class _BearerToken(HTTPBearer):
    """The bearer token if any, on HTTP and WebSocket alike (HTTPBearer itself wants a
    Request); still a security scheme, so the OpenAPI documents it."""

    async def __call__(self, conn: HTTPConnection) -> str | None:  # type: ignore[override]
        scheme, _, token = conn.headers.get("authorization", "").partition(" ")
        return (token.strip() or None) if scheme.lower() == "bearer" else None


_bearer = _BearerToken(
    scheme_name="bearer", auto_error=False, description="Access token from POST /api/auth/login"
)


def _unauthorized(conn: HTTPConnection, detail: str) -> Exception:
    if conn.scope["type"] == "websocket":
        return WebSocketException(status.WS_1008_POLICY_VIOLATION, detail)
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail, headers={"WWW-Authenticate": "Bearer"}
    )


async def current_therapist(
    conn: HTTPConnection, state: State, db: DB, bearer: Annotated[str | None, Depends(_bearer)]
) -> Therapist:
    """The active therapist behind the bearer token, else behind the session cookie.

    The token's login must be alive (not revoked, not idle: :mod:`backend.auth.logins`); its
    id is left in ``conn.state.login_id`` for logout and the WebSockets. Works for WebSocket
    routes too (the browser sends the cookie with the upgrade request); there a refusal
    closes with 1008.
    """
    token = bearer or conn.cookies.get(state.settings.cookie_name)
    if not token:
        raise _unauthorized(conn, "not authenticated")
    try:
        therapist_id, login_id = state.signer.decode_access(token)
    except InvalidToken:
        raise _unauthorized(conn, "invalid or expired token") from None
    login = await db.get(Login, login_id)
    now = utcnow()
    if login is None or not login_alive(login, therapist_id, state.settings.session_idle_s, now):
        await db.commit()
        raise _unauthorized(conn, "logged out, revoked or idle too long")
    touch(login, now)
    therapist = await db.get(Therapist, therapist_id)
    # End the transaction: the connection goes back to the pool (a WebSocket route would
    # otherwise hold it for its whole life); the objects stay loaded and attached.
    await db.commit()
    if therapist is None or not therapist.active:
        raise _unauthorized(conn, "account unknown or deactivated")
    conn.state.login_id = login_id
    return therapist


async def login_still_valid(state: AppState, therapist_id: int, login_id: str) -> bool:
    """For open WebSockets, now and then: the login alive (an open live view counts as use)
    and the account active."""
    async with state.database.transaction() as db:
        login = await db.get(Login, login_id)
        now = utcnow()
        if login is None or not login_alive(
            login, therapist_id, state.settings.session_idle_s, now
        ):
            return False
        touch(login, now)
        therapist = await db.get(Therapist, therapist_id)
        return therapist is not None and therapist.active


CurrentTherapist = Annotated[Therapist, Depends(current_therapist)]


async def require_admin(therapist: CurrentTherapist) -> Therapist:
    if not therapist.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "administrators only")
    return therapist


AdminTherapist = Annotated[Therapist, Depends(require_admin)]


class OverlayGrant(NamedTuple):
    """What an overlay token allows: the live feedback of ``device`` during ``session_id``."""

    device: str
    session_id: int


class OverlayDenied(Exception):
    pass


async def verify_overlay_token(state: AppState, token: str) -> OverlayGrant:
    """Check signature, expiry, and that the session is still active on that device.

    Raises :class:`OverlayDenied`. A stopped or interrupted session revokes its links.
    """
    try:
        device, session_id = state.signer.decode_overlay(token)
    except InvalidToken:
        raise OverlayDenied("invalid or expired overlay token") from None
    async with state.database.session() as db:
        row = (
            await db.execute(
                select(Session.status, Device.name)
                .join(Session.device)
                .where(Session.id == session_id)
            )
        ).first()
    if row is None or row.status != "active":
        raise OverlayDenied("session is not active")
    if row.name != device:
        raise OverlayDenied("token is for another device")
    return OverlayGrant(device, session_id)


OVERLAY_AUTH_TIMEOUT_S = 5.0  # for the overlay's first message, the one with its token
OVERLAY_AUTH_MAX_CHARS = 4096
OLD_LINK = "this overlay link is of an old form (token in the address): ask for a new link"


async def overlay_grant(websocket: WebSocket, state: State) -> OverlayGrant:
    """Dependency for the overlay's WebSocket. Its token never travels in a URL (request
    lines are logged by servers and proxies): the link carries it after ``#`` (the browser
    sends no fragment), and the page sends it as the socket's first message,
    ``{"type": "auth", "token": "..."}``. The socket is therefore accepted here, and a
    refusal closes it with 1008 and the reason. A token in the query (a link of the old
    form) is refused as such."""
    if "token" in websocket.query_params:
        raise WebSocketException(status.WS_1008_POLICY_VIOLATION, OLD_LINK)
    await websocket.accept()
    try:
        text = await asyncio.wait_for(websocket.receive_text(), OVERLAY_AUTH_TIMEOUT_S)
        msg = json.loads(text) if len(text) <= OVERLAY_AUTH_MAX_CHARS else None
        token = msg.get("token") if isinstance(msg, dict) and msg.get("type") == "auth" else None
    except (TimeoutError, ValueError, KeyError, RuntimeError, WebSocketDisconnect):
        token = None  # (receive_text raises KeyError/RuntimeError on a binary or a close)
    if not isinstance(token, str) or not token:
        raise WebSocketException(status.WS_1008_POLICY_VIOLATION, "no overlay token")
    try:
        return await verify_overlay_token(state, token)
    except OverlayDenied as exc:
        raise WebSocketException(status.WS_1008_POLICY_VIOLATION, str(exc)) from None


OverlayAccess = Annotated[OverlayGrant, Depends(overlay_grant)]
