"""The FastAPI application: ``create_app(settings)``.

The lifespan opens what the service holds, in order, and closes it in reverse: storage
(migrations, first admin, sessions left over from a crash) and auth first, then the live
side (Zenoh, pipelines, viser) in the marked places.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from anyio import CapacityLimiter
from fastapi import Depends, FastAPI, WebSocket, WebSocketException, status
from fastapi.exceptions import WebSocketRequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from starlette.websockets import WebSocketState

from backend.auth.first_admin import ensure_first_admin
from backend.auth.guards import current_therapist
from backend.auth.ratelimit import LoginLimiter
from backend.auth.secret import load_or_create_secret
from backend.auth.tokens import TokenSigner
from backend.db.devices import mark_all_devices_offline
from backend.db.engine import Database
from backend.db.sessions import interrupt_active_sessions
from backend.deps import AppState
from backend.live.gateway import make_live
from backend.live.lease import held_devices
from backend.live.manager import LiveManager
from backend.routers import api_router, exports, live
from backend.routers import viz as viz_router
from backend.security import harden
from backend.settings import Settings, get_settings
from backend.static import install_frontend
from backend.viz import Viz

log = logging.getLogger(__name__)


async def open_storage(settings: Settings) -> AppState:
    """Data dir, database at ``head``, secret, first admin; mark crash leftovers."""
    # Private: the database and recordings hold patient data.
    settings.data_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    database = Database(settings.db_url)
    try:
        await database.migrate()
        state = AppState(
            settings=settings,
            database=database,
            signer=TokenSigner(load_or_create_secret(settings)),
            limiter=LoginLimiter(settings.login_max_failures, settings.login_window_s),
            password_slots=CapacityLimiter(settings.password_hash_concurrency),
        )
        async with database.transaction() as db:
            state.first_admin = await ensure_first_admin(db, settings)
            # sessions of devices a worker process still holds go on (backend.live.lease)
            running = await held_devices(db)
            state.interrupted_sessions = await interrupt_active_sessions(db, running)
            await mark_all_devices_offline(db)
    except BaseException:
        await database.dispose()
        raise
    if state.first_admin is not None:
        log.warning(
            "created admin account %r; credentials in %s",
            state.first_admin.username,
            settings.admin_credentials_file,
        )
    if state.interrupted_sessions:
        log.warning("sessions interrupted by the last shutdown: %s", state.interrupted_sessions)
    return state


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    state = await open_storage(settings)
    app.state.rehab = state
    manager: LiveManager | None = None
    try:
        # ---- [live] 1. Zenoh session and 2. pipeline manager (LiveManager opens Zenoh,
        #      then runs one worker per device; it implements backend.deps.LiveHooks).
        #      `rehab serve` requires Zenoh; elsewhere (tests, tools) a busy endpoint
        #      leaves the service running without live data, with an error logged.
        manager = make_live(settings, state.database, state.interrupted_sessions)
        await manager.start(require_zenoh=getattr(app.state, "live_required", False))
        state.live = manager
        # ---- [live] 3. viser server starts here.
        # ---- [ui] 3D view (backend/viz.py): created here, its server starts on first use
        #      (GET/PUT /api/viz); the live side feeds it with app.state.viz.update(device, rows).
        app.state.viz = Viz(
            host=settings.viser_host or "127.0.0.1",  # browsers go through /api/viz/view/
            port=settings.viser_port,
            enabled=settings.viser_enabled,
        )
        manager.viz = app.state.viz  # [live] feeds the 3D view with the dashboard's rows
        yield
    finally:
        # ---- [live] close in reverse order: 3. viser, 2. pipelines (finish sessions,
        #      flush recordings), 1. Zenoh.
        # ---- [ui] 3D view
        viz: Viz | None = getattr(app.state, "viz", None)
        if viz is not None:
            viz.close()
            del app.state.viz
        if manager is not None:
            await manager.close()
        del app.state.rehab
        await state.database.dispose()


async def _refuse_websocket(websocket: WebSocket, exc: Exception) -> None:
    """A refused WebSocket (no or bad credentials, a dead overlay link, bad parameters, the
    live side down) ends with its documented close code (1008, 1013) after the handshake:
    refused during it, a browser sees only HTTP 403 and close code 1006, and the overlay
    could not tell a dead link from a broken network."""
    if isinstance(exc, WebSocketException):
        code, reason = exc.code, exc.reason or ""
    else:  # the parameters did not validate
        code, reason = status.WS_1008_POLICY_VIOLATION, "invalid parameters"
    if websocket.application_state == WebSocketState.DISCONNECTED:
        return
    if websocket.client_state == WebSocketState.CONNECTING:
        await websocket.accept()
    await websocket.close(code=code, reason=reason[:120])


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()
    app = FastAPI(
        title="rehab-tracking",
        summary="Real-time shoulder-compensation feedback for robot-assisted arm therapy.",
        lifespan=lifespan,
        openapi_url="/api/openapi.json",
        docs_url="/api/docs" if settings.api_docs else None,  # Swagger UI comes from a CDN
        redoc_url=None,
    )
    app.state.settings = settings
    app.add_exception_handler(WebSocketException, _refuse_websocket)
    app.add_exception_handler(WebSocketRequestValidationError, _refuse_websocket)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_credentials=True,
            allow_methods=["*"],
            allow_headers=["*"],
        )
    harden(app, settings)  # body limit, Origin checks, headers, proxy address (security.py)
    app.include_router(api_router)
    # ---- [live] WebSocket feeds (they guard themselves) and exports (therapists only)
    app.include_router(live.router, prefix="/api")
    app.include_router(exports.router, prefix="/api", dependencies=[Depends(current_therapist)])
    # ---- [ui] the 3D view's API, and the built front end (dashboard at /, overlay at
    #      /overlay); the front end answers through a 404 handler, so it never shadows
    #      routes added after this line.
    app.include_router(viz_router.router)
    install_frontend(app)
    return app
