"""Therapist accounts (administrators only). Accounts are deactivated, never deleted,
so the audit log keeps pointing at them."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, status
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError

from backend.auth.guards import AdminTherapist, require_admin
from backend.auth.logins import revoke
from backend.auth.passwords import hash_password_async
from backend.db.audit import audit
from backend.db.models import Therapist
from backend.deps import DB, State
from backend.schemas.therapists import TherapistCreate, TherapistOut

router = APIRouter(prefix="/therapists", tags=["therapists"], dependencies=[Depends(require_admin)])


async def _get(db: DB, therapist_id: int) -> Therapist:
    therapist = await db.get(Therapist, therapist_id)
    if therapist is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "therapist not found")
    return therapist


@router.get("")
async def list_therapists(db: DB) -> list[TherapistOut]:
    rows = await db.scalars(select(Therapist).order_by(Therapist.username))
    return [TherapistOut.model_validate(t) for t in rows]


@router.post("", status_code=status.HTTP_201_CREATED)
async def create_therapist(
    body: TherapistCreate, admin: AdminTherapist, db: DB, state: State
) -> TherapistOut:
    therapist = Therapist(
        username=body.username,
        password_hash=await hash_password_async(body.password, state.password_slots),
        is_admin=body.is_admin,
        active=True,
    )
    db.add(therapist)
    try:
        await db.flush()
    except IntegrityError:
        raise HTTPException(status.HTTP_409_CONFLICT, "username already taken") from None
    audit(db, admin, "therapist.create", f"therapist:{therapist.id}", {"is_admin": body.is_admin})
    await db.commit()
    return TherapistOut.model_validate(therapist)


@router.post("/{therapist_id}/deactivate")
async def deactivate_therapist(
    therapist_id: int, admin: AdminTherapist, db: DB, state: State
) -> TherapistOut:
    """Also revokes every login of the account and closes its live views."""
    therapist = await _get(db, therapist_id)
    if therapist.id == admin.id:
        raise HTTPException(status.HTTP_409_CONFLICT, "cannot deactivate your own account")
    therapist.active = False
    await revoke(db, therapist.id)
    audit(db, admin, "therapist.deactivate", f"therapist:{therapist.id}")
    await db.commit()
    state.sockets.close(therapist.id, "account deactivated")
    return TherapistOut.model_validate(therapist)


@router.post("/{therapist_id}/activate")
async def activate_therapist(therapist_id: int, admin: AdminTherapist, db: DB) -> TherapistOut:
    therapist = await _get(db, therapist_id)
    therapist.active = True
    audit(db, admin, "therapist.activate", f"therapist:{therapist.id}")
    await db.commit()
    return TherapistOut.model_validate(therapist)
