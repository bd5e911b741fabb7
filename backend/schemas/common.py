"""Shared field types and the analysis parameters (contract §4)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

Finite = Annotated[float, Field(allow_inf_nan=False)]
Point3 = Annotated[list[Finite], Field(min_length=3, max_length=3, description="[x, y, z], m")]
Length = Annotated[float, Field(gt=0, le=2, allow_inf_nan=False, description="metres")]
Fraction = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
Side = Literal["left", "right"]
Norm = Literal["horizontal", "3d"]
# Same rule as the contract's device ids: letters, digits, '_' and '-'. No spaces, which
# discourages typing a patient's name as the code.
Code = Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,64}$")]
DeviceName = Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,64}$")]
# Tolerated continuous time outside before the warning; None (JSON null) is the adaptive
# mode: max_outside_fraction × the duration of the last cycle (before any cycle, 1 s).
WarnAfter = Annotated[
    float | None,
    Field(
        ge=0, le=600, allow_inf_nan=False,
        description="seconds; null: adaptive (max_outside_fraction × the last cycle's duration)",
    ),
]  # fmt: skip


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Params(Strict):
    """Analysis parameters of contract §4, plus the tolerated time outside (``warning``)."""

    upper_arm_length_m: Length = 0.30
    imu_to_elbow_m: Length = 0.15
    cuff_to_elbow_m: Length = 0.06
    tolerance_m: Length = 0.10
    max_outside_fraction: Fraction = 0.20
    displacement_norm: Norm = "horizontal"
    warning_after_s: WarnAfter = 1.0
    nominal_shoulder_m: Point3 | None = None


class ParamsOverride(Strict):
    """Session-only changes to the patient's parameters; omitted keys (or null) keep the
    patient's. Exception: an explicit ``"warning_after_s": null`` selects the adaptive
    tolerated duration for this session (see :func:`overrides`)."""

    upper_arm_length_m: Length | None = None
    imu_to_elbow_m: Length | None = None
    cuff_to_elbow_m: Length | None = None
    tolerance_m: Length | None = None
    max_outside_fraction: Fraction | None = None
    displacement_norm: Norm | None = None
    warning_after_s: WarnAfter = None
    nominal_shoulder_m: Point3 | None = None


def overrides(body: ParamsOverride | None) -> dict[str, object]:
    """The keys ``body`` changes: those given and not null, and ``warning_after_s`` whenever
    it was given (null: adaptive)."""
    if body is None:
        return {}
    out: dict[str, object] = body.model_dump(exclude_none=True)
    if "warning_after_s" in body.model_fields_set:
        out["warning_after_s"] = body.warning_after_s
    return out
