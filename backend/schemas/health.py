from __future__ import annotations

from typing import Literal

from pydantic import BaseModel


class HealthOut(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    database: Literal["ok", "unreachable"]
    # how the estimators run: always interpreted (the optional compiled build is gone)
    estimators: Literal["interpreted"]
