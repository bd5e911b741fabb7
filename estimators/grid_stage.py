"""Stage 3 of the pipeline: the fusion grid, both elbow accelerations on one uniform time
base, low-passed (§3.2.1), as windows for the heading updates."""

from __future__ import annotations

import itertools
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


def _filter(f: LowPass, x: Array, z: Array) -> None:
    """``f`` along the rows of ``x`` (C, N), in place, from and into the state ``z``
    (C, sections, 2) (the grid keeps its channels as rows)."""
    y, zf = f(x.T, z.transpose(1, 2, 0))
    x[...] = y.T
    z[...] = zf.transpose(2, 0, 1)


def _state(f: LowPass, x0: Array) -> Array:
    """:meth:`LowPass.initial_state` as :func:`_filter`'s (C, sections, 2)."""
    return np.ascontiguousarray(f.initial_state(x0).transpose(2, 0, 1))


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
        # filter states, channels first (:func:`_filter`)
        self.zi: Array | None = None
        self.hist_y = np.empty((NCH, 0))  # last two filtered samples (v, u, c, p), channels first
        self.hist_p = np.empty((0, 3))  # ... their robot elbow positions
        self.hist_g = np.empty(0)  # ... and times
        self.since = 0
        self.imu_seg = -1
        # aligned output (time of sample k−1); each advance makes new arrays (views handed
        # out stay valid). Growable arrays with spare capacity measured slower live.
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
        segid = imu.segid
        n = len(segid)
        if segid[0] == segid[n - 1]:  # one IMU segment (ids only grow)
            segs = None
        else:
            segs = segid[np.clip(np.searchsorted(imu.t, g), 0, n - 1)]
        ok_r, p = robot.interp(g)
        ok = ok_i & ok_r
        ng = len(g)
        # the channels as rows (v, u, c, p), filtered in place
        x = np.empty((NCH, ng))
        x[:15] = vu.T
        x[15:] = p.T
        if segs is None and ok.all():  # the usual advance: one run
            bounds = [0, ng]
        else:
            # contiguous runs of valid samples within one IMU segment
            if segs is None:
                segs = np.full(ng, segid[0])
            brk = np.flatnonzero(np.diff(ok.astype(np.int8)) != 0) + 1
            seg_brk = np.flatnonzero(np.diff(segs) != 0) + 1
            bounds = np.unique(np.concatenate(([0], brk, seg_brk, [ng]))).tolist()
        for lo, hi in itertools.pairwise(bounds):
            if not ok[lo]:
                self.zi = None
                continue
            xs = x if hi - lo == ng else np.ascontiguousarray(x[:, lo:hi])
            seg = int(segid[0] if segs is None else segs[lo])
            if self.zi is None or seg != self.imu_seg:
                # restart after a gap: steady state at the first value, wait for settling
                self.zi = _state(self.lp, xs[:, 0])
                self.hp_zi = None
                self.tilt_zi = None
                self.hist_y = np.empty((NCH, 0))
                self.hist_p = np.empty((0, 3))
                self.hist_g = np.empty(0)
                self.since = 0
                self.imu_seg = seg
            _filter(self.lp, xs, self.zi)
            yy = np.concatenate((self.hist_y, xs), axis=1)
            pp = np.concatenate((self.hist_p, p[lo:hi]))
            gg = np.concatenate((self.hist_g, g[lo:hi]))
            if yy.shape[1] >= 3:
                self._emit(yy, pp, gg)
            self.hist_y, self.hist_p, self.hist_g = yy[:, -2:], pp[-2:], gg[-2:]

    def _emit(self, yy: Array, pp: Array, gg: Array) -> None:
        """Output rows from the filtered channels ``yy`` (18, L), L ≥ 3 (with the last two
        of the previous call in front), their robot positions ``pp`` and times ``gg``."""
        m = yy.shape[1] - 2
        # second difference at k is centred at k−1: align everything to k−1. Only of the
        # channels that use it (u, c, p); each as (y[k+1] − 2 y[k] + y[k−1]) / dt²
        d2 = np.multiply(2.0, yy[3:, 1:-1])
        np.subtract(yy[3:, 2:], d2, out=d2)
        np.add(d2, yy[3:, :-2], out=d2)
        np.divide(d2, self.dt * self.dt, out=d2)
        # a (IMU side), b (robot side), then the bias channels (sensor axes in I) and the
        # lever channels (their second derivative), as rows
        ab = np.empty((24, m))
        np.add(yy[0:3, 1:-1], d2[0:3], out=ab[0:3])
        ab[3:6] = d2[12:15]
        ab[6:15] = yy[6:15, 1:-1]
        ab[15:24] = d2[3:12]
        if self.tilt is not None:
            # the 6D filter levels itself on the slow part of a rotated bias: only
            # the faster part reaches the acceleration (VQF's tauAcc)
            if self.tilt_zi is None:
                self.tilt_zi = _state(self.tilt, ab[6:15, 0])
            _filter(self.tilt, ab[6:15], self.tilt_zi)
        if self.hp is not None:
            if self.hp_zi is None:
                self.hp_zi = _state(self.hp, np.zeros(24))
            _filter(self.hp, ab, self.hp_zi)
        # valid once settled: since > settle, since counting 1, 2, … from the restart
        k = min(max(self.settle - self.since, 0), m)
        valid = np.ones(m, dtype=bool)
        valid[:k] = False
        self.t = np.concatenate((self.t, gg[1:-1]))
        self.a = np.concatenate((self.a, ab[0:3].T))
        self.b = np.concatenate((self.b, ab[3:6].T))
        self.pos = np.concatenate((self.pos, pp[1:-1]))
        self.valid = np.concatenate((self.valid, valid))
        self.seg = np.concatenate((self.seg, np.full(m, self.imu_seg)))
        self.cl = np.concatenate((self.cl, ab[6:24].T))
        self.since += m

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
