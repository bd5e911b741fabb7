"""Completed cycles of a session, with their verdicts."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, status

from backend.auth.guards import CurrentTherapist
from backend.db.audit import audit
from backend.db.models import Session
from backend.db.sessions import list_cycles
from backend.deps import DB
from backend.schemas.cycles import CycleOut

router = APIRouter(prefix="/sessions/{session_id}/cycles", tags=["cycles"])


@router.get("")
async def session_cycles(session_id: int, therapist: CurrentTherapist, db: DB) -> list[CycleOut]:
    if await db.get(Session, session_id) is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "session not found")
    cycles = [CycleOut.model_validate(c) for c in await list_cycles(db, session_id)]
    audit(db, therapist, "cycles.read", f"session:{session_id}")
    await db.commit()
    return cycles
