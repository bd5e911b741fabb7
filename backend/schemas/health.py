from __future__ import annotations

from typing import Literal

from pydantic import BaseModel

from estimators.aot import Mode


class HealthOut(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    database: Literal["ok", "unreachable"]
    # how the kernels run: compiled ahead of time, numba's JIT, or interpreted (estimators.aot)
    estimators: Mode
