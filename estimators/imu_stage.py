"""Stage 1 of the pipeline: the IMU stream's 6D orientation and elbow-acceleration terms."""

from __future__ import annotations

import bisect
import math
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray
from vqf import VQF

from estimators import kinematics as kin
from estimators import quaternion as quat
from estimators.buffers import RowBuffer
from estimators.filters import LowPass
from estimators.jit import aot
from estimators.output import Quality
from estimators.params import PipelineParams

Array: TypeAlias = NDArray[np.float64]
Idx: TypeAlias = NDArray[Any]  # integer and boolean arrays
EX = np.array([1.0, 0.0, 0.0])
_NO_V = np.zeros((0, 3))  # the improved method has no eq. 1–2 acceleration


@aot("f8[:, ::1](f8[:, :], i8[:], f8[:, :])")
def _weighted_sums(w: Any, start: Any, x: Any) -> Any:  # pragma: no cover - compiled
    """``out[i] = Σ_j w[i, j] · x[start[i] + j]`` for w (n, m), x (N, C), summed in order of
    j (the sums of a CSR sparse product; no (n, m, C) array of windows: 26 MB for 8 min)."""
    out = np.zeros((w.shape[0], x.shape[1]))
    for i in range(w.shape[0]):
        for j in range(w.shape[1]):
            a = w[i, j]
            r = start[i] + j
            for c in range(x.shape[1]):
                out[i, c] += a * x[r, c]
    return out


@aot(
    "void(f8[:, :], f8[:], f8, f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[::1], i8[::1])"
)
def _store(  # pragma: no cover - compiled
    rows: Any,
    t: Any,
    seg: float,
    q_ia: Any,
    q_is: Any,
    acc: Any,
    v: Any,
    w: Any,
    prev: Any,
    col: Any,
) -> None:
    """Write a piece of n samples into the buffer's new ``rows`` (n, ·) at the columns
    ``col`` (:data:`ImuStage.COLUMNS`): time ``t`` (s), segment id, ``q_IA``, ``q_IS`` (n, 4),
    specific force (n, 3), the paper method's acceleration ``v`` (n, 3; (0, 3): zero), ``ω_A``
    (n, 3) and its backward difference ``dω_A = (ω_j − ω_{j−1}) / (t_j − t_{j−1})``, the
    sample before the first being ``prev`` (t, ω_A), which becomes the piece's last. t NaN:
    the segment's first sample (dω_A 0, from ω_A against itself 1 s earlier)."""
    ct, cseg, cq, cqs, cacc, cv, cw, cdw = (
        col[0],
        col[1],
        col[2],
        col[3],
        col[4],
        col[5],
        col[6],
        col[7],
    )
    has_v = v.shape[0] > 0
    tp, p0, p1, p2 = prev[0], prev[1], prev[2], prev[3]
    if tp != tp:
        tp, p0, p1, p2 = t[0] - 1.0, w[0, 0], w[0, 1], w[0, 2]
    for i in range(t.shape[0]):
        ti = t[i]
        rows[i, ct] = ti
        rows[i, cseg] = seg
        for c in range(4):
            rows[i, cq + c] = q_ia[i, c]
            rows[i, cqs + c] = q_is[i, c]
        w0, w1, w2 = w[i, 0], w[i, 1], w[i, 2]
        for c in range(3):
            rows[i, cacc + c] = acc[i, c]
            rows[i, cv + c] = v[i, c] if has_v else 0.0
        rows[i, cw], rows[i, cw + 1], rows[i, cw + 2] = w0, w1, w2
        dt = ti - tp
        rows[i, cdw], rows[i, cdw + 1], rows[i, cdw + 2] = (
            (w0 - p0) / dt,
            (w1 - p1) / dt,
            (w2 - p2) / dt,
        )
        tp, p0, p1, p2 = ti, w0, w1, w2
    prev[0], prev[1], prev[2], prev[3] = tp, p0, p1, p2


