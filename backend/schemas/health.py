from __future__ import annotations

from typing import Literal

from pydantic import BaseModel


class HealthOut(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    database: Literal["ok", "unreachable"]
    # the live path's estimators: compiled with mypyc at set-up, or interpreted (same numbers)
    estimators: Literal["compiled", "interpreted"]
