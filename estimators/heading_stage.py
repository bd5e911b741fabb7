"""Stage 4 of the pipeline: the heading schedule (§3.2.2). Updates of δ on a fixed lattice
of the sample clock (every 5 s for the paper's method; every second until converged, then
every 5 s, for the improved one) over the fusion grid's windows, and the snapshot of the
heading after each update, which the rows look up."""

from __future__ import annotations

import bisect
import math

import numpy as np

from estimators import heading as hd
from estimators.grid_stage import GridStage
from estimators.output import Quality

NAN8 = (math.nan,) * 8


class HeadingStage:
    """The heading schedule and its snapshots ``(t, δ, rate, t_update, std, converged, imu
    segment, robot latency)`` after each update."""

    def __init__(self, hp: hd.HeadingParams, quality: Quality) -> None:
        self.hp = hp
        self.quality = quality
        self.state = hd.HeadingState()
        self._seg = 0
        self.t_next: float | None = None  # time of the next update
        self._snaps: list[tuple[float, ...]] = []
        self._snap_t: list[float] = []
        self.convergence_time: float | None = None
        self.first_motion_time: float | None = None

    @property
    def span_s(self) -> float:
        """How much of the grid an update reads, s."""
        hp = self.hp
        return hp.window_s if hp.method == "paper" else max(hp.window_s, hp.fit_window_s)

    def run(self, grid: GridStage) -> None:
        """Every update the grid has reached."""
        hp = self.hp
        front = grid.frontier
        if not math.isfinite(front):
            return
        if self.t_next is None:
            step = hp.update_interval_s
            self.t_next = (math.floor(grid.t[0] / step) + 1) * step
        snaps: list[tuple[float, ...]] = []
        while self.t_next <= front:
            t_up = self.t_next
            # updates on a fixed lattice of the sample clock; sparser once converged
            step = hp.update_interval_s
            if hp.method == "improved" and self.state.converged:
                step = hp.converged_interval_s
            self.t_next = (math.floor(t_up / step + 1e-9) + 1) * step
            i = min(int(np.searchsorted(grid.t, t_up, side="right")) - 1, len(grid.seg) - 1)
            seg = int(grid.seg[i])
            if seg != self._seg:
                self.state = hd.HeadingState()
                self._seg = seg
                self.quality.heading_resets += 1
            w = grid.window(t_up, self.span_s, seg)
            if hp.method == "paper":
                counted = hd.update_paper(self.state, w, hp, t_up)
            else:
                counted = hd.update_improved(self.state, w, hp, t_up, grid.lag)
            if counted and self.first_motion_time is None:
                self.first_motion_time = t_up
            if self.state.converged and self.convergence_time is None:
                self.convergence_time = t_up
            s = self.state
            d = math.nan if s.delta is None else s.delta
            snaps.append(
                (t_up, d, s.rate, s.t_update, s.std, float(s.converged), float(seg), s.lag)
            )
        self._snaps.extend(snaps)
        self._snap_t.extend(s[0] for s in snaps)

    def snapshot(self, t: float) -> tuple[float, ...]:
        """The heading after the latest update at or before ``t`` (NaN before the first)."""
        i = bisect.bisect_right(self._snap_t, t) - 1
        return self._snaps[i] if i >= 0 else NAN8

    def snapshots(self) -> list[tuple[float, ...]]:
        """The snapshots kept, oldest first (each as :meth:`snapshot` gives it); read only."""
        return self._snaps

    def trim(self, t_keep: float) -> None:
        """Forget snapshots no row at or after ``t_keep`` can use."""
        cut = bisect.bisect_right(self._snap_t, t_keep) - 2
        if cut > 0:
            del self._snaps[:cut]
            del self._snap_t[:cut]
