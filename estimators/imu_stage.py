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
from estimators import rows
from estimators.buffers import RowBuffer
from estimators.filters import LowPass
from estimators.jit import aot
from estimators.output import Quality
from estimators.params import PipelineParams

Array: TypeAlias = NDArray[np.float64]
Idx: TypeAlias = NDArray[Any]  # integer and boolean arrays
EX = np.array([1.0, 0.0, 0.0])
NAN4 = (math.nan,) * 4

_FEW_SAMPLES = 8  # up to this many samples per piece, per-sample work in Python floats
_MIRROR = _FEW_SAMPLES  # a larger piece leaves this many of its newest samples in the mirror


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


class ImuStage:
    """6D orientation and elbow-acceleration terms at the IMU rate (frame I).

    Two stores of the same samples: the numpy buffer for the vectorised consumers (grid,
    batch rows), filled from the pending pieces only when one of them asks (a live message
    then costs no buffer copy), and a mirror of the newest samples in Python floats for
    single rows (:meth:`at`), which index it without any numpy call."""

    # buffer columns: t, segment id, q_IA (4), the gyro in frame A and its backward
    # difference (3 + 3: predict q_IA past the newest sample), the 6D filter's sensor
    # orientation q_IS (4), specific force in the sensor frame (3), paper method's eq. 1–2
    # acceleration (3). SEG to DW, together, are what a row looks up (:meth:`_list_rows`).
    T = 0
    SEG = 1
    Q = 2  # 4
    W = 6  # 3
    DW = 9  # 3
    QS = 12  # 4
    ACC = 16  # 3
    V = 19  # 3
    WIDTH = 22

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
        # last (t, ω_A) of this segment (a tuple of floats: the cyclic collector stops
        # tracking it, also where _p_prev holds it)
        self.w_prev: tuple[float, tuple[float, ...]] | None = None
        self.buf = RowBuffer(self.WIDTH)
        self.tl: list[float] = []  # every sample's time, buffered or pending (bisect)
        # pieces not yet in buf, one list per column group (per-piece tuples would stay
        # tracked by the cyclic collector: they hold arrays)
        self._p_q: list[Array] = []  # q_IA
        self._p_qs: list[Array] = []  # q_IS
        self._p_acc: list[Array] = []
        self._p_v: list[Array | None] = []
        self._p_w: list[Array] = []  # ω_A
        self._p_seg: list[float] = []
        self._p_len: list[int] = []
        # (pending row, t, ω_A) where dω's previous sample is not the row before: the first
        # pending piece and every segment start
        self._p_prev: list[tuple[int, float, tuple[float, ...]]] = []
        # the newest samples in floats: q_IA (4 per sample), ω_A (3), segment id; dω_A is
        # worked out when a prediction asks for it (_dw), from these and the (t, ω_A,
        # segment) of the sample before the first (None: there is none)
        self._mq: list[float] = []
        self._mw: list[float] = []
        self._mseg: list[float] = []
        self._mprev: tuple[float, tuple[float, ...], float] | None = None
        self._rows_list: list[list[float]] | None = None  # the buffer as floats, when asked

    @property
    def t(self) -> Array:
        self._flush()
        return self.buf.col(self.T)

    @property
    def segid(self) -> Array:
        self._flush()
        return self.buf.col(self.SEG)

    def _reset(self) -> None:
        assert self.ts is not None
        self.vqf = VQF(self.ts, tauAcc=self.p.vqf_tau_acc_s)
        self.gyro_zi = None
        self.gyro_prev = None
        self.w_prev = None

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
        seg = float(self.seg)
        # angular acceleration: backward difference, 0 at a segment's first sample
        fresh = self.w_prev is None
        if self.w_prev is None:
            t0, w0 = tl[0] - 1.0, tuple(w_a[0].tolist())
        else:
            t0, w0 = self.w_prev
        if fresh or not self._p_len:
            self._p_prev.append((len(self.tl) - len(self.buf), t0, w0))
        self._p_q.append(q_ia)
        if not self.identity_mount:  # else q_IS is q_IA (_flush copies that column group)
            self._p_qs.append(q_is)
        self._p_acc.append(acc)
        self._p_v.append(v)
        self._p_w.append(w_a)
        self._p_seg.append(seg)
        self._p_len.append(n)
        if n <= _FEW_SAMPLES:  # a message's few: Python floats beat numpy's per-call cost
            wl = w_a.ravel().tolist()
            self.w_prev = (tl[-1], (wl[-3], wl[-2], wl[-1]))
            self._mq += q_ia.ravel().tolist()
            self._mw += wl
            self._mseg += [seg] * n
        else:  # the mirror keeps the newest _MIRROR (< n) samples
            k = _MIRROR
            wl = w_a[-k - 1 :].ravel().tolist()
            self.w_prev = (tl[-1], (wl[-3], wl[-2], wl[-1]))
            self._mq = q_ia[-k:].ravel().tolist()
            self._mw = wl[3:]
            self._mseg = [seg] * k
            self._mprev = (tl[-k - 1], (wl[0], wl[1], wl[2]), seg)
        self.tl += tl

    def _flush(self) -> None:
        """Move the pending pieces into the buffer: one copy per column group for all."""
        if not self._p_len:
            return
        n = len(self.tl) - len(self.buf)
        rows = self.buf.grow(n)
        self._rows_list = None
        rows[:, self.T] = self.tl[len(self.tl) - n :]
        seg = self._p_seg
        if seg.count(seg[0]) == len(seg):  # one segment: no per-piece repeat
            rows[:, self.SEG] = seg[0]
        else:
            rows[:, self.SEG] = np.repeat(seg, self._p_len)
        np.concatenate(self._p_q, out=rows[:, self.Q : self.Q + 4])
        if self.identity_mount:
            rows[:, self.QS : self.QS + 4] = rows[:, self.Q : self.Q + 4]
        else:
            np.concatenate(self._p_qs, out=rows[:, self.QS : self.QS + 4])
        np.concatenate(self._p_acc, out=rows[:, self.ACC : self.ACC + 3])
        if self.p.method == "paper":
            np.concatenate(self._p_v, out=rows[:, self.V : self.V + 3])  # type: ignore[arg-type]
        else:
            rows[:, self.V : self.V + 3] = 0.0
        w = rows[:, self.W : self.W + 3]
        np.concatenate(self._p_w, out=w)
        # dω: the same backward difference as _run's (bit-identical), over all pieces at
        # once: the row before, or where that is not the previous sample the (t, ω) _run took.
        # The three axes as rows: one loop over the samples each (numpy loops over the
        # buffer's (n, 3) column groups 3 elements at a time)
        t = rows[:, self.T]
        dt = np.empty(n)
        dt[1:] = t[:-1]
        dw = np.empty((3, n))
        dw[:, 1:] = w[:-1].T
        for j, t0, w0 in self._p_prev:
            dt[j] = t0
            dw[:, j] = w0
        del self._p_q[:], self._p_qs[:], self._p_acc[:], self._p_v[:], self._p_w[:]
        del self._p_seg[:], self._p_len[:], self._p_prev[:]
        np.subtract(t, dt, out=dt)
        np.subtract(w.T, dw, out=dw)
        np.divide(dw, dt, out=rows[:, self.DW : self.DW + 3].T)

    def trim(self, t_keep: float) -> None:
        i = max(0, bisect.bisect_left(self.tl, t_keep) - 2)
        if i > 0:
            if i > len(self.buf):
                self._flush()
            self.buf.drop(i)
            self._rows_list = None
            extra = len(self._mseg) - (len(self.tl) - i)
            if extra > 0:  # the mirror loses its oldest: the last of them is _mprev now
                j = extra - 1
                self._mprev = (
                    self.tl[len(self.tl) - len(self._mseg) + j],
                    tuple(self._mw[3 * j : 3 * j + 3]),
                    self._mseg[j],
                )
                del self._mq[: 4 * extra], self._mw[: 3 * extra], self._mseg[:extra]
            del self.tl[:i]

    def _sample(self, i: int) -> tuple[list[float], list[float], list[float], float]:
        """Sample ``i``'s q_IA, ω_A, dω_A and segment id as floats: from the mirror, or
        the buffer for an older one."""
        k = i - (len(self.tl) - len(self._mseg))
        if k >= 0:
            return (
                self._mq[4 * k : 4 * k + 4],
                self._mw[3 * k : 3 * k + 3],
                self._dw(k),
                self._mseg[k],
            )
        rows = self._rows_list
        if rows is None or i >= len(rows):
            rows = self._list_rows()
        r = rows[i]
        return r[1:5], r[5:8], r[8:11], r[0]

    def _list_rows(self) -> list[list[float]]:
        """The buffer's segment id, q_IA, ω_A and dω_A as floats, made once for many
        look-ups behind the mirror (an analysis's rows)."""
        self._flush()
        rows: list[list[float]] = self.buf.view()[:, self.SEG : self.DW + 3].tolist()
        self._rows_list = rows
        return rows

    def _dw(self, k: int) -> list[float]:
        """dω_A of mirror sample ``k``: the backward difference ``_flush`` takes (the same
        arithmetic), 0 at a segment's first sample (ω_A against itself, 1 s earlier)."""
        tl, mw, mseg = self.tl, self._mw, self._mseg
        j = len(tl) - len(mseg) + k
        tj, seg = tl[j], mseg[k]
        x, y, z = mw[3 * k : 3 * k + 3]
        if k > 0 and mseg[k - 1] == seg:
            t0 = tl[j - 1]
            p0, p1, p2 = mw[3 * k - 3 : 3 * k]
        elif k == 0 and self._mprev is not None and self._mprev[2] == seg:
            t0, (p0, p1, p2), _ = self._mprev
        else:
            t0, p0, p1, p2 = tj - 1.0, x, y, z
        h = tj - t0
        return [(x - p0) / h, (y - p1) / h, (z - p2) / h]

    def smooth(self, g: Array, half: float) -> tuple[Idx, Array]:
        """Acceleration terms (v, u) at grid times ``g``, anti-aliased by a centred Hann
        kernel of half-width ``half`` (s). Centred, so it shifts nothing in time: a lag
        between the two sides would turn into a heading bias on circular paths.
        Returns ``(ok, x)`` with x (n, 6); ok where the whole kernel lies in one segment."""
        self._flush()
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
        self._flush()
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

    def at(self, s: float, asof: float) -> tuple[bool, tuple[float, ...], float]:
        """Orientation q_IA (w, x, y, z) at time ``s`` (nlerp, :func:`rows.nlerp`), whether
        both neighbours exist in one segment, and the segment id. Where ``s > asof`` (the IMU
        had only reached ``asof`` when the row was decided), predicted from the newest sample
        at or before ``asof`` (:func:`rows.predict`)."""
        tl = self.tl
        n = len(tl)
        if n < 2:
            return False, NAN4, 0.0
        if s > asof:
            # the newest sample at or before asof (usually the newest of all)
            j = n - 1 if asof >= tl[-1] else bisect.bisect_right(tl, asof) - 1
            jc = j if j > 0 else 0
            q, w, dw, seg = self._sample(jc)
            return j >= 0, rows.predict(q, w, dw, s - tl[jc]), seg
        i1 = bisect.bisect_left(tl, s)
        i1c = min(max(i1, 1), n - 1)
        i0 = i1c - 1
        k = i0 - (n - len(self._mseg))
        if k >= 0:  # both in the mirror (the live case): one slice
            q01, (seg0, seg1) = self._mq[4 * k : 4 * k + 8], self._mseg[k : k + 2]
            q0, q1 = q01[:4], q01[4:]
        else:  # older samples (an analysis's rows): their segment and q_IA from the buffer
            buf = self._rows_list
            if buf is None or i1c >= len(buf):
                buf = self._list_rows()
            r0, r1 = buf[i0], buf[i1c]
            seg0, q0, seg1, q1 = r0[0], r0[1:5], r1[0], r1[1:5]
        t0 = tl[i0]
        a = (s - t0) / (tl[i1c] - t0)
        a = 0.0 if a < 0.0 else 1.0 if a > 1.0 else a  # as np.clip (NaN passes)
        return 0 < i1 < n and seg0 == seg1, rows.nlerp(q0, q1, a), seg1

    def interp_channels(self, s: Array) -> tuple[Idx, Array]:
        """Fusion channels linearly interpolated at ``s`` (no anti-alias: the paper's way)."""
        if len(self.tl) < 2:
            return np.zeros(len(s), bool), np.full((len(s), 15), np.nan)
        ok, i0, i1, w = self._bracket(s)
        base = int(i0.min()) if len(i0) else 0
        x = self.channels(base, int(i1.max()) + 1 if len(i1) else 0)
        x0, x1 = x[i0 - base], x[i1 - base]
        return ok, x0 + w[:, None] * (x1 - x0)
