"""Therapy sessions: start, stop, read, the nominal shoulder, and overlay links.

Starting, stopping and the nominal shoulder go through :class:`backend.deps.LiveHooks`
before the transaction commits, so the records and the live side agree.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal
from urllib.parse import urlencode

from fastapi import APIRouter, HTTPException, Query, status
from sqlalchemy import select
from sqlalchemy.orm import selectinload

from backend.auth.guards import CurrentTherapist
from backend.db.audit import audit
from backend.db.devices import get_device
from backend.db.errors import Conflict, NotFound
from backend.db.models import Device, Patient, Session
from backend.db.sessions import (
    NominalSource,
    get_session,
    start_session,
    stop_session,
    store_nominal_shoulder,
)
from backend.deps import DB, LiveUnavailable, SessionInfo, State
from backend.schemas.common import Params, overrides
from backend.schemas.sessions import (
    NominalShoulderIn,
    OverlayLinkOut,
    RomTestIn,
    SessionCreate,
    SessionOut,
    SessionSummary,
    WearableSpec,
)
from backend.summaries import complete_summaries
from estimators.wearable.params import WearableParams, WearableParamsError

WEARABLE_ROBOT_KEYS = ("upper_arm_length_m",)  # the patient's §4 values a wearable session uses


def wearable_params(params: dict[str, Any], spec: WearableSpec) -> dict[str, Any]:
    """A wearable session's parameters (contract §8): the patient's upper-arm length and the
    request's wearable keys; 422 if they cannot be used."""
    out: dict[str, Any] = {"mode": "wearable", **{k: params[k] for k in WEARABLE_ROBOT_KEYS}}
    out.update(spec.model_dump(exclude_none=True))
    for k in ("upperarm_imu", "forearm_imu"):
        if k in out:
            out[k] = {a: v for a, v in out[k].items() if v is not None}
    try:
        WearableParams.from_json(out)
    except WearableParamsError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    return out


router = APIRouter(prefix="/sessions", tags=["sessions"])

Responses = dict[int | str, dict[str, Any]]
_404: Responses = {404: {"description": "Not found"}}
_409: Responses = {409: {"description": "Conflict with the session's state"}}


def session_out(session: Session) -> SessionOut:
    return SessionOut(
        id=session.id,
        patient_id=session.patient_id,
        patient_code=session.patient.code,
        device=session.device.name,
        therapist=session.therapist.username if session.therapist else None,
        started_at=session.started_at,
        stopped_at=session.stopped_at,
        status=session.status,  # type: ignore[arg-type]  # the CHECK constraint holds it
        params=session.params,
        recording_path=session.recording_path,
        nominal_shoulder=session.nominal_shoulder,  # type: ignore[arg-type]  # validated
        summary=SessionSummary.model_validate(session.summary) if session.summary else None,
    )


def session_info(session: Session) -> SessionInfo:
    return SessionInfo(
        id=session.id,
        device=session.device.name,
        patient_id=session.patient_id,
        params=session.params,
        started_at=session.started_at,
        recording_path=session.recording_path,
    )


async def _load(db: DB, session_id: int) -> Session:
    try:
        return await get_session(db, session_id)
    except NotFound:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "session not found") from None


def _require_active(session: Session) -> None:
    if session.status != "active":
        raise HTTPException(status.HTTP_409_CONFLICT, f"session is {session.status}")


@router.post("", status_code=status.HTTP_201_CREATED, responses={**_404, **_409})
async def create_session(
    body: SessionCreate, therapist: CurrentTherapist, state: State, db: DB
) -> SessionOut:
    """Start a session of a patient on a device, with the patient's parameters (and any
    session-only overrides)."""
    patient = await db.get(Patient, body.patient_id)
    if patient is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "patient not found")
    device = await get_device(db, body.device)
    if device is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "device has never sent data")
    params = Params.model_validate({**patient.params(), **overrides(body.params)}).model_dump()
    if body.wearable is not None:  # contract §8: the mode is chosen by the parameters
        params = wearable_params(params, body.wearable)
    try:
        session = await start_session(
            db, patient=patient, device=device, therapist=therapist, params=params
        )
    except Conflict as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    session = await get_session(db, session.id)
    try:
        recording = await state.live.session_started(session_info(session))
    except LiveUnavailable as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    if recording is not None:
        session.recording_path = recording
    audit(
        db,
        therapist,
        "session.start",
        f"session:{session.id}",
        {"patient_id": patient.id, "device": device.name},
    )
    await db.commit()
    await state.live.session_committed(session_info(session))
    return session_out(session)


