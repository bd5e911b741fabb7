from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, model_validator

from backend.schemas.common import DeviceName, ParamsOverride, Point3, Strict


class SessionCreate(Strict):
    patient_id: int
    device: DeviceName
    params: ParamsOverride | None = None


class NominalShoulder(BaseModel):
    point: list[float]
    source: Literal["params", "event", "auto", "therapist", "estimate"]
    set_at: datetime
    set_by: str | None


class NominalShoulderIn(Strict):
    """``{"source": "point", "point": [x, y, z]}`` or ``{"source": "estimate"}``."""

    source: Literal["point", "estimate"]
    point: Point3 | None = None

    @model_validator(mode="after")
    def _point_iff_source_point(self) -> NominalShoulderIn:
        if (self.source == "point") != (self.point is not None):
            raise ValueError("give a point exactly when source is 'point'")
        return self


class SessionOut(BaseModel):
    id: int
    patient_id: int
    patient_code: str
    device: str
    therapist: str | None
    started_at: datetime
    stopped_at: datetime | None
    status: Literal["active", "stopped", "interrupted"]
    params: dict[str, Any]
    recording_path: str | None
    nominal_shoulder: NominalShoulder | None
    summary: dict[str, Any] | None


class OverlayLinkOut(BaseModel):
    path: str
    token: str
    expires_at: datetime
    device: str
    session_id: int
