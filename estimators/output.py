"""What a poll returns: the estimate rows (one matrix behind a read-only mapping), feedback,
cycle verdicts and episodes, and a device's data-quality counters."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.compensation import Episode
from estimators.verdicts import CycleVerdict

Array: TypeAlias = NDArray[np.float64]
Idx: TypeAlias = NDArray[Any]  # integer and boolean arrays

ROW_COLUMNS = (
    "t",
    "elbow",  # (n,3) m
    "shoulder",  # (n,3) m, NaN until converged
    "elbow_angle_deg",
    "heading_offset_deg",
    "heading_converged",  # bool
    "shoulder_displacement_m",
    "state",  # int8: -1 unknown, 0 ok, 1 outside, 2 warning
    "q_ra",  # (n,4) upper arm in R
    "heading_std_deg",
    "heading_confidence",  # 0..1
    "upper_arm_elevation_deg",  # 0 = hanging down, 90 = horizontal
    "upper_arm_azimuth_deg",  # horizontal direction of the arm, 0 = forward (+y), 90 = +x
    "nominal_shoulder",  # (n,3) m
    "conv_elbow_angle_deg",  # conventional (fixed-shoulder) baseline
    "wrist",  # (n,3) m
    "upper_arm_length_m",
)

# the rows' matrix: each column's first index and width
_WIDTHS = {"elbow": 3, "shoulder": 3, "q_ra": 4, "nominal_shoulder": 3, "wrist": 3}
LAYOUT: list[tuple[str, int, int]] = []
for _name in ROW_COLUMNS:
    _w = _WIDTHS.get(_name, 1)
    LAYOUT.append((_name, sum(w for _, _, w in LAYOUT), _w))
COL = {name: a for name, a, _ in LAYOUT}
SPAN = {name: (a, w) for name, a, w in LAYOUT}
NCOL = sum(w for _, _, w in LAYOUT)


class RowTable(Mapping[str, Any]):
    """The rows of one poll as a read-only mapping ``ROW_COLUMNS`` → arrays, backed by one
    (n, ``NCOL``) matrix: a column is sliced when asked for, so a consumer pays only for
    the columns it reads."""

    __slots__ = ("_cols", "m")

    def __init__(self, m: Array, state: Idx) -> None:
        self.m = m
        self._cols: dict[str, Any] = {"state": state}  # made once (several consumers read)

    def __getitem__(self, name: str) -> Any:
        col = self._cols.get(name)
        if col is None:
            if name == "heading_converged":
                col = self.m[:, COL[name]] > 0.5
            else:
                a, w = SPAN[name]
                col = self.m[:, a] if w == 1 else self.m[:, a : a + w]
            self._cols[name] = col
        return col

    def column_lists(self, index: Idx) -> list[list[float]]:
        """Matrix columns ``index`` (:func:`column_index`) as Python lists, in one numpy
        call (a live poll's one row: a tolist() per column cost several times more)."""
        out: list[list[float]] = self.m[:, index].T.tolist()
        return out

    def __iter__(self) -> Iterator[str]:
        return iter(ROW_COLUMNS)

    def __len__(self) -> int:
        return len(ROW_COLUMNS)


def column_index(names: Sequence[str]) -> Idx:
    """Matrix columns of ``ROW_COLUMNS`` names (every component of a vector column), for
    :meth:`RowTable.column_lists`. Not ``state``: it is not in the matrix."""
    idx: list[int] = []
    for name in names:
        a, w = SPAN[name]
        idx.extend(range(a, a + w))
    return np.array(idx, dtype=np.intp)


def concat_rows(parts: Sequence[Mapping[str, Array]]) -> Mapping[str, Array]:
    """Consecutive polls' rows as one table."""
    if all(isinstance(p, RowTable) for p in parts):
        tables: list[RowTable] = [p for p in parts if isinstance(p, RowTable)]
        return RowTable(
            np.concatenate([p.m for p in tables]),
            np.concatenate([p["state"] for p in tables]),
        )
    return {k: np.concatenate([p[k] for p in parts]) for k in ROW_COLUMNS}


@dataclass
class Output:
    """New rows (``ROW_COLUMNS``, arrays of equal length) and feedback since the last poll."""

    rows: Mapping[str, Array] = field(default_factory=dict)
    feedback: list[dict[str, Any]] = field(default_factory=list)
    cycles: list[CycleVerdict] = field(default_factory=list)
    episodes: list[Episode] = field(default_factory=list)  # tolerated-time rule (§3.4, §5)

    @property
    def n(self) -> int:
        return 0 if not self.rows else len(self.rows["t"])

    def extend(self, other: Output) -> None:
        if other.n:
            if not self.rows:
                self.rows = {k: v.copy() for k, v in other.rows.items()}
            else:
                self.rows = concat_rows([self.rows, other.rows])
        self.feedback.extend(other.feedback)
        self.cycles.extend(other.cycles)
        self.episodes.extend(other.episodes)


@dataclass
class Quality:
    """Data-quality counters of one device's streams (reported, never silently dropped)."""

    rejected: dict[str, int] = field(default_factory=dict)
    ignored: dict[str, int] = field(default_factory=dict)  # valid messages the method does not use
    imu_samples: int = 0
    robot_samples: int = 0
    imu_bridged_gaps: int = 0
    imu_bridged_samples: int = 0
    imu_resets: int = 0
    robot_bridged_gaps: int = 0
    robot_gaps: int = 0
    seq_lost: dict[str, int] = field(default_factory=dict)
    rows_without_imu: int = 0
    heading_resets: int = 0
    gaps: list[dict[str, Any]] = field(default_factory=list)

    def reject(self, reason: str, n: int = 1) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + n

    def as_dict(self) -> dict[str, Any]:
        return {
            "rejected": dict(sorted(self.rejected.items())),
            "ignored": dict(sorted(self.ignored.items())),
            "imu_samples": self.imu_samples,
            "robot_samples": self.robot_samples,
            "imu_bridged_gaps": self.imu_bridged_gaps,
            "imu_bridged_samples": self.imu_bridged_samples,
            "imu_resets": self.imu_resets,
            "robot_bridged_gaps": self.robot_bridged_gaps,
            "robot_gaps": self.robot_gaps,
            "seq_lost": dict(sorted(self.seq_lost.items())),
            "rows_without_imu": self.rows_without_imu,
            "heading_resets": self.heading_resets,
            "gaps": self.gaps[:1000],
        }
