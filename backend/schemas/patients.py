from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from backend.schemas.common import Code, Fraction, Length, Norm, Side, Strict, WarnAfter

_NOTES = Field(
    default="", max_length=10_000, description="Clinical notes. No names or other identifiers."
)


class PatientCreate(Strict):
    code: Code = Field(description="Pseudonymous code; never a name.")
    affected_side: Side
    upper_arm_length_m: Length = 0.30
    imu_to_elbow_m: Length = 0.15
    cuff_to_elbow_m: Length = 0.06
    tolerance_m: Length = 0.10
    max_outside_fraction: Fraction = 0.20
    displacement_norm: Norm = "horizontal"
    warning_after_s: WarnAfter = 1.0
    notes: str = _NOTES


class PatientUpdate(Strict):
    """Only the fields sent are changed; none can be set to null except
    ``warning_after_s`` (null: adaptive)."""

    code: Code | None = None
    affected_side: Side | None = None
    upper_arm_length_m: Length | None = None
    imu_to_elbow_m: Length | None = None
    cuff_to_elbow_m: Length | None = None
    tolerance_m: Length | None = None
    max_outside_fraction: Fraction | None = None
    displacement_norm: Norm | None = None
    warning_after_s: WarnAfter = None
    notes: str | None = Field(default=None, max_length=10_000)


class PatientOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    code: str
    affected_side: Side
    upper_arm_length_m: float
    imu_to_elbow_m: float
    cuff_to_elbow_m: float
    tolerance_m: float
    max_outside_fraction: float
    displacement_norm: Norm
    warning_after_s: float | None = Field(description="seconds; null: adaptive")
    notes: str
    created_by_id: int | None
    created_at: datetime
    updated_at: datetime
    params: dict[str, Any] = Field(description="The contract §4 parameters for a session.")
