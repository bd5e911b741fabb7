"""Simulation configuration and the session layout (which phase when)."""

from __future__ import annotations

import re
from dataclasses import dataclass

from simulator.subject import Subject

REST, PROPER, TRANSITION, COMPENSATORY = 0, 1, 2, 3
PHASE_CODES = {
    "rest": REST,
    "proper": PROPER,
    "transition": TRANSITION,
    "compensatory": COMPENSATORY,
}
PHASE_NAMES = {v: k for k, v in PHASE_CODES.items()}

Layout = tuple[tuple[str, float], ...]

# The 8-minute session of the paper's protocol; durations in seconds.
DEFAULT_LAYOUT_480: Layout = (
    ("rest", 5.0),
    ("proper", 195.0),
    ("transition", 20.0),
    ("compensatory", 180.0),
    ("transition", 15.0),
    ("proper", 65.0),
)

ERROR_SWITCHES = (
    "gyro_noise",
    "acc_noise",
    "gyro_bias",
    "acc_bias",
    "misalignment",
    "radial_offset",
    "wobble",
    "robot_noise",
    "rope",
    "latency",
    "reference_noise",
)

_DEVICE_RE = re.compile(r"[A-Za-z0-9_-]{1,64}")


def default_layout(duration_s: float) -> Layout:
    """:data:`DEFAULT_LAYOUT_480` with everything after the 5 s rest scaled to ``duration_s``."""
    rest = DEFAULT_LAYOUT_480[0][1]
    scale = max(duration_s - rest, 0.0) / (480.0 - rest)
    return (DEFAULT_LAYOUT_480[0], *((n, d * scale) for n, d in DEFAULT_LAYOUT_480[1:]))


@dataclass(frozen=True)
class SimConfig:
    """Everything about one simulated session. Units: s, Hz, m, rad/s, m/s².

    Error switches are ``None`` (follow ``ideal``: on unless ``ideal``) or an explicit bool,
    so ``SimConfig(ideal=True, wobble=True)`` isolates one error.
    """

    seed: int = 0
    duration_s: float = 480.0
    subject: Subject | None = None  # None: drawn from the seed
    layout: Layout | None = None  # (phase name, duration s) pairs; None: default_layout
    imu_rate_hz: float = 100.0
    robot_rate_hz: float = 25.0
    imu_batch: int = 4  # samples per IMU message
    robot_batch: int = 1  # samples per robot message
    device: str = "sim01"
    segment: str = "upperarm"
    cycle_events: bool = False
    t0_s: float = 0.0  # clock reading at the session start
    robot_time_offset_s: float = 0.0  # robot stamps are t0 + offset + k / robot_rate
    cuff_to_elbow_m: float = 0.06  # proximal cuff, device property (contract default)
    wrist_cuff_m: float = 0.02  # wrist cuff, proximal of the wrist joint centre
    round_output: bool = True  # µs stamps, µm positions, 1e-7 rad/s, 1e-6 m/s² on the wire
    # error magnitudes (used when the matching switch is on)
    gyro_noise_rad_s: float = 0.005  # white noise rms per axis at 100 Hz (scales with √rate)
    acc_noise_m_s2: float = 0.03  # white noise rms per axis at 100 Hz (scales with √rate)
    gyro_bias_walk_dps: float = 0.002  # bias random walk, °/s per √s
    gyro_bias_scale: float = 1.0  # the drawn subject's gyro bias times this (fast drift: 2.5)
    robot_noise_m: float = 0.0015  # white noise per axis per cuff
    # error switches
    ideal: bool = False
    gyro_noise: bool | None = None
    acc_noise: bool | None = None
    gyro_bias: bool | None = None
    acc_bias: bool | None = None
    misalignment: bool | None = None
    radial_offset: bool | None = None
    wobble: bool | None = None
    robot_noise: bool | None = None
    rope: bool | None = None
    latency: bool | None = None
    reference_noise: bool | None = None

    def __post_init__(self) -> None:
        if self.duration_s <= 0:
            raise ValueError("duration_s must be positive")
        if not (self.imu_rate_hz > 0 and self.robot_rate_hz > 0):
            raise ValueError("rates must be positive")
        if self.imu_batch < 1 or self.robot_batch < 1:
            raise ValueError("batch sizes must be ≥ 1")
        if not _DEVICE_RE.fullmatch(self.device):
            raise ValueError(f"device name {self.device!r} does not match {_DEVICE_RE.pattern}")
        spans = self.spans()
        if spans[0][0] != REST or any(p == REST for p, _, _ in spans[1:]):
            raise ValueError("the layout must start with, and have only, one initial rest")
        if spans[0][2] >= self.duration_s:
            raise ValueError("the session must be longer than its initial rest")

    def enabled(self, switch: str) -> bool:
        """Whether the named error is on."""
        if switch not in ERROR_SWITCHES:
            raise KeyError(switch)
        value: bool | None = getattr(self, switch)
        return (not self.ideal) if value is None else value

    def switches(self) -> dict[str, bool]:
        return {s: self.enabled(s) for s in ERROR_SWITCHES}

    def spans(self) -> list[tuple[int, float, float]]:
        """(phase code, start s, end s) in session time; the last span runs to the end."""
        layout = self.layout if self.layout is not None else default_layout(self.duration_s)
        out: list[tuple[int, float, float]] = []
        t = 0.0
        for name, dur in layout:
            if name not in PHASE_CODES:
                raise ValueError(f"unknown phase {name!r}; use one of {sorted(PHASE_CODES)}")
            if dur <= 0:
                continue
            if t >= self.duration_s:
                break
            out.append((PHASE_CODES[name], t, t + float(dur)))
            t += float(dur)
        if not out:
            raise ValueError("empty layout")
        last = out[-1]
        out[-1] = (last[0], last[1], max(last[2], self.duration_s))
        return out
