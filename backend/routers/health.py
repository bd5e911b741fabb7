"""Liveness for load balancers and compose health checks: no auth, no patient data."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from typing import Literal

from fastapi import APIRouter
from sqlalchemy import text

from backend.deps import DB
from backend.schemas.health import HealthOut

router = APIRouter(tags=["health"])

try:
    _VERSION = version("rehab-tracking")
except PackageNotFoundError:  # running from a source tree that was never installed
    _VERSION = "0+unknown"

# the estimators run interpreted (a field kept for clients that read it)
_ESTIMATORS: Literal["interpreted"] = "interpreted"


@router.get("/health")
async def health(db: DB) -> HealthOut:
    try:
        await db.execute(text("SELECT 1"))
    except Exception:  # any driver error means the same thing to a health check
        return HealthOut(
            status="degraded", version=_VERSION, database="unreachable", estimators=_ESTIMATORS
        )
    return HealthOut(status="ok", version=_VERSION, database="ok", estimators=_ESTIMATORS)
