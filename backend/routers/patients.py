"""Patients: pseudonymous records with the arm and tolerance parameters of their sessions."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, status
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError

from backend.auth.guards import CurrentTherapist
from backend.db.audit import audit
from backend.db.models import Patient, Session
from backend.deps import DB
from backend.schemas.patients import PatientCreate, PatientOut, PatientUpdate

router = APIRouter(prefix="/patients", tags=["patients"])

NULLABLE = frozenset({"warning_after_s"})  # null: the adaptive tolerated duration


def patient_out(patient: Patient) -> PatientOut:
    return PatientOut.model_validate(
        {
            **{c: getattr(patient, c) for c in PatientOut.model_fields if c != "params"},
            "params": patient.params(),
        }
    )


async def get_patient(db: DB, patient_id: int) -> Patient:
    patient = await db.get(Patient, patient_id)
    if patient is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "patient not found")
    return patient


async def _flush_unique_code(db: DB) -> None:
    try:
        await db.flush()
    except IntegrityError:
        raise HTTPException(status.HTTP_409_CONFLICT, "patient code already exists") from None


@router.get("")
async def list_patients(
    db: DB,
    therapist: CurrentTherapist,
    code: Annotated[str | None, Query(max_length=64, description="Code prefix")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> list[PatientOut]:
    stmt = select(Patient).order_by(Patient.code).limit(limit).offset(offset)
    if code:
        escaped = code.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
        stmt = stmt.where(Patient.code.like(escaped + "%", escape="\\"))
    patients = [patient_out(p) for p in await db.scalars(stmt)]
    audit(db, therapist, "patient.list", None, {"code": code, "count": len(patients)})
    await db.commit()
    return patients


@router.post("", status_code=status.HTTP_201_CREATED)
async def create_patient(body: PatientCreate, therapist: CurrentTherapist, db: DB) -> PatientOut:
    patient = Patient(**body.model_dump(), created_by_id=therapist.id)
    db.add(patient)
    await _flush_unique_code(db)
    audit(db, therapist, "patient.create", f"patient:{patient.id}")
    await db.commit()
    return patient_out(patient)


@router.get("/{patient_id}")
async def read_patient(patient_id: int, therapist: CurrentTherapist, db: DB) -> PatientOut:
    patient = patient_out(await get_patient(db, patient_id))
    audit(db, therapist, "patient.read", f"patient:{patient_id}")
    await db.commit()
    return patient


@router.patch("/{patient_id}")
async def update_patient(
    patient_id: int, body: PatientUpdate, therapist: CurrentTherapist, db: DB
) -> PatientOut:
    patient = await get_patient(db, patient_id)
    changes = body.model_dump(exclude_unset=True)
    if any(v is None for k, v in changes.items() if k not in NULLABLE):
        raise HTTPException(422, "fields cannot be set to null (except warning_after_s)")
    for name, value in changes.items():
        setattr(patient, name, value)
    await _flush_unique_code(db)
    # Notes may be sensitive: the log records which fields changed, not their values.
    audit(db, therapist, "patient.update", f"patient:{patient.id}", {"fields": sorted(changes)})
    await db.commit()
    await db.refresh(patient)
    return patient_out(patient)


@router.delete("/{patient_id}", status_code=status.HTTP_204_NO_CONTENT)
async def delete_patient(patient_id: int, therapist: CurrentTherapist, db: DB) -> None:
    """Only a patient without sessions can be deleted: recorded data is never dropped here."""
    patient = await get_patient(db, patient_id)
    if await db.scalar(select(func.count()).where(Session.patient_id == patient.id)):
        raise HTTPException(status.HTTP_409_CONFLICT, "patient has sessions")
    await db.delete(patient)
    audit(db, therapist, "patient.delete", f"patient:{patient_id}", {"code": patient.code})
    await db.commit()
