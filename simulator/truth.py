"""Ground truth of a simulated session, and its ``.npz`` file format.

All times are on the streams' clock (seconds); positions are in the robot frame R, metres;
quaternions are (w, x, y, z) and rotate body vectors into R.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from simulator.subject import Subject

F64: TypeAlias = NDArray[np.float64]

TOLERANCE_M = 0.10  # contract default: shoulder displacement tolerance (horizontal)
MAX_OUTSIDE_FRACTION = 0.20  # contract default: a cycle is compensatory above this


@dataclass(frozen=True)
class Cycles:
    """Complete task cycles (K): the wrist passes the front-right corner at start and end."""

    start: F64  # (K,) s
    end: F64  # (K,) s
    phase: NDArray[np.int8]  # (K,) 1 proper, 2 transition (spans two phases), 3 compensatory
    outside_fraction: F64  # (K,) time fraction with horizontal displacement > TOLERANCE_M
    peak_displacement_m: F64  # (K,) largest horizontal shoulder displacement
    compensatory: NDArray[np.bool_]  # (K,) outside_fraction > MAX_OUTSIDE_FRACTION

    def __len__(self) -> int:
        return int(self.start.shape[0])

    def to_list(self) -> list[dict[str, Any]]:
        """Rows shaped like ``report.json``'s cycles, plus ``phase``."""
        return [
            {
                "start": float(s),
                "end": float(e),
                "outside_fraction": float(f),
                "compensatory": bool(c),
                "phase": int(p),
            }
            for s, e, f, c, p in zip(
                self.start,
                self.end,
                self.outside_fraction,
                self.compensatory,
                self.phase,
                strict=True,
            )
        ]


@dataclass(frozen=True)
class Truth:
    """True state at the IMU sample times (M samples; ``t`` equals the IMU stamps)."""

    t: F64  # (M,) s
    shoulder: F64  # (M,3)
    elbow: F64  # (M,3)
    wrist: F64  # (M,3) wrist joint centre
    elbow_angle_deg: F64  # (M,) 0 = extended
    q_ra: F64  # (M,4) upper-arm segment frame A (x shoulder→elbow) in R
    q_imu: F64  # (M,4) IMU sensor frame in R
    imu_position: F64  # (M,3) sensor centre
    gyro_bias: F64  # (M,3) rad/s, sensor frame, the bias actually added
    shoulder_displacement_m: F64  # (M,) horizontal distance from the nominal shoulder
    phase: NDArray[np.int8]  # (M,) 0 rest, 1 proper, 2 transition, 3 compensatory
    cycle: NDArray[np.int64]  # (M,) index into ``cycles``, −1 outside complete cycles
    nominal_shoulder: F64  # (3,) shoulder during the initial rest
    corner_t: F64  # (E,) s, the wrist passes a rectangle corner (rope oscillations start)
    cycles: Cycles

    def save(self, path: str | Path, subject: Subject | None = None) -> None:
        """Write a compressed ``.npz``; ``subject`` goes inside as JSON (key ``subject_json``)."""
        arrays: dict[str, Any] = {
            f.name: getattr(self, f.name) for f in fields(self) if f.name != "cycles"
        }
        arrays.update({f"cycles_{f.name}": getattr(self.cycles, f.name) for f in fields(Cycles)})
        if subject is not None:
            arrays["subject_json"] = np.array(subject.to_json())
        with open(path, "wb") as fh:  # a file object keeps numpy from appending ".npz"
            np.savez_compressed(fh, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> Truth:
        """Read a file written by :meth:`save`."""
        with np.load(path, allow_pickle=False) as data:
            cyc = Cycles(**{f.name: data[f"cycles_{f.name}"] for f in fields(Cycles)})
            kw = {f.name: data[f.name] for f in fields(cls) if f.name != "cycles"}
        return cls(cycles=cyc, **kw)


def load(path: str | Path) -> Truth:
    """Same as :meth:`Truth.load`."""
    return Truth.load(path)


def load_subject(path: str | Path) -> Subject | None:
    """The subject stored inside a truth ``.npz``, if any."""
    with np.load(path, allow_pickle=False) as data:
        if "subject_json" not in data:
            return None
        return Subject.from_json(str(data["subject_json"]))
