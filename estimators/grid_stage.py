"""Stage 3 of the pipeline: the fusion grid, both elbow accelerations on one uniform time
base, low-passed (§3.2.1), as windows for the heading updates."""

from __future__ import annotations

import math
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators import heading as hd
from estimators.filters import LowPass, dc_group_delay_s
from estimators.imu_stage import ImuStage
from estimators.params import PipelineParams
from estimators.robot_stage import RobotStage

Array: TypeAlias = NDArray[np.float64]
Idx: TypeAlias = NDArray[Any]  # integer and boolean arrays
NCH = 18  # grid channels: v (3), u (3), sensor axes in I (9), robot elbow (3)


class GridStage:
    """Both elbow accelerations on a uniform time base, low-passed (§3.2.1, step 5)."""

    def __init__(self, p: PipelineParams) -> None:
        self.p = p
        self.dt = 1.0 / p.fusion_rate_hz
        # anti-alias kernel half-width (first null at fusion_rate/2); 0: plain interpolation
        self.half = 2.0 * self.dt if p.use_antialias else 0.0
        self.lp = LowPass(p.lowpass_order, p.lowpass_cutoff_hz, p.fusion_rate_hz)
        # Optional common high-pass on both accelerations: removes the slowly varying
        # gravity leakage of the 6D filter's inclination error (robot side has none).
        self.hp = LowPass(2, p.highpass, p.fusion_rate_hz, "highpass") if p.highpass > 0 else None
        self.hp_zi: Array | None = None
        # VQF levels itself with a first-order time constant tauAcc on the accelerometer
        tilt_hz = 1.0 / (2.0 * math.pi * p.vqf_tau_acc_s)
        self.tilt = LowPass(1, tilt_hz, p.fusion_rate_hz, "highpass")
        self.tilt_zi: Array | None = None
        self.lag = dc_group_delay_s(p.lowpass_order, p.lowpass_cutoff_hz, p.fusion_rate_hz)
        self.settle = int(math.ceil(3.0 * self.lag * p.fusion_rate_hz))
        self.k_next: int | None = None  # next grid index (time k·dt)
        self.zi: Array | None = None
        self.hist_y = np.empty((0, NCH))  # last two filtered rows (v, u, c, p)
        self.hist_x = np.empty((0, NCH))  # ... and their raw values
        self.hist_g = np.empty(0)
        self.since = 0
        self.imu_seg = -1
        # aligned output buffer (time of sample k−1)
        self.t = np.empty(0)
        self.a = np.empty((0, 3))
        self.b = np.empty((0, 3))
        self.pos = np.empty((0, 3))
        self.valid = np.empty(0, dtype=bool)
        self.seg = np.empty(0, dtype=np.int64)
        self.cl = np.empty((0, 18))  # sensor axes in I (9) and their second derivative (9)

    @property
    def frontier(self) -> float:
        return float(self.t[-1]) if len(self.t) else -math.inf

    def advance(self, imu: ImuStage, robot: RobotStage, until: float) -> None:
        if not imu.tl or not robot.tl:
            return
        if self.k_next is None:
            self.k_next = int(math.ceil(max(imu.tl[0], robot.tl[0]) / self.dt))
        k_end = int(math.floor(until / self.dt))
        if k_end * self.dt > until:
            # k·dt can round above ``until`` (1503 × 0.04 = 60.120000000000005 > 60.12): that
            # point lies past the newest sample, would be judged invalid now and never be
            # revisited (a filter restart a batch run does not have). The next advance takes it.
            k_end -= 1
        if k_end < self.k_next:
            return
        g = np.arange(self.k_next, k_end + 1, dtype=np.float64) * self.dt
        self.k_next = k_end + 1
        if self.half > 0:
            ok_i, vu = imu.smooth(g, self.half)
        else:
            ok_i, vu = imu.interp_channels(g)
        # (the buffer's time column: the same floats as imu.tl, without a list conversion)
        segs = imu.segid[np.clip(np.searchsorted(imu.t, g), 0, len(imu.tl) - 1)]
        ok_r, p = robot.interp(g)
        ok = ok_i & ok_r
        x = np.concatenate((vu, p), axis=1)
        parts: list[tuple[Array, Array, Array, Array, Idx, Idx, Array]] = []
        # contiguous runs of valid samples within one IMU segment
        brk = np.flatnonzero(np.diff(ok.astype(np.int8)) != 0) + 1
        seg_brk = np.flatnonzero(np.diff(segs) != 0) + 1
        bounds = np.unique(np.concatenate(([0], brk, seg_brk, [len(g)])))
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
            if not ok[lo]:
                self.zi = None
                continue
            xs = x[lo:hi]
            if self.zi is None or int(segs[lo]) != self.imu_seg:
                # restart after a gap: steady state at the first value, wait for settling
                self.zi = self.lp.initial_state(xs[0])
                self.hp_zi = None
                self.tilt_zi = None
                self.hist_y = np.empty((0, NCH))
                self.hist_x = np.empty((0, NCH))
                self.since = 0
                self.imu_seg = int(segs[lo])
            y, self.zi = self.lp(xs, self.zi)
            yy = np.concatenate((self.hist_y, y))
            xx = np.concatenate((self.hist_x, xs))
            gg = np.concatenate((self.hist_g, g[lo:hi]))[-len(yy) :]
            if len(yy) >= 3:
                # second difference at k is centred at k−1: align everything to k−1
                d2 = (yy[2:] - 2.0 * yy[1:-1] + yy[:-2]) / (self.dt * self.dt)
                m = len(d2)
                since = self.since + np.arange(1, m + 1)
                # a (IMU side), b (robot side), then the bias channels (sensor axes in I)
                # and the lever channels (their second derivative)
                ab = np.concatenate(
                    (yy[1:-1, 0:3] + d2[:, 3:6], d2[:, 15:18], yy[1:-1, 6:15], d2[:, 6:15]), axis=1
                )
                if self.tilt is not None:
                    # the 6D filter levels itself on the slow part of a rotated bias: only
                    # the faster part reaches the acceleration (VQF's tauAcc)
                    if self.tilt_zi is None:
                        self.tilt_zi = self.tilt.initial_state(ab[0, 6:15])
                    ab[:, 6:15], self.tilt_zi = self.tilt(ab[:, 6:15], self.tilt_zi)
                if self.hp is not None:
                    if self.hp_zi is None:
                        self.hp_zi = self.hp.initial_state(np.zeros(ab.shape[1]))
                    ab, self.hp_zi = self.hp(ab, self.hp_zi)
                parts.append(
                    (
                        gg[1:-1],
                        ab[:, 0:3],
                        ab[:, 3:6],
                        xx[1:-1, 15:18],
                        since > self.settle,
                        np.full(m, self.imu_seg),
                        ab[:, 6:24],
                    )
                )
                self.since += m
            self.hist_y, self.hist_x, self.hist_g = yy[-2:], xx[-2:], gg[-2:]
        if parts:
            self.t = np.concatenate([self.t, *(pt[0] for pt in parts)])
            self.a = np.concatenate([self.a, *(pt[1] for pt in parts)])
            self.b = np.concatenate([self.b, *(pt[2] for pt in parts)])
            self.pos = np.concatenate([self.pos, *(pt[3] for pt in parts)])
            self.valid = np.concatenate([self.valid, *(pt[4] for pt in parts)])
            self.seg = np.concatenate([self.seg, *(pt[5] for pt in parts)])
            self.cl = np.concatenate([self.cl, *(pt[6] for pt in parts)])

    def window(self, t_end: float, span: float, seg: int) -> hd.Window:
        lo = int(np.searchsorted(self.t, t_end - span, side="right"))
        hi = int(np.searchsorted(self.t, t_end, side="right"))
        sl = slice(lo, hi)
        valid = self.valid[sl] & (self.seg[sl] == seg)
        return hd.Window(self.t[sl], self.a[sl], self.b[sl], self.pos[sl], valid, self.cl[sl])

    def trim(self, t_keep: float) -> None:
        i = int(np.searchsorted(self.t, t_keep))
        if i > 0:
            self.t, self.a, self.b = self.t[i:], self.a[i:], self.b[i:]
            self.pos, self.valid, self.seg = self.pos[i:], self.valid[i:], self.seg[i:]
            self.cl = self.cl[i:]
