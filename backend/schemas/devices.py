from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel


class DeviceOut(BaseModel):
    name: str
    first_seen: datetime
    last_seen: datetime
    status: Literal["online", "offline"]
    stats: dict[str, Any] | None
    active_session_id: int | None
