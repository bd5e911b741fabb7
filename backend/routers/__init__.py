"""The REST API, one router per resource, all under ``/api``.

Everything except ``/health`` and ``/auth/login`` sits behind :func:`current_therapist`,
attached here once so that a new router cannot forget it (a test checks every route).
"""

from fastapi import APIRouter, Depends

from backend.auth.guards import current_therapist
from backend.routers import audit, auth, cycles, devices, health, patients, sessions, therapists

public = APIRouter()
public.include_router(health.router)
public.include_router(auth.router)  # login is public; logout, me and password guard themselves

protected = APIRouter(dependencies=[Depends(current_therapist)])
for module in (patients, devices, sessions, cycles, therapists, audit):
    protected.include_router(module.router)

api_router = APIRouter(prefix="/api")
api_router.include_router(public)
api_router.include_router(protected)

__all__ = ["api_router"]
