from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict


class AuditOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    at: datetime
    therapist_id: int | None
    actor: str | None
    action: str
    object: str | None
    details: dict[str, Any] | None
