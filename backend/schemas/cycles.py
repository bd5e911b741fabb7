from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict


class CycleOut(BaseModel):
    """Times are sample times (seconds, the device's clock), as in report.json."""

    model_config = ConfigDict(from_attributes=True)

    index: int
    start: float
    end: float
    outside_fraction: float
    compensatory: bool
    coverage: float | None
    peak_displacement_m: float | None
    recorded_at: datetime
