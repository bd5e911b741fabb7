"""Login (bearer token + HttpOnly cookie), logout, the current account, password change."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, Response, status
from sqlalchemy import select

from backend.auth.first_admin import read_admin_credentials
from backend.auth.guards import CurrentTherapist
from backend.auth.logins import open_login, revoke
from backend.auth.passwords import hash_password_async, verify_password_async
from backend.db.audit import audit
from backend.db.models import Therapist
from backend.deps import DB, State
from backend.schemas.auth import LoginIn, PasswordChangeIn, TokenOut
from backend.schemas.therapists import TherapistOut

router = APIRouter(prefix="/auth", tags=["auth"])


def client_address(request: Request) -> str:
    return request.client.host if request.client else "unknown"


@router.post(
    "/login",
    responses={401: {"description": "Wrong credentials"}, 429: {"description": "Too many"}},
)
async def login(
    body: LoginIn, request: Request, response: Response, state: State, db: DB
) -> TokenOut:
    """Returns a bearer token (scripts) and sets it as a Secure, HttpOnly, SameSite=Strict
    cookie (the dashboard)."""
    client = client_address(request)
    # Counted now, before the (slow) verification: parallel guesses see each other.
    wait, stamp = state.limiter.attempt(body.username, client)
    if wait is not None:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            "too many failed logins; try again later",
            headers={"Retry-After": str(max(1, round(wait)))},
        )
    therapist = await db.scalar(select(Therapist).where(Therapist.username == body.username))
    ok, new_hash = await verify_password_async(
        body.password, therapist.password_hash if therapist else None, state.password_slots
    )
    if therapist is None or not ok or not therapist.active:
        reason = "inactive" if therapist is not None and ok else "bad_credentials"
        audit(
            db, therapist or body.username, "login.failed", None, {"ip": client, "reason": reason}
        )
        await db.commit()
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            "invalid username or password",
            headers={"WWW-Authenticate": "Bearer"},
        )
    state.limiter.succeeded(body.username, client, stamp)
    if new_hash is not None:
        therapist.password_hash = new_hash
    ttl = state.settings.access_token_ttl_s
    session = await open_login(db, therapist, ttl, client)
    issued = state.signer.issue_access(therapist.id, ttl, session.id)
    audit(db, therapist, "login", f"therapist:{therapist.id}", {"ip": client})
    await db.commit()
    response.set_cookie(
        state.settings.cookie_name,
        issued.token,
        max_age=ttl,
        httponly=True,
        secure=state.settings.cookie_secure,
        samesite="strict",
        path="/",
    )
    return TokenOut(
        access_token=issued.token,
        expires_at=issued.expires_at,
        therapist=TherapistOut.model_validate(therapist),
    )


@router.post("/logout", status_code=status.HTTP_204_NO_CONTENT)
async def logout(
    therapist: CurrentTherapist, request: Request, response: Response, state: State, db: DB
) -> None:
    """Ends this login on the server (its token is refused from now on, its live views
    close) and clears the cookie. The account's other logins go on."""
    login_id: str = request.state.login_id
    await revoke(db, therapist.id, only=login_id)
    audit(db, therapist, "logout", f"therapist:{therapist.id}")
    await db.commit()
    state.sockets.close(therapist.id, "logged out", only=login_id)
    response.delete_cookie(
        state.settings.cookie_name,
        httponly=True,
        secure=state.settings.cookie_secure,
        samesite="strict",
        path="/",
    )


@router.get("/me")
async def me(therapist: CurrentTherapist) -> TherapistOut:
    return TherapistOut.model_validate(therapist)


@router.post("/password", status_code=status.HTTP_204_NO_CONTENT)
async def change_password(
    body: PasswordChangeIn, therapist: CurrentTherapist, request: Request, state: State, db: DB
) -> None:
    """Also ends every other login of the account (a stolen token dies with the old
    password); this one goes on."""
    ok, _ = await verify_password_async(
        body.current_password, therapist.password_hash, state.password_slots
    )
    if not ok:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "current password is wrong")
    therapist.password_hash = await hash_password_async(body.new_password, state.password_slots)
    login_id: str = request.state.login_id
    await revoke(db, therapist.id, keep=login_id)
    audit(db, therapist, "therapist.password", f"therapist:{therapist.id}")
    await db.commit()
    state.sockets.close(therapist.id, "password changed", keep=login_id)
    # The first admin's generated password must not linger on disk once it is replaced.
    creds = read_admin_credentials(state.settings)
    if creds is not None and creds.username == therapist.username:
        state.settings.admin_credentials_file.unlink(missing_ok=True)
