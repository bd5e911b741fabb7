"""Server-side logins (the ``logins`` table): created at login, checked on every request and
by open WebSockets, revoked by logout, a password change and a deactivation.

Open WebSockets of a login are registered in :class:`OpenSockets`, so a revocation closes
them at once (1008) instead of at their next periodic re-check.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable
from datetime import datetime, timedelta

from sqlalchemy import delete, update
from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.base import utcnow
from backend.db.models import Login, Therapist

TOUCH_EVERY = timedelta(seconds=60)  # last_seen is written at most this often per login
KEEP_EXPIRED = timedelta(days=1)


async def open_login(db: AsyncSession, therapist: Therapist, ttl_s: float, ip: str | None) -> Login:
    now = utcnow()
    # Expired rows are of no use: drop them now and then (here, at each login).
    await db.execute(delete(Login).where(Login.expires_at < now - KEEP_EXPIRED))
    login = Login(
        id=secrets.token_urlsafe(24),
        therapist_id=therapist.id,
        created_at=now,
        last_seen=now,
        expires_at=now + timedelta(seconds=ttl_s),
        ip=ip,
    )
    db.add(login)
    await db.flush()
    return login


def login_alive(login: Login | None, therapist_id: int, idle_s: float, now: datetime) -> bool:
    return (
        login is not None
        and login.therapist_id == therapist_id
        and login.revoked_at is None
        and login.expires_at > now
        and login.last_seen > now - timedelta(seconds=idle_s)
    )


def touch(login: Login, now: datetime) -> None:
    if login.last_seen < now - TOUCH_EVERY:
        login.last_seen = now


async def revoke(
    db: AsyncSession, therapist_id: int, only: str | None = None, keep: str | None = None
) -> None:
    """Revoke login ``only``, or every unrevoked login of the therapist except ``keep``."""
    stmt = update(Login).where(Login.therapist_id == therapist_id, Login.revoked_at.is_(None))
    if only is not None:
        stmt = stmt.where(Login.id == only)
    if keep is not None:
        stmt = stmt.where(Login.id != keep)
    await db.execute(stmt.values(revoked_at=utcnow()))


class OpenSockets:
    """The therapists' open WebSockets by login: ``close`` callbacks to call on revocation."""

    def __init__(self) -> None:
        self._by_login: dict[str, tuple[int, set[Callable[[str], None]]]] = {}

    def add(self, therapist_id: int, login_id: str, close: Callable[[str], None]) -> None:
        self._by_login.setdefault(login_id, (therapist_id, set()))[1].add(close)

    def remove(self, login_id: str, close: Callable[[str], None]) -> None:
        entry = self._by_login.get(login_id)
        if entry is not None:
            entry[1].discard(close)
            if not entry[1]:
                del self._by_login[login_id]

    def close(
        self, therapist_id: int, reason: str, only: str | None = None, keep: str | None = None
    ) -> int:
        """Close the sockets of a login, or of the therapist's logins except ``keep``."""
        closed = 0
        for login_id, (tid, closers) in list(self._by_login.items()):
            if tid != therapist_id or login_id == keep or (only is not None and login_id != only):
                continue
            for close in list(closers):
                close(reason)
                closed += 1
        return closed

    def __len__(self) -> int:
        return sum(len(c) for _, c in self._by_login.values())
