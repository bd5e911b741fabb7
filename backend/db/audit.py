"""The audit log helper: one call per login, data change or export."""

from __future__ import annotations

from typing import Any

from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.models import AuditLog, Therapist


def audit(
    db: AsyncSession,
    therapist: Therapist | str | None,
    action: str,
    obj: str | None = None,
    details: dict[str, Any] | None = None,
) -> AuditLog:
    """Add an audit row to ``db`` (committed with the change it describes).

    ``therapist`` is the acting account, a bare username (e.g. a failed login), or ``None``
    for the service itself. ``action`` is dotted (``patient.create``, ``export.report``),
    ``obj`` names the object (``patient:12``, ``session:7``).
    """
    if isinstance(therapist, Therapist):
        entry = AuditLog(therapist_id=therapist.id, actor=therapist.username, action=action)
    else:
        entry = AuditLog(therapist_id=None, actor=therapist, action=action)
    entry.object = obj
    entry.details = details
    db.add(entry)
    return entry
