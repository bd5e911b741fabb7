"""What route handlers depend on: the running service's state, a DB session, the settings,
and the interface through which REST reaches the live side (:class:`LiveHooks`).

Auth dependencies (``CurrentTherapist``, ``AdminTherapist``, overlay tokens) live in
:mod:`backend.auth.guards`.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from typing import Annotated, Any, Protocol

from anyio import CapacityLimiter
from fastapi import Depends
from sqlalchemy.ext.asyncio import AsyncSession
from starlette.requests import HTTPConnection

from backend.auth.first_admin import AdminCredentials
from backend.auth.logins import OpenSockets
from backend.auth.ratelimit import LoginLimiter
from backend.auth.tokens import TokenSigner
from backend.db.engine import Database
from backend.settings import Settings

Point = Sequence[float]


@dataclass(frozen=True, slots=True)
class SessionInfo:
    """What the live side needs to know about a therapy session."""

    id: int
    device: str
    patient_id: int
    params: dict[str, Any]
    started_at: datetime
    recording_path: str | None = None


class LiveUnavailable(RuntimeError):
    """The live side cannot do what was asked (no pipeline, no estimate yet); REST → 409."""


class LiveHooks(Protocol):
    """Called by the REST layer inside the request; the pipeline manager implements it.

    Each call happens before the request's transaction commits: raising aborts the request.
    """

    async def session_started(self, session: SessionInfo) -> str | None:
        """Start recording/applying params; return the recording path (relative to data_dir)."""
        ...

    async def session_committed(self, session: SessionInfo) -> None:
        """After the start's commit (the one call that is): the live side may now wait for
        what needs the committed row (a worker process starting the session)."""
        ...

    async def session_stopped(self, session: SessionInfo) -> dict[str, Any] | None:
        """Close the recording; return the session summary to store (or ``None``)."""
        ...

    async def set_nominal_shoulder(
        self, session: SessionInfo, point: Point | None, from_estimate: bool
    ) -> Point | None:
        """Adopt ``point``; or, with ``from_estimate``, the current shoulder estimate; or, with
        neither, reset to automatic. Return the adopted point (``None`` after a reset).
        Raise :class:`LiveUnavailable` when there is no estimate to take."""
        ...

    async def rom_test(self, session: SessionInfo, movement: str | None) -> dict[str, Any] | None:
        """A wearable session's ROM test: start one for ``movement``, or stop the running one
        (None) and return it with its peak. :class:`LiveUnavailable` if not running."""
        ...


class NoLive:
    """The hooks before a pipeline is wired in: sessions are only records."""

    async def session_started(self, session: SessionInfo) -> str | None:
        return None

    async def session_committed(self, session: SessionInfo) -> None:
        return None

    async def session_stopped(self, session: SessionInfo) -> dict[str, Any] | None:
        return None

    async def set_nominal_shoulder(
        self, session: SessionInfo, point: Point | None, from_estimate: bool
    ) -> Point | None:
        if from_estimate:
            raise LiveUnavailable("no live pipeline: no shoulder estimate to take")
        return point

    async def rom_test(self, session: SessionInfo, movement: str | None) -> dict[str, Any] | None:
        raise LiveUnavailable("no live pipeline: no joint angles")


@dataclass(eq=False)
class AppState:
    """Everything a running service holds; ``app.state.rehab`` while the lifespan runs."""

    settings: Settings
    database: Database
    signer: TokenSigner
    limiter: LoginLimiter
    # Argon2 runs at once (open_storage: settings.password_hash_concurrency)
    password_slots: CapacityLimiter = field(default_factory=lambda: CapacityLimiter(2))
    live: LiveHooks = field(default_factory=NoLive)
    sockets: OpenSockets = field(default_factory=OpenSockets)  # therapists' WebSockets
    first_admin: AdminCredentials | None = None
    interrupted_sessions: list[int] = field(default_factory=list)


def get_state(conn: HTTPConnection) -> AppState:
    state: AppState | None = getattr(conn.app.state, "rehab", None)
    if state is None:
        raise RuntimeError("the service is not started (lifespan has not run)")
    return state


State = Annotated[AppState, Depends(get_state)]


def get_app_settings(state: State) -> Settings:
    return state.settings


SettingsDep = Annotated[Settings, Depends(get_app_settings)]


async def get_db(state: State) -> AsyncIterator[AsyncSession]:
    """One session per request; handlers commit explicitly, anything else is rolled back."""
    async with state.database.session() as db:
        yield db


DB = Annotated[AsyncSession, Depends(get_db)]
