"""Session exports: the report (JSON), the per-sample estimates and details (CSV), the raw
recording.

Every export is written to the audit log. A session the service did not stop (killed)
has its outputs regenerated from its recording on first request. A running session
exports what it has so far: a provisional report, the rows and messages flushed to disk.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, status
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, ConfigDict

from backend.auth.guards import CurrentTherapist
from backend.db.audit import audit
from backend.db.errors import NotFound
from backend.db.models import Session
from backend.db.sessions import get_session
from backend.deps import DB, State
from backend.live import files
from backend.live.manager import LiveManager
from backend.schemas.sessions import Range, Spread

router = APIRouter(prefix="/sessions/{session_id}", tags=["exports"])

Responses = dict[int | str, dict[str, Any]]
_ERRORS: Responses = {
    404: {"description": "No such session, or it has no recording"},
    409: {"description": "The session is running but the live side does not have it"},
}


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow")  # the report may grow; clients ignore the rest


class ReportCycle(_Open):
    start: float
    end: float
    outside_fraction: float
    compensatory: bool | None
    coverage: float | None = None
    max_displacement_m: float | None = None
    mean_displacement_m: float | None = None


class ReportSummary(_Open):
    rows: int
    cycles: int
    compensatory_cycles: int
    compensatory_share: float | None = None
    time_outside_share: float | None = None


class ReportHeading(_Open):
    method: str | None = None
    first_motion_t: float | None = None
    converged_t: float | None = None


class Durations(_Open):
    median: float | None = None
    min: float | None = None
    max: float | None = None


class Report(_Open):
    """``report.json`` as ``rehab analyze`` writes it (angles in degrees, lengths in metres,
    times in seconds of the device clock)."""

    device: str
    cycles: list[ReportCycle]
    unjudged_cycles: list[ReportCycle] = []
    summary: ReportSummary
    heading: ReportHeading | None = None
    upper_arm_length_m: float | None = None
    upper_arm_length_estimated: bool | None = None
    shoulder_displacement_m: Spread | None = None
    elbow_flexion_deg: Range | None = None
    upper_arm_elevation_deg: Range | None = None
    upper_arm_azimuth_deg: Range | None = None
    cycle_duration_s: Durations | None = None
    data_quality: dict[str, Any] = {}
    params: dict[str, Any] = {}


class SessionMeta(BaseModel):
    id: int
    status: str
    device: str
    therapist: str | None
    started_at: datetime
    stopped_at: datetime | None
    params: dict[str, Any]
    nominal_shoulder: dict[str, Any] | None


class PatientMeta(BaseModel):
    id: int
    code: str
    affected_side: str


class SessionReportOut(BaseModel):
    session: SessionMeta
    patient: PatientMeta
    provisional: bool  # the session is still running: no final rows yet
    report: Report


def _file(path: Path, media_type: str, filename: str, growing: bool) -> Response:
    """A file still being written is sent as a snapshot (a streamed file would outgrow
    the Content-Length taken when the response started)."""
    if growing:
        disposition = f'attachment; filename="{filename}"'
        return Response(
            path.read_bytes(), media_type=media_type, headers={"Content-Disposition": disposition}
        )
    return FileResponse(path, media_type=media_type, filename=filename)


async def _load(db: DB, session_id: int) -> Session:
    try:
        return await get_session(db, session_id)
    except NotFound:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "session not found") from None


def _recording(state: State, session: Session) -> Path:
    if session.recording_path is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "the session has no recording")
    return files.resolve(state.settings.data_dir, session.recording_path)


def _manager(state: State) -> LiveManager | None:
    return state.live if isinstance(state.live, LiveManager) else None


async def _complete(state: State, session: Session) -> Path:
    """The recording of a finished session, its outputs complete; a running one flushed."""
    path = _recording(state, session)
    manager = _manager(state)
    if session.status == "active":
        if manager is not None:
            manager.flush_session(session.id, session.device.name)
    elif await files.ensure_outputs(path, session.params, session.device.name) is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "the session's recording is missing")
    if not path.exists():
        raise HTTPException(status.HTTP_404_NOT_FOUND, "the session's recording is missing")
    return path


@router.get("/report", responses=_ERRORS)
async def session_report(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> SessionReportOut:
    """Cycles with verdicts, shoulder displacement statistics, elbow flexion, upper-arm
    elevation and azimuth ranges, cycle durations and data quality, with the session's
    and the patient's metadata."""
    session = await _load(db, session_id)
    provisional = session.status == "active"
    report: dict[str, Any] | None
    if provisional:
        manager = _manager(state)
        report = manager.live_report(session.id, session.device.name) if manager else None
        if report is None:
            raise HTTPException(status.HTTP_409_CONFLICT, "the live side does not run it")
    else:
        report = await files.ensure_outputs(
            _recording(state, session), session.params, session.device.name
        )
        if report is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, "the session's recording is missing")
    audit(db, therapist, "export.report", f"session:{session.id}", {"provisional": provisional})
    await db.commit()
    return SessionReportOut(
        session=SessionMeta(
            id=session.id,
            status=session.status,
            device=session.device.name,
            therapist=session.therapist.username if session.therapist else None,
            started_at=session.started_at,
            stopped_at=session.stopped_at,
            params=session.params,
            nominal_shoulder=session.nominal_shoulder,
        ),
        patient=PatientMeta(
            id=session.patient.id,
            code=session.patient.code,
            affected_side=session.patient.affected_side,
        ),
        provisional=provisional,
        report=Report.model_validate(report),
    )


@router.get(
    "/estimates.csv",
    response_class=FileResponse,
    responses={
        200: {
            "description": "One row per robot sample (contract §6)",
            "content": {"text/csv": {"schema": {"type": "string"}}},
        },
        **_ERRORS,
    },
)
async def session_estimates(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> Response:
    return await _table(db, state, therapist, session_id, "estimates")


@router.get(
    "/details.csv",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The same rows' orientation, heading confidence, upper-arm "
            "elevation and azimuth, nominal shoulder and more (contract §6)",
            "content": {"text/csv": {"schema": {"type": "string"}}},
        },
        **_ERRORS,
    },
)
async def session_details(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> Response:
    return await _table(db, state, therapist, session_id, "details")


async def _table(
    db: DB, state: State, therapist: CurrentTherapist, session_id: int, name: str
) -> Response:
    """One of the session's two CSV files (contract §6), audited as ``export.<name>``."""
    session = await _load(db, session_id)
    path = files.outputs_dir(await _complete(state, session)) / f"{name}.csv"
    if not path.exists():
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no {name} for this session")
    audit(db, therapist, f"export.{name}", f"session:{session.id}")
    await db.commit()
    return _file(path, "text/csv", f"session-{session.id}-{name}.csv", session.status == "active")


@router.get(
    "/recording.jsonl.gz",
    response_class=FileResponse,
    responses={
        200: {
            "description": "Every raw message of the session (contract §5)",
            "content": {"application/gzip": {"schema": {"type": "string", "format": "binary"}}},
        },
        **_ERRORS,
    },
)
async def session_recording(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> Response:
    session = await _load(db, session_id)
    path = await _complete(state, session)
    audit(db, therapist, "export.recording", f"session:{session.id}")
    await db.commit()
    return _file(
        path, "application/gzip", f"session-{session.id}.jsonl.gz", session.status == "active"
    )