@router.get("")
async def list_sessions(
    db: DB,
    state: State,
    therapist: CurrentTherapist,
    patient_id: int | None = None,
    device: Annotated[str | None, Query(max_length=64)] = None,
    session_status: Annotated[
        Literal["active", "stopped", "interrupted"] | None, Query(alias="status")
    ] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> list[SessionOut]:
    """Newest first; filter by patient, device and status. Each finished session carries
    its summary (cycles, compensatory share, shoulder displacement, range of motion): a
    patient's history needs no report."""
    stmt = (
        select(Session)
        .options(
            selectinload(Session.patient),
            selectinload(Session.device),
            selectinload(Session.therapist),
        )
        .order_by(Session.id.desc())
        .limit(limit)
        .offset(offset)
    )
    if patient_id is not None:
        stmt = stmt.where(Session.patient_id == patient_id)
    if device is not None:
        stmt = stmt.join(Session.device).where(Device.name == device)
    if session_status is not None:
        stmt = stmt.where(Session.status == session_status)
    sessions = list(await db.scalars(stmt))
    await _complete(db, state, sessions)
    obj = f"patient:{patient_id}" if patient_id is not None else None
    details = {"device": device, "status": session_status, "count": len(sessions)}
    audit(db, therapist, "session.list", obj, details)
    await db.commit()
    return [session_out(s) for s in sessions]


@router.get("/{session_id}", responses=_404)
async def read_session(
    session_id: int, therapist: CurrentTherapist, db: DB, state: State
) -> SessionOut:
    session = await _load(db, session_id)
    await _complete(db, state, [session])
    audit(db, therapist, "session.read", f"session:{session_id}")
    await db.commit()
    return session_out(session)


async def _complete(db: DB, state: State, sessions: list[Session]) -> None:
    """Summaries stored before they held the range of motion: completed once, kept."""
    if await complete_summaries(sessions, state.settings.data_dir):
        await db.commit()


@router.post("/{session_id}/stop", responses={**_404, **_409})
async def stop(session_id: int, therapist: CurrentTherapist, state: State, db: DB) -> SessionOut:
    session = await _load(db, session_id)
    _require_active(session)
    summary = await state.live.session_stopped(session_info(session))
    await stop_session(db, session, summary=summary)
    audit(db, therapist, "session.stop", f"session:{session.id}")
    await db.commit()
    return session_out(session)


@router.put("/{session_id}/nominal-shoulder", responses={**_404, **_409})
async def set_nominal_shoulder(
    session_id: int, body: NominalShoulderIn, therapist: CurrentTherapist, state: State, db: DB
) -> SessionOut:
    """Set the nominal shoulder to a point, or to the current shoulder estimate."""
    session = await _load(db, session_id)
    _require_active(session)
    from_estimate = body.source == "estimate"
    try:
        point = await state.live.set_nominal_shoulder(
            session_info(session), body.point, from_estimate
        )
    except LiveUnavailable as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    if point is None:
        raise HTTPException(status.HTTP_409_CONFLICT, "no shoulder estimate available yet")
    source: NominalSource = "estimate" if from_estimate else "therapist"
    await store_nominal_shoulder(db, session.id, point, source, therapist.username)
    audit(
        db,
        therapist,
        "session.nominal_shoulder",
        f"session:{session.id}",
        {"source": source, "point": [float(x) for x in point]},
    )
    await db.commit()
    await db.refresh(session, ["nominal_shoulder"])
    return session_out(session)


@router.post("/{session_id}/rom-test", responses={**_404, **_409})
async def start_rom_test(
    session_id: int, body: RomTestIn, therapist: CurrentTherapist, state: State, db: DB
) -> dict[str, Any]:
    """A wearable session: start a range-of-motion test of ``movement`` (one at a time; a
    running one is stopped). Its peak goes into the session's report."""
    session = await _load(db, session_id)
    _require_active(session)
    try:
        test = await state.live.rom_test(session_info(session), body.movement)
    except LiveUnavailable as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    audit(
        db,
        therapist,
        "session.rom_test_start",
        f"session:{session.id}",
        {"movement": body.movement},
    )
    await db.commit()
    return test or {}


@router.delete("/{session_id}/rom-test", responses={**_404, **_409})
async def stop_rom_test(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> dict[str, Any]:
    """Stop the running ROM test; returns it with its peak (``peak_deg`` null: no sure
    sample of the joint during the test)."""
    session = await _load(db, session_id)
    _require_active(session)
    try:
        test = await state.live.rom_test(session_info(session), None)
    except LiveUnavailable as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    if test is None:
        raise HTTPException(status.HTTP_409_CONFLICT, "no ROM test is running")
    audit(db, therapist, "session.rom_test_stop", f"session:{session.id}", test)
    await db.commit()
    return test


@router.delete("/{session_id}/nominal-shoulder", responses={**_404, **_409})
async def reset_nominal_shoulder(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> SessionOut:
    """Forget the nominal shoulder; the pipeline sets it again once the heading converged."""
    session = await _load(db, session_id)
    _require_active(session)
    try:
        await state.live.set_nominal_shoulder(session_info(session), None, False)
    except LiveUnavailable as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    await store_nominal_shoulder(db, session.id, None, "therapist", therapist.username)
    audit(db, therapist, "session.nominal_shoulder_reset", f"session:{session.id}")
    await db.commit()
    await db.refresh(session, ["nominal_shoulder"])
    return session_out(session)


@router.post(
    "/{session_id}/overlay-link", status_code=status.HTTP_201_CREATED, responses={**_404, **_409}
)
async def create_overlay_link(
    session_id: int, therapist: CurrentTherapist, state: State, db: DB
) -> OverlayLinkOut:
    """A link for the patient's game overlay: it reads only this device's live feedback,
    and only while this session is active."""
    session = await _load(db, session_id)
    _require_active(session)
    device = session.device.name
    issued = state.signer.issue_overlay(device, session.id, state.settings.overlay_token_ttl_s)
    audit(db, therapist, "session.overlay_link", f"session:{session.id}", {"device": device})
    await db.commit()
    return OverlayLinkOut(
        # after "#": a browser never sends the fragment, so no request line carries it
        path="/overlay#" + urlencode({"token": issued.token}),
        token=issued.token,
        expires_at=issued.expires_at,
        device=device,
        session_id=session.id,
    )
