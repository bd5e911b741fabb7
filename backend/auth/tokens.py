"""Signed tokens (JWT, HS256, PyJWT): therapist access tokens and overlay tokens.

The audience separates the two kinds, so neither is accepted where the other is expected.
Overlay tokens are stateless and bound to one device and one session; they are revoked by
the session itself: :func:`backend.auth.guards.verify_overlay_token` also requires that
session to still be active on that device, so stopping the session kills every link.
Access tokens name a login (``sid``, a row of ``logins``): the guard requires that row to
be unrevoked and recently used, so logout, a password change or a deactivation ends a token
at once (see :mod:`backend.auth.logins`); they also expire (a shift by default).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import jwt

from backend.db.base import utcnow

ISSUER = "rehab"
ACCESS = "rehab:access"
OVERLAY = "rehab:overlay"
_ALGORITHM = "HS256"


class InvalidToken(Exception):
    pass


@dataclass(frozen=True, slots=True)
class Issued:
    token: str
    expires_at: datetime


class TokenSigner:
    def __init__(self, key: bytes) -> None:
        self._key = key

    def _issue(self, audience: str, ttl_s: float, claims: dict[str, Any]) -> Issued:
        now = utcnow()
        exp = now + timedelta(seconds=ttl_s)
        payload = {"iss": ISSUER, "aud": audience, "iat": now, "exp": exp, **claims}
        return Issued(jwt.encode(payload, self._key, algorithm=_ALGORITHM), exp)

    def _decode(self, token: str, audience: str, required: list[str]) -> dict[str, Any]:
        try:
            claims: dict[str, Any] = jwt.decode(
                token,
                self._key,
                algorithms=[_ALGORITHM],
                audience=audience,
                issuer=ISSUER,
                options={"require": ["exp", "iat", "aud", "iss", *required]},
            )
        except jwt.PyJWTError as exc:
            raise InvalidToken(str(exc)) from None
        return claims

    def issue_access(self, therapist_id: int, ttl_s: float, login_id: str) -> Issued:
        return self._issue(ACCESS, ttl_s, {"sub": str(therapist_id), "sid": login_id})

    def decode_access(self, token: str) -> tuple[int, str]:
        """``(therapist id, login id)`` of a valid, unexpired access token."""
        claims = self._decode(token, ACCESS, ["sub", "sid"])
        sub, sid = claims["sub"], claims["sid"]
        if not isinstance(sub, str) or not sub.isdigit() or not isinstance(sid, str):
            raise InvalidToken("bad subject")
        return int(sub), sid

    def issue_overlay(self, device: str, session_id: int, ttl_s: float) -> Issued:
        return self._issue(OVERLAY, ttl_s, {"dev": device, "sid": session_id})

    def decode_overlay(self, token: str) -> tuple[str, int]:
        claims = self._decode(token, OVERLAY, ["dev", "sid"])
        device, session_id = claims["dev"], claims["sid"]
        if not isinstance(device, str) or not isinstance(session_id, int):
            raise InvalidToken("bad overlay claims")
        return device, session_id
