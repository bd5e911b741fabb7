"""What the service knows about each device beside its pipeline: presence, rates, counters.

All wall-clock here (arrival times, last seen, rates) is for the dashboard and the registry
only; the pipelines never see it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any


@dataclass
class DeviceStats:
    name: str
    messages: int = 0  # received from Zenoh (any payload)
    bytes: int = 0
    accepted: int = 0  # decoded and fed to the pipeline
    rejected: dict[str, int] = field(default_factory=dict)  # by reason, before the pipeline
    dropped: int = 0  # the device's queue was full (ingest never blocks)
    pipeline_errors: int = 0  # exceptions caught; the pipeline was reset
    imu_samples: int = 0
    robot_samples: int = 0
    last_seen: float | None = None  # wall time of the last message
    token: bool = False  # a Zenoh liveliness token of the device is alive
    online: bool = False
    rates_hz: dict[str, float] = field(default_factory=lambda: {"imu": 0.0, "robot": 0.0})
    _tick_t: float = field(default_factory=time.monotonic)
    _tick_imu: int = 0
    _tick_robot: int = 0

    def reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def tick(self, now_mono: float) -> None:
        """Samples per second over the last tick (called about once a second)."""
        dt = now_mono - self._tick_t
        if dt < 0.2:
            return
        self.rates_hz = {
            "imu": round((self.imu_samples - self._tick_imu) / dt, 2),
            "robot": round((self.robot_samples - self._tick_robot) / dt, 2),
        }
        self._tick_t = now_mono
        self._tick_imu, self._tick_robot = self.imu_samples, self.robot_samples

    def update_online(self, now_wall: float, offline_after_s: float) -> bool:
        """Online: a liveliness token, or data within ``offline_after_s``. True if changed."""
        recent = self.last_seen is not None and now_wall - self.last_seen <= offline_after_s
        online = self.token or recent
        changed = online != self.online
        self.online = online
        return changed

    def ingest(self) -> dict[str, Any]:
        return {
            "messages": self.messages,
            "bytes": self.bytes,
            "accepted": self.accepted,
            "rejected": dict(sorted(self.rejected.items())),
            "dropped": self.dropped,
            "pipeline_errors": self.pipeline_errors,
        }