class ImuStage:
    """6D orientation and elbow-acceleration terms at the IMU rate (frame I).

    The samples are kept in a numpy buffer, filled from the pending pieces when a consumer
    (the grid, the rows) asks: each piece is copied once, whatever the polls."""

    # buffer columns: t, segment id, q_IA (4), the gyro in frame A and its backward
    # difference (3 + 3: predict q_IA past the newest sample), the 6D filter's sensor
    # orientation q_IS (4), specific force in the sensor frame (3), paper method's eq. 1–2
    # acceleration (3). T to DW are what a row looks up (:meth:`lookup`).
    T = 0
    SEG = 1
    Q = 2  # 4
    W = 6  # 3
    DW = 9  # 3
    QS = 12  # 4
    ACC = 16  # 3
    V = 19  # 3
    WIDTH = 22
    LOOKUP = np.array([T, SEG, Q, W, DW], dtype=np.int64)  # :func:`estimators.rows.compute`
    COLUMNS = np.array([T, SEG, Q, QS, ACC, V, W, DW], dtype=np.int64)  # :func:`_store`

    def __init__(self, p: PipelineParams) -> None:
        self.p = p
        self.mount = np.array(p.mounting_quat, dtype=np.float64)
        self.mount /= np.linalg.norm(self.mount)
        self.identity_mount = bool(np.array_equal(self.mount, [1.0, 0.0, 0.0, 0.0]))
        # lever arm IMU → elbow in the sensor frame (eq. 1's r = [d, 0, 0] in A)
        self.r = quat.rotate(self.mount, EX * p.imu_to_elbow_m)
        self.unmount = quat.conj(self.mount)  # sensor frame → A, for the gyro
        self.ts: float | None = None
        self.probe: list[tuple[Array, Array, Array]] = []
        self.vqf: VQF | None = None
        # the last sample's time, and gyro and accelerometer arrays whose last row it is
        self.last: tuple[float, Array, Array] | None = None
        self.seg = 0
        self.gyro_lp: LowPass | None = None
        self.gyro_zi: Array | None = None
        self.gyro_prev: Array | None = None
        # the last sample's (t, ω_A) in this segment, for dω_A (t NaN: none yet)
        self.w_prev = np.full(4, math.nan)
        self.buf = RowBuffer(self.WIDTH)
        self.tl: list[float] = []  # every sample's time (bisect)

    @property
    def t(self) -> Array:
        return self.buf.col(self.T)

    @property
    def segid(self) -> Array:
        return self.buf.col(self.SEG)

    def _reset(self) -> None:
        assert self.ts is not None
        self.vqf = VQF(self.ts, tauAcc=self.p.vqf_tau_acc_s)
        self.gyro_zi = None
        self.gyro_prev = None
        self.w_prev = np.full(4, math.nan)

    def process(
        self, t: Array, gyr: Array, acc: Array, q: Quality, tl: list[float] | None = None
    ) -> None:
        """Samples ``t`` (n,) s (``tl``: as floats, if at hand), ``gyr`` (n, 3) rad/s,
        ``acc`` (n, 3) m/s²."""
        if self.ts is None:
            self.probe.append((t, gyr, acc))
            if sum(len(c[0]) for c in self.probe) < self.p.rate_probe_samples:
                return
            t = np.concatenate([c[0] for c in self.probe])
            gyr = np.concatenate([c[1] for c in self.probe])
            acc = np.concatenate([c[2] for c in self.probe])
            self.probe, tl = [], None
            dt = float(np.median(np.diff(t[: self.p.rate_probe_samples])))
            self.ts = min(max(dt, 1e-3), 0.1)  # contract: 10..1000 Hz
            if self.p.method == "paper":
                self.gyro_lp = LowPass(self.p.lowpass_order, self.p.gyro_lowpass_hz, 1.0 / self.ts)
            self._reset()
        assert self.ts is not None
        ts = self.ts
        if tl is None:
            tl = t.tolist()
        if self.last is not None:
            # the usual message: no gap (a plain loop, cheaper than numpy for a few samples)
            prev, limit = self.last[0], 2.5 * ts
            for x in tl:
                if x - prev > limit:
                    break
                prev = x
            else:
                # the message's arrays (never written), indexed only at the next gap
                self.last = (tl[-1], gyr, acc)
                self._run(t, gyr, acc, tl)
                return
        # gaps: bridge short ones by interpolation, reset on long ones
        if self.last is not None:
            t = np.concatenate(([self.last[0]], t))
            gyr = np.concatenate((self.last[1][-1:], gyr))
            acc = np.concatenate((self.last[2][-1:], acc))
            start = 1
        else:
            start = 0
        self.last = (float(t[-1]), gyr[-1:].copy(), acc[-1:].copy())
        dts = np.diff(t)
        for gi in np.flatnonzero(dts > 2.5 * ts):
            gap = float(dts[gi])
            q.gaps.append({"stream": "imu", "t": float(t[gi]), "duration_s": gap})
            self._run(t[start : gi + 1], gyr[start : gi + 1], acc[start : gi + 1])
            if gap <= self.p.imu_max_bridge_s:
                n_missing = int(round(gap / ts)) - 1
                s = np.arange(1, n_missing + 1) / (n_missing + 1)
                self._run(
                    t[gi] + s * gap,
                    gyr[gi] + s[:, None] * (gyr[gi + 1] - gyr[gi]),
                    acc[gi] + s[:, None] * (acc[gi + 1] - acc[gi]),
                )
                q.imu_bridged_gaps += 1
                q.imu_bridged_samples += n_missing
            else:
                q.imu_resets += 1
                self.seg += 1
                self._reset()
            start = int(gi) + 1
        self._run(t[start:], gyr[start:], acc[start:])

    def _run(self, t: Array, gyr: Array, acc: Array, tl: list[float] | None = None) -> None:
        """Orientation and acceleration terms of one contiguous piece of samples."""
        n = len(t)
        if n == 0:
            return
        assert self.vqf is not None
        try:  # decoded messages are C-contiguous float64 already: no conversion calls
            out = self.vqf.updateBatch(gyr, acc)
        except ValueError:  # VQF takes only those
            out = self.vqf.updateBatch(np.ascontiguousarray(gyr), np.ascontiguousarray(acc))
        q_is = out["quat6D"]
        tl = t.tolist() if tl is None else tl
        q_ia = q_is if self.identity_mount else quat.mul(q_is, self.mount)
        v: Array | None = None
        if self.p.method == "paper":
            assert self.gyro_lp is not None and self.ts is not None
            if self.gyro_zi is None or self.gyro_prev is None:
                self.gyro_zi = self.gyro_lp.initial_state(gyr[0])
                self.gyro_prev = gyr[0].copy()
            gf, self.gyro_zi = self.gyro_lp(gyr, self.gyro_zi)
            prev = np.concatenate((self.gyro_prev[None], gf[:-1]))
            gdot = (gf - prev) / self.ts  # backward difference of the low-passed gyro (eq. 1)
            self.gyro_prev = gf[-1].copy()
            v = kin.inertial_acceleration(q_is, kin.joint_specific_force(acc, gyr, gdot, self.r))
        w_a = gyr if self.identity_mount else quat.rotate(self.unmount, gyr)
        _store(
            self.buf.grow(n),
            t,
            float(self.seg),
            q_ia,
            q_is,
            acc,
            _NO_V if v is None else v,
            w_a,
            self.w_prev,
            self.COLUMNS,
        )
        self.tl += tl

    def lookup(self) -> Array:
        """Every sample held (N, ``WIDTH``), for the rows' look-ups: the columns
        :data:`LOOKUP` are time, segment id, q_IA, ω_A and dω_A."""
        return self.buf.view()

    def trim(self, t_keep: float) -> None:
        i = max(0, bisect.bisect_left(self.tl, t_keep) - 2)
        if i > 0:
            self.buf.drop(i)
            del self.tl[:i]

    def smooth(self, g: Array, half: float) -> tuple[Idx, Array]:
        """Acceleration terms (v, u) at grid times ``g``, anti-aliased by a centred Hann
        kernel of half-width ``half`` (s). Centred, so it shifts nothing in time: a lag
        between the two sides would turn into a heading bias on circular paths.
        Returns ``(ok, x)`` with x (n, 6); ok where the whole kernel lies in one segment."""
        tl = self.tl
        n, ng = len(tl), len(g)
        ts = self.ts or 0.01
        m = int(math.ceil(2.0 * half / ts)) + 2
        if n < m:
            return np.zeros(ng, bool), np.full((ng, 15), np.nan)
        # Only the samples from the first kernel's on (the grid times ascend): searched
        # there, with the clip's bound kept inside, they give the indices all samples give.
        # (The buffer's times are tl's floats, and g[0] - half is gh[0].)
        s0 = min(bisect.bisect_left(tl, float(g[0]) - half), n - m)
        t = np.ascontiguousarray(self.buf.col(self.T)[s0:])
        nt = n - s0
        gh = g - half
        lo = t.searchsorted(gh, side="left")
        np.minimum(lo, nt - m, out=lo)  # np.clip(…, 0, nt − m): a searchsorted index is ≥ 0
        idx = lo[:, None] + np.arange(m)
        tt = t.take(idx)
        np.subtract(tt, g[:, None], out=tt)
        c = np.multiply(np.pi, tt)
        np.divide(c, half, out=c)
        np.cos(c, out=c)
        np.multiply(0.5, c, out=c)
        np.add(0.5, c, out=c)
        w = np.where(np.abs(tt) < half, c, 0.0)
        wsum = np.add.reduce(w, axis=1)  # = w.sum(axis=1)
        last = lo + (m - 1)
        ok = np.less_equal(t.take(lo), gh + ts)
        ok &= t.take(last) >= g + half - ts
        segid = self.buf.col(self.SEG)
        if segid[s0] != segid[n - 1]:  # one segment: all equal
            ok &= segid[s0:].take(lo) == segid[s0:].take(last)
        ok &= wsum > 0
        base = int(lo.min())
        x = self.channels(s0 + base, s0 + int(lo.max()) + m)
        acc = _weighted_sums(w, lo - base, x)
        with np.errstate(invalid="ignore", divide="ignore"):
            np.divide(acc, wsum[:, None], out=acc)
        return ok, acc

    def channels(self, lo: int, hi: int) -> Array:
        """Fusion channels of samples ``lo:hi`` (n, 15): the acceleration term v (used as
        is), the lever term u = q r q* (differentiated after the low-pass), and the sensor
        axes in I (for the bias and lever fits). Computed only when the grid needs them."""
        rows = self.buf.view()[lo:hi]
        n = len(rows)
        if self.p.method == "paper":
            x = np.zeros((n, 15))
            x[:, 0:3] = rows[:, self.V : self.V + 3]
            return x
        # Channel-major (15, n), transposed once at the end: each operation then runs over
        # contiguous samples (over the buffer's (n, 3) column groups numpy loops 3 at a
        # time). The operations are quat.matrix_columns's, then v's and u's, in their order.
        w, x, y, z = rows[:, self.QS : self.QS + 4].T.copy()
        out = np.empty((15, n))
        c = out[6:15]  # the images of the sensor's x, y and z axes
        np.subtract(1.0, 2.0 * (y * y + z * z), out=c[0])
        np.multiply(2.0, x * y + w * z, out=c[1])
        np.multiply(2.0, x * z - w * y, out=c[2])
        np.multiply(2.0, x * y - w * z, out=c[3])
        np.subtract(1.0, 2.0 * (x * x + z * z), out=c[4])
        np.multiply(2.0, y * z + w * x, out=c[5])
        np.multiply(2.0, x * z + w * y, out=c[6])
        np.multiply(2.0, y * z - w * x, out=c[7])
        np.subtract(1.0, 2.0 * (x * x + y * y), out=c[8])
        a0, a1, a2 = rows[:, self.ACC : self.ACC + 3].T.copy()
        cx, cy, cz, r = c[0:3], c[3:6], c[6:9], self.r
        np.subtract(cx * a0 + cy * a1 + cz * a2, kin.GRAVITY[:, None], out=out[0:3])  # v
        np.add(cx * r[0] + cy * r[1], cz * r[2], out=out[3:6])  # u
        return out.T.copy()

    def _bracket(self, s: Array) -> tuple[Idx, Idx, Idx, Array]:
        t, segid = np.ascontiguousarray(self.t), self.segid
        n = len(t)
        i1 = np.searchsorted(t, s, side="left")
        i1c = np.clip(i1, 1, max(n - 1, 1))
        i0 = i1c - 1
        ok = (i1 > 0) & (i1 < n) & (segid[i0] == segid[i1c])
        w = np.clip((s - t[i0]) / (t[i1c] - t[i0]), 0.0, 1.0)
        return ok, i0, i1c, w

    def interp_channels(self, s: Array) -> tuple[Idx, Array]:
        """Fusion channels linearly interpolated at ``s`` (no anti-alias: the paper's way)."""
        if len(self.tl) < 2:
            return np.zeros(len(s), bool), np.full((len(s), 15), np.nan)
        ok, i0, i1, w = self._bracket(s)
        base = int(i0.min()) if len(i0) else 0
        x = self.channels(base, int(i1.max()) + 1 if len(i1) else 0)
        x0, x1 = x[i0 - base], x[i1 - base]
        return ok, x0 + w[:, None] * (x1 - x0)
