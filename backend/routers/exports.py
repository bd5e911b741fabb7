"""Session exports: the report (JSON), the per-sample estimates and details (CSV), the raw
recording; for the clinic's records the PDF report and the FHIR R4 Bundle (also sent to a
configured FHIR server on request), and the MCAP file for Foxglove (backend/exports).

Every export is written to the audit log. A session the service did not stop (killed)
has its outputs regenerated from its recording on first request. A running session
exports what it has so far: a provisional report, the rows and messages flushed to disk.
"""

from __future__ import annotations

import asyncio
import io
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, status
from fastapi.responses import FileResponse, Response
from pydantic import BaseModel, ConfigDict

from backend.analysis import read_estimates
from backend.auth.guards import CurrentTherapist
from backend.db.audit import audit
from backend.db.errors import NotFound
from backend.db.models import Session
from backend.db.sessions import get_session
from backend.deps import DB, State
from backend.exports import ExportMeta, fhir, mcap_file
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
    cycles: int = 0  # a wearable session has no robot cycles (its movements instead)
    compensatory_cycles: int = 0
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


async def _report_of(state: State, session: Session) -> tuple[dict[str, Any], bool]:
    """The session's report and whether it is provisional (the session still runs: the live
    side's report so far); 409 when the live side does not run it, 404 without recording."""
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
    return report, provisional


@router.get("/report", responses=_ERRORS)
async def session_report(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> SessionReportOut:
    """Cycles with verdicts, shoulder displacement statistics, elbow flexion, upper-arm
    elevation and azimuth ranges, cycle durations and data quality, with the session's
    and the patient's metadata."""
    session = await _load(db, session_id)
    report, provisional = await _report_of(state, session)
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


# ---- clinical exports: PDF report, FHIR R4 Bundle (and sending it), MCAP (backend/exports)


async def _clinical(state: State, session: Session) -> tuple[dict[str, Any], ExportMeta]:
    """The session's report (provisional while it runs) and what the exports say about it."""
    report, provisional = await _report_of(state, session)
    meta = ExportMeta(
        session=str(session.id),
        device=session.device.name,
        patient_code=session.patient.code,
        started_at=_aware(session.started_at),
        stopped_at=_aware(session.stopped_at),
        therapist=session.therapist.username if session.therapist else None,
        provisional=provisional,
    )
    return report, meta


def _aware(t: datetime | None) -> datetime | None:
    """Stored times are UTC; SQLite gives them back naive."""
    return t.replace(tzinfo=UTC) if t is not None and t.tzinfo is None else t


@router.get(
    "/report.pdf",
    response_class=Response,
    responses={
        200: {
            "description": "The session report, one or two pages: key figures, plots, range "
            "of motion, movement quality, cycles",
            "content": {"application/pdf": {"schema": {"type": "string", "format": "binary"}}},
        },
        **_ERRORS,
    },
)
async def session_report_pdf(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> Response:
    session = await _load(db, session_id)
    report, meta = await _clinical(state, session)
    from backend.exports import pdf  # matplotlib and reportlab: loaded on first use

    body = await asyncio.to_thread(pdf.render, report, meta)
    audit(db, therapist, "export.pdf", f"session:{session.id}", {"provisional": meta.provisional})
    await db.commit()
    return Response(
        body,
        media_type="application/pdf",
        headers={"Content-Disposition": f'attachment; filename="session-{session.id}.pdf"'},
    )


@router.get(
    "/fhir",
    response_class=Response,
    responses={
        200: {
            "description": "A FHIR R4 Bundle (collection): DiagnosticReport and Observations "
            "(key figures, range of motion, movement quality) about a pseudonymous Patient",
            "content": {"application/fhir+json": {"schema": {"type": "object"}}},
        },
        **_ERRORS,
    },
)
async def session_fhir(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> Response:
    session = await _load(db, session_id)
    report, meta = await _clinical(state, session)
    body = json.dumps(fhir.bundle(report, meta))
    audit(db, therapist, "export.fhir", f"session:{session.id}", {"provisional": meta.provisional})
    await db.commit()
    return Response(body, media_type="application/fhir+json")


class FhirSent(BaseModel):
    url: str
    response: dict[str, Any]  # the server's answer (a transaction-response Bundle)


@router.post(
    "/fhir/send",
    responses={
        409: {"description": "No FHIR endpoint is configured, or the session is still running"},
        502: {"description": "The FHIR server could not be reached or refused the Bundle"},
        404: _ERRORS[404],
    },
)
async def session_fhir_send(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> FhirSent:
    """Send the session's Bundle (as a transaction) to the configured FHIR server
    (``REHAB_FHIR_URL``). Only a finished session: records are not sent provisionally."""
    url = state.settings.fhir_url
    if not url:
        raise HTTPException(
            status.HTTP_409_CONFLICT, "no FHIR endpoint configured (REHAB_FHIR_URL)"
        )
    session = await _load(db, session_id)
    if session.status == "active":
        raise HTTPException(status.HTTP_409_CONFLICT, "the session is still running")
    report, meta = await _clinical(state, session)
    try:
        answer = await asyncio.to_thread(
            fhir.send, report, meta, url, state.settings.fhir_timeout_s
        )
    except fhir.FhirSendError as exc:
        audit(db, therapist, "export.fhir_send", f"session:{session.id}", {"ok": False})
        await db.commit()
        raise HTTPException(status.HTTP_502_BAD_GATEWAY, str(exc)) from None
    audit(db, therapist, "export.fhir_send", f"session:{session.id}", {"ok": True})
    await db.commit()
    return FhirSent(url=url, response=answer)


@router.get(
    "/recording.mcap",
    response_class=Response,
    responses={
        200: {
            "description": "The recording, the estimates and the cycle verdicts as MCAP (JSON "
            "messages with JSON Schemas; opens in Foxglove)",
            "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}
            },
        },
        **_ERRORS,
    },
)
async def session_mcap(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> Response:
    session = await _load(db, session_id)
    path = await _complete(state, session)
    report, meta = await _clinical(state, session)
    est_path = files.outputs_dir(path) / "estimates.csv"

    def build() -> bytes:
        buf = io.BytesIO()
        estimates = read_estimates(est_path) if est_path.exists() else None
        mcap_file.write(buf, path, report, estimates, meta, state.settings.key_prefix)
        return buf.getvalue()

    body = await asyncio.to_thread(build)
    audit(db, therapist, "export.mcap", f"session:{session.id}", {"provisional": meta.provisional})
    await db.commit()
    return Response(
        body,
        media_type="application/octet-stream",
        headers={"Content-Disposition": f'attachment; filename="session-{session.id}.mcap"'},
    )
