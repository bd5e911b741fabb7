"""Liveness for load balancers and compose health checks: no auth, no patient data."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from fastapi import APIRouter
from sqlalchemy import text

from backend.deps import DB
from backend.schemas.health import HealthOut
from estimators import aot

router = APIRouter(tags=["health"])

try:
    _VERSION = version("rehab-tracking")
except PackageNotFoundError:  # running from a source tree that was never installed
    _VERSION = "0+unknown"

# how the kernels run (the service's processes share the build and the environment): once,
# at start-up, as it imports the kernels' modules
_ESTIMATORS = aot.mode()


@router.get("/health")
async def health(db: DB) -> HealthOut:
    try:
        await db.execute(text("SELECT 1"))
    except Exception:  # any driver error means the same thing to a health check
        return HealthOut(
            status="degraded", version=_VERSION, database="unreachable", estimators=_ESTIMATORS
        )
    return HealthOut(status="ok", version=_VERSION, database="ok", estimators=_ESTIMATORS)
