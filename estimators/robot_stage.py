"""Stage 2 of the pipeline: the robot's elbow positions, split into segments at gaps."""

from __future__ import annotations

import bisect
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.buffers import RowBuffer
from estimators.output import Quality
from estimators.params import PipelineParams

Array: TypeAlias = NDArray[np.float64]
Idx: TypeAlias = NDArray[Any]  # integer and boolean arrays


class RobotStage:
    """The elbow positions on the physical time base (stamp − offset), with segments split
    at gaps longer than ``robot_max_bridge_s``."""

    def __init__(self, p: PipelineParams) -> None:
        self.p = p
        self.buf = RowBuffer(5)  # t, segment id, p_E (3)
        self.tail: list[float] = []  # rows not yet in buf, end to end (one by one: cheaper)
        self.tl: list[float] = []
        self.seg = 0

    def _flush(self) -> None:
        if self.tail:
            rows = np.fromiter(self.tail, np.float64, len(self.tail)).reshape(-1, 5)
            self.buf.append(rows)
            self.tail = []

    def append(self, s: list[float], p_e: Any, q: Quality) -> None:
        """Samples at physical times ``s``; ``p_e`` (n, 3) array or n float triples."""
        segs = self._segments(s, q)
        if isinstance(p_e, list):  # a message's few: rows as floats, one flat list
            tail = self.tail
            for x, g, e in zip(s, segs, p_e, strict=True):
                tail += (x, g, *e)
            self.tl.extend(s)
            return
        self._flush()
        rows = np.empty((len(s), 5))
        rows[:, 0] = s
        rows[:, 1] = segs
        rows[:, 2:5] = p_e
        self.buf.append(rows)
        self.tl.extend(s)

    def _segments(self, s: list[float], q: Quality) -> list[int]:
        """Segment ids of samples at times ``s``: a new one after each gap longer than
        ``robot_max_bridge_s`` (counted, as the shorter bridged ones are)."""
        seg = self.seg
        segs: list[int] = []
        prev = self.tl[-1] if self.tl else None
        bridge = self.p.robot_max_bridge_s
        for x in s:
            if prev is not None:
                d = x - prev
                if d > bridge:
                    q.robot_gaps += 1
                    q.gaps.append({"stream": "robot", "t": prev, "duration_s": d})
                    seg += 1
                elif d > _BRIDGED_S:
                    q.robot_bridged_gaps += 1
            segs.append(seg)
            prev = x
        self.seg = seg
        return segs

    def interp(self, g: Array) -> tuple[Idx, Array]:
        n = len(self.tl)
        if n < 2:
            return np.zeros(len(g), bool), np.full((len(g), 3), np.nan)
        self._flush()
        v = self.buf.view()
        t, segid, p_e = np.ascontiguousarray(v[:, 0]), v[:, 1], v[:, 2:5]
        i1 = np.searchsorted(t, g, side="left")
        np.minimum(np.maximum(i1, 1, out=i1), n - 1, out=i1)  # np.clip's (ints): 4x cheaper
        i0 = i1 - 1
        ok = (g >= t[0]) & (g <= t[-1]) & (segid[i0] == segid[i1])
        w = np.clip((g - t[i0]) / (t[i1] - t[i0]), 0.0, 1.0)
        return ok, p_e[i0] + w[:, None] * (p_e[i1] - p_e[i0])

    def trim(self, t_keep: float) -> None:
        i = max(0, bisect.bisect_left(self.tl, t_keep) - 2)
        if i > 0:
            self._flush()
            self.buf.drop(i)
            del self.tl[:i]


_BRIDGED_S = 2.5 / 25.0  # s between robot samples counted as a bridged gap
