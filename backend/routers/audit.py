"""The audit log (administrators only)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Query
from sqlalchemy import select

from backend.auth.guards import require_admin
from backend.db.models import AuditLog
from backend.deps import DB
from backend.schemas.audit import AuditOut

router = APIRouter(prefix="/audit", tags=["audit"], dependencies=[Depends(require_admin)])


@router.get("")
async def list_audit(
    db: DB,
    action: Annotated[str | None, Query(max_length=64)] = None,
    therapist_id: int | None = None,
    obj: Annotated[str | None, Query(alias="object", max_length=128)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> list[AuditOut]:
    """Newest first."""
    stmt = select(AuditLog).order_by(AuditLog.id.desc()).limit(limit).offset(offset)
    if action is not None:
        stmt = stmt.where(AuditLog.action == action)
    if therapist_id is not None:
        stmt = stmt.where(AuditLog.therapist_id == therapist_id)
    if obj is not None:
        stmt = stmt.where(AuditLog.object == obj)
    return [AuditOut.model_validate(a) for a in await db.scalars(stmt)]
