from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from backend.schemas.common import DeviceName, Length, ParamsOverride, Point3, Strict


class ImuMounting(Strict):
    """Contract §8: the IMU's position in its segment's frame (m) and the rotation [w, x, y,
    z] of IMU coordinates into it."""

    position_m: Point3 | None = None
    quat: Annotated[list[float], Field(min_length=4, max_length=4)] | None = None


class WearableSpec(Strict):
    """A wearable session (contract §8): two IMUs and an optional camera, no robot. Omitted
    keys take §8's defaults; the upper-arm length is the patient's."""

    side: Literal["left", "right"] | None = None
    forearm_length_m: Length | None = None
    upperarm_imu: ImuMounting | None = None
    forearm_imu: ImuMounting | None = None
    filter: Literal["ekf", "ukf"] | None = None
    model: Literal["A", "B", "C"] | None = None


class SessionCreate(Strict):
    patient_id: int
    device: DeviceName
    params: ParamsOverride | None = None
    wearable: WearableSpec | None = None  # a wearable session (contract §8 "mode")


class RomTestIn(Strict):
    """Start a range-of-motion test: the movement the therapist asks for."""

    movement: Literal[
        "shoulder_flexion",
        "shoulder_extension",
        "shoulder_abduction",
        "shoulder_internal_rotation",
        "shoulder_external_rotation",
        "elbow_flexion",
        "elbow_extension",
        "forearm_pronation",
        "forearm_supination",
    ]


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


class Open(BaseModel):
    model_config = ConfigDict(extra="allow")  # reports may grow; clients ignore the rest


class Spread(Open):
    median: float | None = None
    p95: float | None = None
    max: float | None = None


class Range(Open):
    """Over the rows with a converged heading; p5..p95 is the robust range."""

    min: float | None = None
    max: float | None = None
    p5: float | None = None
    p95: float | None = None
    range: float | None = None


class SessionSummary(Open):
    """What the sessions table keeps of a finished session's report: enough for a patient's
    history and trends without reading (and auditing as an export) every report. Sessions
    stored before a key existed get it from their stored report when first listed."""

    rows: int | None = None
    cycles: int | None = None
    compensatory_cycles: int | None = None
    compensatory_share: float | None = None
    time_outside_share: float | None = None
    heading_converged_t: float | None = None
    shoulder_displacement_m: Spread | None = None
    elbow_flexion_deg: Range | None = None
    upper_arm_elevation_deg: Range | None = None
    upper_arm_azimuth_deg: Range | None = None
    rejected_messages: int | None = None


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
    summary: SessionSummary | None


class OverlayLinkOut(BaseModel):
    path: str
    token: str
    expires_at: datetime
    device: str
    session_id: int
