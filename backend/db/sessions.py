"""Therapy sessions and their cycles: the functions both REST and the live pipeline call.

None of them commits: the caller owns the transaction (a request handler commits once, with
its audit entry; the pipeline uses ``Database.transaction()``).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import Any, Literal

from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncSession
from sqlalchemy.orm import selectinload

from backend.db.base import utcnow
from backend.db.errors import Conflict, NotFound
from backend.db.models import Cycle, Device, Patient, Session, Therapist

# Where a nominal shoulder came from: given at start, the robot's shoulder_reference event,
# set automatically once the heading converged, or by a therapist (a point or the estimate).
NominalSource = Literal["params", "event", "auto", "therapist", "estimate"]
Point = Sequence[float]


def _with_relations() -> Any:
    return (
        selectinload(Session.patient),
        selectinload(Session.device),
        selectinload(Session.therapist),
    )


async def get_session(db: AsyncSession, session_id: int) -> Session:
    """The session with patient, device and therapist loaded; :class:`NotFound` otherwise."""
    found = await db.scalar(
        select(Session).where(Session.id == session_id).options(*_with_relations())
    )
    if found is None:
        raise NotFound(f"session {session_id} does not exist")
    return found


async def active_session(db: AsyncSession, device: str) -> Session | None:
    """The running session on ``device`` (the pipeline routes data and cycles with it)."""
    return await db.scalar(
        select(Session)
        .join(Session.device)
        .where(Device.name == device, Session.status == "active")
        .options(*_with_relations())
    )


def nominal_record(point: Point, source: NominalSource, set_by: str | None) -> dict[str, Any]:
    return {
        "point": [float(x) for x in point],
        "source": source,
        "set_at": utcnow().isoformat(),
        "set_by": set_by,
    }


async def start_session(
    db: AsyncSession,
    *,
    patient: Patient,
    device: Device,
    therapist: Therapist | None,
    params: dict[str, Any],
) -> Session:
    """Open a session; :class:`Conflict` (transaction rolled back) if the device runs one."""
    if await active_session(db, device.name) is not None:
        raise Conflict(f"device {device.name!r} already has an active session")
    nominal = params.get("nominal_shoulder_m")
    session = Session(
        patient=patient,
        device=device,
        therapist=therapist,
        status="active",
        params=params,
        nominal_shoulder=None if nominal is None else nominal_record(nominal, "params", None),
    )
    db.add(session)
    try:
        await db.flush()
    except IntegrityError:
        # The partial unique index caught a concurrent start that the check above missed.
        # No savepoint (pysqlite's are unreliable): the whole transaction is rolled back.
        await db.rollback()
        raise Conflict(f"device {device.name!r} already has an active session") from None
    return session


async def stop_session(
    db: AsyncSession,
    session: Session,
    *,
    status: Literal["stopped", "interrupted"] = "stopped",
    summary: dict[str, Any] | None = None,
    at: datetime | None = None,
) -> None:
    if session.status != "active":
        raise Conflict(f"session {session.id} is {session.status}, not active")
    session.status = status
    session.stopped_at = at or utcnow()
    if summary is not None:
        session.summary = summary
    await db.flush()


async def interrupt_active_sessions(db: AsyncSession, running: Sequence[str] = ()) -> list[int]:
    """At start: sessions a previous run left active were cut off (crash, kill -9).

    They end when their device was last seen, the best record of when data stopped.
    ``running``: devices a live worker holds (its sessions go on).
    """
    sessions = await db.scalars(
        select(Session).where(Session.status == "active").options(selectinload(Session.device))
    )
    ids = []
    for session in sessions:
        if session.device.name in running:
            continue
        session.status = "interrupted"
        session.stopped_at = max(session.started_at, session.device.last_seen)
        ids.append(session.id)
    await db.flush()
    return ids


async def store_nominal_shoulder(
    db: AsyncSession,
    session_id: int,
    point: Point | None,
    source: NominalSource,
    set_by: str | None = None,
) -> None:
    """Persist the nominal shoulder (``None`` = reset; the pipeline will set it again)."""
    record = None if point is None else nominal_record(point, source, set_by)
    result = await db.execute(
        update(Session).where(Session.id == session_id).values(nominal_shoulder=record)
    )
    if getattr(result, "rowcount", 1) == 0:
        raise NotFound(f"session {session_id} does not exist")


async def record_cycle(
    db: AsyncSession,
    session_id: int,
    *,
    start: float,
    end: float,
    outside_fraction: float,
    compensatory: bool,
    coverage: float | None = None,
    peak_displacement_m: float | None = None,
    index: int | None = None,
) -> Cycle:
    """Store a completed cycle; ``index`` defaults to the next one of the session."""
    if index is None:
        last = await db.scalar(select(func.max(Cycle.index)).where(Cycle.session_id == session_id))
        index = 0 if last is None else last + 1
    cycle = Cycle(
        session_id=session_id,
        index=index,
        start=start,
        end=end,
        outside_fraction=outside_fraction,
        compensatory=compensatory,
        coverage=coverage,
        peak_displacement_m=peak_displacement_m,
    )
    db.add(cycle)
    await db.flush()
    return cycle


async def list_cycles(db: AsyncSession, session_id: int) -> list[Cycle]:
    return list(
        await db.scalars(select(Cycle).where(Cycle.session_id == session_id).order_by(Cycle.index))
    )
