"""The streaming inertial-robotic pipeline (Passon et al. 2020, §3), message by message.

``feed()`` takes decoded contract messages in arrival order and only does cheap
book-keeping; ``poll()`` runs the numerical work on everything that has become ready and
returns the new estimate rows (one per robot sample) and feedback. Results depend only on
the messages and their order, never on how they are batched or when ``poll()`` is called,
and never on the wall clock: the live service and ``rehab analyze`` give identical numbers.

Stages (each keeps its own state, like ``scipy.signal``'s ``zi``):

1. IMU: sample-rate probe, gap bridging or reset, 6D orientation ``q_IA`` (VQF), and the
   elbow's acceleration terms in frame I (eqs. 1–2).
2. Robot: elbow and forearm axis from the cuffs (eq. 13).
3. Fusion grid: both accelerations on a common uniform time base, low-passed (§3.2.1).
4. Heading: scheduled updates of δ (§3.2.2, eqs. 5–8, or the improved method).
5. Rows: ``q_RA = Rz(δ) q_IA`` (eqs. 9–10), elbow angle (eq. 11), shoulder (eq. 12), the
   conventional baseline, nominal shoulder, indicator state and cycle verdicts (§3.4).

Improved IMU-side acceleration: instead of eq. 1's ``ω̇ × r`` with ω̇ from a causally
low-passed gyro (delayed ~0.2 s against the raw ω in the centripetal term, which breaks
fast motions), the elbow acceleration is written exactly as
``a_E = (q f q* − g) + d²/dt² (q r q*)``; low-pass and differentiation commute, so the
second term is differentiated after the same 0.5 Hz low-pass as the robot's position.
Both sides then see the same filter, the same delay and no gyro derivative at all.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from vqf import VQF

from estimators import heading as hd
from estimators import kinematics as kin
from estimators import quaternion as quat
from estimators import rows
from estimators.buffers import RowBuffer, RowQueue
from estimators.compensation import CompensationParams, Episode, EpisodeTracker, Indicator
from estimators.cycles import CycleParams, CycleSegmenter
from estimators.filters import LowPass, dc_group_delay_s
from estimators.params import PipelineParams
from estimators.verdicts import CycleJudge, CycleVerdict

Array: TypeAlias = NDArray[np.float64]
Idx: TypeAlias = NDArray[Any]  # integer and boolean arrays
EX = np.array([1.0, 0.0, 0.0])
NCH = 18  # grid channels: v (3), u (3), sensor axes in I (9), robot elbow (3)
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


# ------------------------------------------------------------------------------ inputs
# The pipeline accepts any objects with these attributes (backend.wire's messages do).


@dataclass(frozen=True, slots=True)
class ImuSamples:
    t: Array
    gyr: Array
    acc: Array
    seq: int | None = None
    segment: str = "upperarm"


@dataclass(frozen=True, slots=True)
class RobotSamples:
    t: Array
    wrist: Array
    proximal: Array
    elbow: Array | None = None
    seq: int | None = None


@dataclass(frozen=True, slots=True)
class Event:
    t: float
    type: str
    point: Array | None = None


# ------------------------------------------------------------------------------ outputs


class RowTable(Mapping[str, Any]):
    """The rows of one poll as a read-only mapping ``ROW_COLUMNS`` → arrays, backed by one
    (n, ``_NCOL``) matrix: a column is sliced when asked for, so a consumer pays only for
    the columns it reads."""

    __slots__ = ("_cols", "m")

    def __init__(self, m: Array, state: Idx) -> None:
        self.m = m
        self._cols: dict[str, Any] = {"state": state}  # made once (several consumers read)

    def __getitem__(self, name: str) -> Any:
        col = self._cols.get(name)
        if col is None:
            if name == "heading_converged":
                col = self.m[:, _COL[name]] > 0.5
            else:
                a, w = _SPAN[name]
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
        a, w = _SPAN[name]
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


class _Stream:
    """Per-stream ordering and sequence book-keeping."""

    __slots__ = ("last_seq", "last_t", "name")

    def __init__(self, name: str) -> None:
        self.name = name
        self.last_t = -math.inf
        self.last_seq: int | None = None

    def admit(self, t0: float, seq: int | None, q: Quality) -> bool:
        if t0 <= self.last_t:
            q.reject("duplicate_t" if t0 == self.last_t else "time_backwards")
            return False
        if seq is not None:
            if self.last_seq is not None and seq != self.last_seq + 1:
                lost = seq - self.last_seq - 1
                if lost > 0:
                    q.seq_lost[self.name] = q.seq_lost.get(self.name, 0) + lost
                else:
                    q.reject("seq_restart")  # counted, data still accepted (device restart)
            self.last_seq = seq
        return True


def _run_end(values: Sequence[int], i: int) -> int:
    """End of the run of equal values starting at ``i``."""
    v, j, n = values[i], i + 1, len(values)
    while j < n and values[j] == v:
        j += 1
    return j


# ------------------------------------------------------------------------------ stage 1: IMU

_FEW_SAMPLES = 8  # up to this many samples per piece, per-sample work in Python floats
_MIRROR = _FEW_SAMPLES  # a larger piece leaves this many of its newest samples in the mirror


class _ImuStage:
    """6D orientation and elbow-acceleration terms at the IMU rate (frame I).

    Two stores of the same samples: the numpy buffer for the vectorised consumers (grid,
    batch rows), filled from the pending pieces only when one of them asks (a live message
    then costs no buffer copy), and a mirror of the newest samples in Python floats for
    single rows (:meth:`at`), which index it without any numpy call."""

    # buffer columns: t, segment id, q_IA (4), the 6D filter's sensor orientation q_IS (4),
    # specific force in the sensor frame (3), paper method's eq. 1–2 acceleration (3), the
    # gyro in frame A and its backward difference (3 + 3: predict q_IA past the newest sample)
    T, SEG, Q, QS, ACC, V, W, DW, WIDTH = 0, 1, 2, 6, 10, 13, 16, 19, 22

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
        # the newest samples in floats: q_IA (4 per sample), ω_A (3), dω_A (3), segment id
        self._mq: list[float] = []
        self._mw: list[float] = []
        self._mdw: list[float] = []
        self._mseg: list[float] = []

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
                self.last = (tl[-1], gyr[-1], acc[-1])  # message arrays are never written
                self._run(t, gyr, acc, tl)
                return
        # gaps: bridge short ones by interpolation, reset on long ones
        if self.last is not None:
            t = np.concatenate(([self.last[0]], t))
            gyr = np.concatenate((self.last[1][None], gyr))
            acc = np.concatenate((self.last[2][None], acc))
            start = 1
        else:
            start = 0
        self.last = (float(t[-1]), gyr[-1].copy(), acc[-1].copy())
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
        self._p_qs.append(q_is)
        self._p_acc.append(acc)
        self._p_v.append(v)
        self._p_w.append(w_a)
        self._p_seg.append(seg)
        self._p_len.append(n)
        if n <= _FEW_SAMPLES:  # a message's few: Python floats beat numpy's per-call cost
            wl = w_a.ravel().tolist()
            dw: list[float] = []
            p0, p1, p2 = w0
            for j, tj in enumerate(tl):
                x, y, z = wl[3 * j : 3 * j + 3]
                h = tj - t0
                dw += ((x - p0) / h, (y - p1) / h, (z - p2) / h)
                t0, p0, p1, p2 = tj, x, y, z
            self.w_prev = (tl[-1], (wl[-3], wl[-2], wl[-1]))
            self._mq += q_ia.ravel().tolist()
            self._mw += wl
            self._mdw += dw
            self._mseg += [seg] * n
        else:  # the mirror keeps the newest _MIRROR (< n) samples; _flush does all of dω
            k = _MIRROR
            dwa = (w_a[-k:] - w_a[-k - 1 : -1]) / (t[-k:] - t[-k - 1 : -1])[:, None]
            self.w_prev = (tl[-1], tuple(w_a[-1].tolist()))
            self._mq = q_ia[-k:].ravel().tolist()
            self._mw = w_a[-k:].ravel().tolist()
            self._mdw = dwa.ravel().tolist()
            self._mseg = [seg] * k
        self.tl += tl

    def _flush(self) -> None:
        """Move the pending pieces into the buffer: one copy per column group for all."""
        if not self._p_len:
            return
        n = len(self.tl) - len(self.buf)
        rows = self.buf.grow(n)
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
        # once: the row before, or where that is not the previous sample the (t, ω) _run took
        prev_t = np.empty(n)
        prev_t[1:] = rows[:-1, self.T]
        prev_w = np.empty((n, 3))
        prev_w[1:] = w[:-1]
        for j, t0, w0 in self._p_prev:
            prev_t[j], prev_w[j] = t0, w0
        del self._p_q[:], self._p_qs[:], self._p_acc[:], self._p_v[:], self._p_w[:]
        del self._p_seg[:], self._p_len[:], self._p_prev[:]
        np.divide(
            w - prev_w, (rows[:, self.T] - prev_t)[:, None], out=rows[:, self.DW : self.DW + 3]
        )

    def trim(self, t_keep: float) -> None:
        i = max(0, bisect.bisect_left(self.tl, t_keep) - 2)
        if i > 0:
            if i > len(self.buf):
                self._flush()
            self.buf.drop(i)
            del self.tl[:i]
            extra = len(self._mseg) - len(self.tl)
            if extra > 0:
                del self._mq[: 4 * extra], self._mw[: 3 * extra], self._mdw[: 3 * extra]
                del self._mseg[:extra]

    def _sample(self, i: int) -> tuple[list[float], list[float], list[float], float]:
        """Sample ``i``'s q_IA, ω_A, dω_A and segment id as floats: from the mirror, or
        the buffer for an older one."""
        k = i - (len(self.tl) - len(self._mseg))
        if k >= 0:
            return (
                self._mq[4 * k : 4 * k + 4],
                self._mw[3 * k : 3 * k + 3],
                self._mdw[3 * k : 3 * k + 3],
                self._mseg[k],
            )
        self._flush()
        r: list[float] = self.buf.a[self.buf.lo + i].tolist()
        return r[2:6], r[16:19], r[19:22], r[1]

    def smooth(self, g: Array, half: float) -> tuple[Idx, Array]:
        """Acceleration terms (v, u) at grid times ``g``, anti-aliased by a centred Hann
        kernel of half-width ``half`` (s). Centred, so it shifts nothing in time: a lag
        between the two sides would turn into a heading bias on circular paths.
        Returns ``(ok, x)`` with x (n, 6); ok where the whole kernel lies in one segment."""
        t, segid = np.ascontiguousarray(self.t), self.segid
        n, ng = len(t), len(g)
        ts = self.ts or 0.01
        m = int(math.ceil(2.0 * half / ts)) + 2
        if n < m:
            return np.zeros(ng, bool), np.full((ng, 15), np.nan)
        lo = np.clip(np.searchsorted(t, g - half, side="left"), 0, n - m)
        idx = lo[:, None] + np.arange(m)[None, :]
        tt = t[idx] - g[:, None]
        w = np.where(np.abs(tt) < half, 0.5 + 0.5 * np.cos(np.pi * tt / half), 0.0)
        wsum = w.sum(axis=1)
        ok = (
            (t[lo] <= g - half + ts)
            & (t[lo + m - 1] >= g + half - ts)
            & (segid[lo] == segid[lo + m - 1])
            & (wsum > 0)
        )
        base = int(lo.min())
        x = self.channels(base, int(lo.max()) + m)
        # the weighted sums as a sparse product: the same sequential sums as gathering
        # (ng, m, 15) windows and reducing them, without that array (26 MB for 8 minutes)
        kernel = sparse.csr_matrix(
            (w.ravel(), (idx - base).ravel(), np.arange(0, ng * m + 1, m)), shape=(ng, len(x))
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.asarray(kernel @ x) / wsum[:, None]
        return ok, out

    def channels(self, lo: int, hi: int) -> Array:
        """Fusion channels of samples ``lo:hi`` (n, 15): the acceleration term v (used as
        is), the lever term u = q r q* (differentiated after the low-pass), and the sensor
        axes in I (for the bias and lever fits). Computed only when the grid needs them."""
        self._flush()
        rows = self.buf.view()[lo:hi]
        if self.p.method == "paper":
            v = rows[:, self.V : self.V + 3]
            return np.concatenate((v, np.zeros((len(v), 12))), axis=1)
        c = quat.matrix_columns(rows[:, self.QS : self.QS + 4])
        acc, r = rows[:, self.ACC : self.ACC + 3], self.r
        cx, cy, cz = c[:, 0:3], c[:, 3:6], c[:, 6:9]
        v = cx * acc[:, 0:1] + cy * acc[:, 1:2] + cz * acc[:, 2:3] - kin.GRAVITY
        u = cx * r[0] + cy * r[1] + cz * r[2]
        return np.concatenate((v, u, c), axis=1)

    def _bracket(self, s: Array) -> tuple[Idx, Idx, Idx, Array]:
        t, segid = np.ascontiguousarray(self.t), self.segid
        n = len(t)
        i1 = np.searchsorted(t, s, side="left")
        i1c = np.clip(i1, 1, max(n - 1, 1))
        i0 = i1c - 1
        ok = (i1 > 0) & (i1 < n) & (segid[i0] == segid[i1c])
        w = np.clip((s - t[i0]) / (t[i1c] - t[i0]), 0.0, 1.0)
        return ok, i0, i1c, w

    def interp(self, s: Array, asof: Array) -> tuple[Idx, tuple[Array, ...], Array]:
        """Orientation q_IA (w, x, y, z columns) at times ``s`` (nlerp, :func:`rows.nlerp`);
        ``ok`` where both neighbours exist in one segment; also the segment ids. Where
        ``s > asof`` (the IMU had only reached ``asof`` when the row was decided), predicted
        from the newest sample at or before ``asof`` (:func:`rows.predict`).
        Bit-identical to :meth:`at` for each time."""
        if len(self.tl) < 2:
            nan = np.full(len(s), np.nan)
            return np.zeros(len(s), bool), (nan, nan, nan, nan), np.zeros(len(s))
        ok, i0, i1, w = self._bracket(s)
        q = self.buf.cols(self.Q, self.Q + 4)
        q0 = tuple(q[i0, j] for j in range(4))
        q1 = tuple(q[i1, j] for j in range(4))
        qs, seg = rows.nlerp(rows.VECTOR, q0, q1, w), self.segid[i1]
        ahead = np.flatnonzero(s > asof)
        if len(ahead):
            t = np.ascontiguousarray(self.t)
            j = np.searchsorted(t, asof[ahead], side="right") - 1
            jc = np.maximum(j, 0)
            wa = self.buf.cols(self.W, self.DW + 3)
            qp = rows.predict(
                rows.VECTOR,
                tuple(q[jc, c] for c in range(4)),
                tuple(wa[jc, c] for c in range(3)),
                tuple(wa[jc, 3 + c] for c in range(3)),
                s[ahead] - t[jc],
            )
            qs = tuple(a.copy() for a in qs)
            for a, b in zip(qs, qp, strict=True):
                a[ahead] = b
            ok = ok.copy()
            ok[ahead] = j >= 0
            seg = seg.copy()
            seg[ahead] = self.segid[jc]
        return ok, qs, seg

    def at(self, s: float, asof: float) -> tuple[bool, tuple[float, ...], float]:
        """:meth:`interp` for one time, with Python floats (a single row costs ~20× less)."""
        tl = self.tl
        n = len(tl)
        if n < 2:
            return False, NAN4, 0.0
        if s > asof:
            # the newest sample at or before asof (usually the newest of all)
            j = n - 1 if asof >= tl[-1] else bisect.bisect_right(tl, asof) - 1
            jc = j if j > 0 else 0
            q, w, dw, seg = self._sample(jc)
            return j >= 0, rows.predict(rows.SCALAR, q, w, dw, s - tl[jc]), seg
        i1 = bisect.bisect_left(tl, s)
        i1c = min(max(i1, 1), n - 1)
        i0 = i1c - 1
        k = i0 - (n - len(self._mseg))
        if k >= 0:  # both in the mirror (the live case): one slice
            q01, (seg0, seg1) = self._mq[4 * k : 4 * k + 8], self._mseg[k : k + 2]
            q0, q1 = q01[:4], q01[4:]
        else:
            q0, _, _, seg0 = self._sample(i0)
            q1, _, _, seg1 = self._sample(i1c)
        t0, t1 = tl[i0], tl[i1c]
        w = rows.SCALAR.clip((s - t0) / (t1 - t0), 0.0, 1.0)
        return 0 < i1 < n and seg0 == seg1, rows.nlerp(rows.SCALAR, q0, q1, w), seg1

    def interp_channels(self, s: Array) -> tuple[Idx, Array]:
        """Fusion channels linearly interpolated at ``s`` (no anti-alias: the paper's way)."""
        if len(self.tl) < 2:
            return np.zeros(len(s), bool), np.full((len(s), 15), np.nan)
        ok, i0, i1, w = self._bracket(s)
        base = int(i0.min()) if len(i0) else 0
        x = self.channels(base, int(i1.max()) + 1 if len(i1) else 0)
        x0, x1 = x[i0 - base], x[i1 - base]
        return ok, x0 + w[:, None] * (x1 - x0)


# ------------------------------------------------------------------------------ stage 2: robot


class _RobotStage:
    """The elbow positions on the physical time base (stamp − offset), with segments split
    at gaps longer than ``robot_max_bridge_s``."""

    def __init__(self, p: PipelineParams) -> None:
        self.p = p
        self.buf = RowBuffer(5)  # t, segment id, p_E (3)
        self.tail: list[tuple[float, ...]] = []  # rows not yet in buf (one by one: cheaper)
        self.tl: list[float] = []
        self.seg = 0

    def _flush(self) -> None:
        if self.tail:
            self.buf.append(np.array(self.tail, dtype=np.float64))
            self.tail = []

    def append(self, s: list[float], p_e: Any, q: Quality) -> None:
        """Samples at physical times ``s``; ``p_e`` (n, 3) array or n float triples."""
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
                elif d > 2.5 / 25.0:
                    q.robot_bridged_gaps += 1
            segs.append(seg)
            prev = x
        self.seg = seg
        if isinstance(p_e, list):
            for x, g, e in zip(s, segs, p_e, strict=True):
                self.tail.append((x, g, *e))
        else:
            self._flush()
            rows = np.empty((len(s), 5))
            rows[:, 0] = s
            rows[:, 1] = segs
            rows[:, 2:5] = p_e
            self.buf.append(rows)
        self.tl.extend(s)

    def interp(self, g: Array) -> tuple[Idx, Array]:
        n = len(self.tl)
        if n < 2:
            return np.zeros(len(g), bool), np.full((len(g), 3), np.nan)
        self._flush()
        v = self.buf.view()
        t, segid, p_e = np.ascontiguousarray(v[:, 0]), v[:, 1], v[:, 2:5]
        i1 = np.clip(np.searchsorted(t, g, side="left"), 1, n - 1)
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


# ------------------------------------------------------------------------------ stage 3: grid


class _GridStage:
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

    def advance(self, imu: _ImuStage, robot: _RobotStage, until: float) -> None:
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


# ------------------------------------------------------------------------------ pipeline


class Pipeline:
    """One device's streaming pipeline. See the module docstring for the guarantees."""

    def __init__(self, params: PipelineParams | None = None) -> None:
        self.params = p = params or PipelineParams()
        self.hp = p.heading_params
        self.quality = Quality()
        self._imu_stream = _Stream("imu")
        self._robot_stream = _Stream("robot")
        self._imu = _ImuStage(p)
        self._robot = _RobotStage(p)
        self._grid = _GridStage(p)
        # messages fed since the last poll
        self._imu_pending: list[tuple[Array, Array, Array, list[float] | None]] = []
        # (t, wrist, proximal, elbow, the first three as float lists if at hand)
        self._robot_pending: list[tuple[Array, Array, Array, Array | None, Any]] = []
        # consecutive rows fed by feed_*_rows, not yet cut out as one pending piece:
        # [t, gyr, acc, i0, i1] and [t, wrist, proximal, elbow, i0, i1]
        self._imu_run: list[Any] | None = None
        self._robot_run: list[Any] | None = None
        self._cuff_src: tuple[Array, Array] | None = None  # arrays _cuff_bad describes
        self._cuff_bad: list[int] = []
        self._imu_frontier = -math.inf  # last IMU stamp fed
        self._robot_frontier = -math.inf
        # rows: robot samples in order; decided[i] = (with_imu, nominal_spec)
        self._row_t: list[float] = []
        self._n_decided = 0
        # (with IMU, nominal spec, the newest IMU stamp the row may use: inf once the IMU
        # has reached the row, else its prediction starts there)
        self._decisions: list[tuple[bool, int, float]] = []
        self._n_done = 0
        self._rowq = RowQueue(9)  # wrist, p_E, x_C of the robot samples not yet emitted
        # heading
        self._hstate = hd.HeadingState()
        self._hseg = 0
        self._t_update: float | None = None
        # heading after each update: t, delta, rate, t_update, std, converged, imu segment,
        # robot latency
        self._snaps: list[tuple[float, ...]] = []
        self._snap_t: list[float] = []
        self.convergence_time: float | None = None
        self.first_motion_time: float | None = None
        # nominal shoulder: specs in feed order: ("point", t, xyz) or ("auto", t, None)
        self._specs: list[tuple[str, float, Array | None]] = []
        if p.nominal_shoulder_m is not None:
            self._specs.append(
                ("param", -math.inf, np.array(p.nominal_shoulder_m, dtype=np.float64))
            )
        else:
            self._specs.append(("auto", -math.inf, None))
        self._nom_spec = -1
        self._nom_point: tuple[float, ...] | None = None
        self._nom_acc: list[tuple[float, ...]] = []
        self._nom_t0: float | None = None
        self._ref_point: Array | None = None  # the last rope-measured point (for l_A)
        self._arm_len = p.upper_arm_length_m
        self._arm_spec = -1
        self._arm_spec_done = -1
        self._arm_pts: list[Array] = []
        self._arm_free: set[int] = set()  # specs whose rows all use _arm_len as it is
        self.arm_length_estimate: float | None = None
        # compensation
        self._cp = CompensationParams(
            tolerance_m=p.tolerance_m,
            max_outside_fraction=p.max_outside_fraction,
            displacement_norm=p.displacement_norm,
            warning_after_s=p.warning_after_s,
        )
        self._indicator = Indicator(self._cp)
        self._segmenter = CycleSegmenter(CycleParams(mode=p.cycle_mode))
        self._judge = CycleJudge(self._cp)
        self._episodes = EpisodeTracker(self._cp)
        self._xc_prev_t = -math.inf
        self._xc_prev: Sequence[float] = (0.0, 0.0, 0.0)
        self._grid_trimmed = -math.inf
        self._next_trim = -math.inf  # robot stamp from which the next poll trims buffers
        # a row uses the latest heading update the grid is sure to have reached by the time
        # the row became ready (two grid steps and the anti-alias half-width back)
        self._snap_lag = 2.0 * self._grid.dt + self._grid.half + 1e-9

    # ------------------------------------------------------------------ feeding

    def feed(self, msg: Any) -> bool:
        """Take one decoded message (IMU, robot or event). Returns False if rejected."""
        kind = _KINDS.get(type(msg))
        if kind is None:  # duck-typed by attributes, cached per slotted type (hasattr is slow)
            kind = _kind_of(msg)
            if hasattr(type(msg), "__slots__"):
                _KINDS[type(msg)] = kind
        if kind == "imu":
            return self.feed_imu(
                msg.t,
                msg.gyr,
                msg.acc,
                getattr(msg, "seq", None),
                getattr(msg, "segment", "upperarm"),
            )
        if kind == "robot":
            return self.feed_robot(
                msg.t,
                msg.wrist,
                msg.proximal,
                getattr(msg, "elbow", None),
                getattr(msg, "seq", None),
            )
        if kind == "event":
            return self.feed_event(float(msg.t), str(msg.type), getattr(msg, "point", None))
        # optional streams (camera) are valid but not used by the method: counted, not rejected
        self.quality.ignored[type(msg).__name__] = (
            self.quality.ignored.get(type(msg).__name__, 0) + 1
        )
        return False

    def feed_imu(
        self, t: Array, gyr: Array, acc: Array, seq: int | None = None, segment: str = "upperarm"
    ) -> bool:
        # (pending messages hold no Python lists: in a batch they would be many thousand
        # objects for the garbage collector to walk again and again)
        tl = t.tolist()
        if not self._admit_imu(tl[0], tl[-1], len(tl), seq, segment):
            return False
        if self._imu_run is not None:
            self._close_imu_run()
        self._imu_pending.append((t, gyr, acc, tl))
        if self._n_decided < len(self._row_t):
            self._decide()
        return True

    def feed_imu_rows(
        self,
        t: Array,
        tl: Sequence[float],
        gyr: Array,
        acc: Array,
        i0: int,
        i1: int,
        seq: int | None = None,
        segment: str = "upperarm",
    ) -> bool:
        """:meth:`feed_imu` of rows ``i0:i1`` of arrays that hold many messages end to end
        (``tl``: ``t`` as floats). The same result as
        ``feed_imu(t[i0:i1], gyr[i0:i1], acc[i0:i1], seq, segment)``, but consecutive
        messages stay one piece: a batch's poll then joins a few pieces, not ~10^4."""
        if not self._admit_imu(tl[i0], tl[i1 - 1], i1 - i0, seq, segment):
            return False
        run = self._imu_run
        if run is not None and run[0] is t and run[4] == i0:
            run[4] = i1
        else:
            self._close_imu_run()
            self._imu_run = [t, gyr, acc, i0, i1]
        self._decide()
        return True

    def _admit_imu(self, t0: float, t1: float, n: int, seq: int | None, segment: str) -> bool:
        if segment != "upperarm":  # forearm/trunk IMUs are for later estimators
            self.quality.ignored[f"imu_{segment}"] = (
                self.quality.ignored.get(f"imu_{segment}", 0) + 1
            )
            return False
        if not self._imu_stream.admit(t0, seq, self.quality):
            return False
        self._imu_stream.last_t = self._imu_frontier = t1
        self.quality.imu_samples += n
        return True

    def _close_imu_run(self) -> None:
        run = self._imu_run
        if run is not None:
            t, gyr, acc, i0, i1 = run
            self._imu_pending.append((t[i0:i1], gyr[i0:i1], acc[i0:i1], None))
            self._imu_run = None

    def feed_robot(
        self,
        t: Array,
        wrist: Array,
        proximal: Array,
        elbow: Array | None = None,
        seq: int | None = None,
    ) -> bool:
        tl = t.tolist()
        if not self._robot_stream.admit(tl[0], seq, self.quality):
            return False
        # pure Python: per-message numpy calls would cost more than the whole check
        wl, pl = wrist.tolist(), proximal.tolist()
        for w, p in zip(wl, pl, strict=True):
            x, y, z = w[0] - p[0], w[1] - p[1], w[2] - p[2]
            if x * x + y * y + z * z <= _COINCIDENT_M2:
                self.quality.reject("coincident_cuffs")
                return False
        if self._robot_run is not None:
            self._close_robot_run()
        self._robot_pending.append((t, wrist, proximal, elbow, (tl, wl, pl)))
        self._accept_robot(tl)
        return True

    def feed_robot_rows(
        self,
        t: Array,
        tl: Sequence[float],
        wrist: Array,
        proximal: Array,
        elbow: Array | None,
        i0: int,
        i1: int,
        seq: int | None = None,
    ) -> bool:
        """:meth:`feed_robot` of rows ``i0:i1`` (as :meth:`feed_imu_rows`). ``elbow``: NaN
        rows for messages without one (the cuffs' elbow is used there, as for None)."""
        if not self._robot_stream.admit(tl[i0], seq, self.quality):
            return False
        if self._cuff_src is None or not (
            self._cuff_src[0] is wrist and self._cuff_src[1] is proximal
        ):
            # the same arithmetic as feed_robot's loop, for all the rows at once
            d = wrist - proximal
            x, y, z = d[:, 0], d[:, 1], d[:, 2]
            self._cuff_bad = np.flatnonzero(x * x + y * y + z * z <= _COINCIDENT_M2).tolist()
            self._cuff_src = (wrist, proximal)
        j = bisect.bisect_left(self._cuff_bad, i0)
        if j < len(self._cuff_bad) and self._cuff_bad[j] < i1:
            self.quality.reject("coincident_cuffs")
            return False
        run = self._robot_run
        if run is not None and run[0] is t and run[3] is elbow and run[5] == i0:
            run[5] = i1
        else:
            self._close_robot_run()
            self._robot_run = [t, wrist, proximal, elbow, i0, i1]
        self._accept_robot(tl[i0:i1])
        return True

    def _accept_robot(self, tl: Sequence[float]) -> None:
        self._robot_stream.last_t = self._robot_frontier = tl[-1]
        self._row_t.extend(tl)
        self.quality.robot_samples += len(tl)
        self._decide()

    def _close_robot_run(self) -> None:
        run = self._robot_run
        if run is not None:
            t, wrist, prox, elbow, i0, i1 = run
            e = None if elbow is None else elbow[i0:i1]
            self._robot_pending.append((t[i0:i1], wrist[i0:i1], prox[i0:i1], e, None))
            self._robot_run = None

    def feed_event(self, t: float, etype: str, point: Array | None = None) -> bool:
        if etype == "shoulder_reference" and point is not None:
            self._specs.append(("point", t, np.asarray(point, dtype=np.float64)))
        elif etype == "nominal_reset":
            self._specs.append(("auto", t, None))
        elif etype == "cycle_start":
            self._segmenter.add_event(t)
        else:
            self.quality.reject("unknown_event")
            return False
        return True

    def _decide(self) -> None:
        """Mark robot samples ready: the IMU has reached them, or is at most
        ``imu_predict_s`` behind (the upper arm is then predicted from the newest IMU
        sample), or the robot ran ahead by ``imu_wait_s`` (then they are emitted without
        IMU-derived values). Decided in feed order, so batching changes nothing."""
        if self._n_decided >= len(self._row_t):
            return
        off = self.params.robot_time_offset_s
        wait = self.params.imu_wait_s
        ahead = self.params.imu_predict_s
        front = self._imu_frontier
        n = len(self._row_t)
        i = self._n_decided
        spec = len(self._specs) - 1
        while i < n:
            tr = self._row_t[i]
            asof = math.inf
            with_imu = front >= tr - off
            if not with_imu and tr - off - front <= ahead:
                with_imu, asof = True, front
            elif not with_imu and self._robot_frontier < tr + wait:
                break
            # the latest nominal spec (in feed order) whose time has come
            k = spec
            while k > 0 and self._specs[k][1] > tr:
                k -= 1
            self._decisions.append((with_imu, k, asof))
            i += 1
        self._n_decided = i

    @property
    def rows_ready(self) -> bool:
        """Whether :meth:`poll` would return rows now (cheap; for callers polling on demand)."""
        return self._n_decided > self._n_done

    def status(self) -> dict[str, Any]:
        """What a dashboard shows beside the numbers: convergence and its progress, the
        heading's confidence, the estimated sensor errors, and the data quality."""
        s = self._hstate
        hp = self.hp
        if s.converged:
            progress = 1.0
        elif hp.method == "paper":
            progress = min(s.n_counted / (hp.n_two_step + hp.converge_count), 0.99)
        else:
            # motion seen so far (sub-windows) and the heading's certainty, whichever lags
            need = hp.min_motion_subwindows * hp.window_s / hp.n_subwindows
            moved = 0.0 if self.first_motion_time is None else need
            certainty = (
                0.0
                if not math.isfinite(s.std)
                else min(1.0, math.radians(hp.max_converge_std_deg) / s.std)
            )
            progress = min(0.99, 0.5 * moved / need + 0.5 * certainty)
        std = math.degrees(s.std) if math.isfinite(s.std) else None
        return {
            "heading_converged": s.converged,
            "convergence_progress": progress,
            "heading_offset_deg": None if s.delta is None else math.degrees(s.delta) % 360.0,
            "heading_std_deg": std,
            "heading_confidence": 0.0 if std is None else 1.0 / (1.0 + (std / 3.0) ** 2),
            "heading_drift_dps": math.degrees(s.rate),
            "excitation_m_s2": s.excitation,
            "first_motion_t": self.first_motion_time,
            "converged_t": self.convergence_time,
            "robot_latency_s": s.lag,
            "acc_bias_m_s2": s.acc_bias.tolist(),
            "lever_error_m": s.lever_error.tolist(),
            "upper_arm_length_m": self._arm_len,
            "upper_arm_length_measured": self.arm_length_estimate is not None,
            "quality": self.quality.as_dict(),
        }

    # ------------------------------------------------------------------ computing

    def poll(self) -> Output:
        """Run everything that is ready; return the new rows and feedback."""
        if self._imu_run is not None:
            self._close_imu_run()
        if self._robot_run is not None:
            self._close_robot_run()
        if self._imu_pending:
            pend, self._imu_pending = self._imu_pending, []
            if len(pend) == 1:
                t, gyr, acc, tl = pend[0]
                self._imu.process(t, gyr, acc, self.quality, tl)
            else:
                self._imu.process(
                    np.concatenate([c[0] for c in pend]),
                    np.concatenate([c[1] for c in pend]),
                    np.concatenate([c[2] for c in pend]),
                    self.quality,
                )
        off = self.params.robot_time_offset_s
        if self._robot_pending:
            pend_r, self._robot_pending = self._robot_pending, []
            if len(pend_r) == 1:
                self._robot_samples(*pend_r[0][:4], off, pend_r[0][4])
            else:  # one vectorised call (elementwise: the same numbers as one by one)
                given = [c[3] for c in pend_r]
                elbow = None
                if any(e is not None for e in given):
                    elbow = np.concatenate(
                        [np.full((len(c[0]), 3), np.nan) if c[3] is None else c[3] for c in pend_r]
                    )
                self._robot_samples(
                    np.concatenate([c[0] for c in pend_r]),
                    np.concatenate([c[1] for c in pend_r]),
                    np.concatenate([c[2] for c in pend_r]),
                    elbow,
                    off,
                )
        # fusion grid as far as both streams reach (stamps fed so far)
        until = min(self._imu_frontier - self._grid.half, self._robot_frontier - off)
        # The grid only feeds heading updates: advance it (in one vectorised chunk, with the
        # same numbers as sample by sample) once its output, which ends one grid step before
        # the last grid point, reaches the next update.
        dt = self._grid.dt
        due = self._t_update is None or (
            math.isfinite(until) and (math.floor(until / dt) - 1) * dt >= self._t_update
        )
        if self._imu.ts is not None and due:
            self._grid.advance(self._imu, self._robot, until)
            self._run_heading()
        out = self._rows()
        # forgetting old data changes no result, so it is done about once a second of data
        # (per poll it would cost as much as the row itself)
        if not self._robot_frontier < self._next_trim:
            self._trim()
            self._next_trim = self._robot_frontier + 1.0
        return out

    def finish(self) -> Output:
        """End of data: emit the rows still waiting for an IMU that will not come."""
        self._robot_frontier = math.inf
        self._decide()
        return self.poll()

    def run(self, messages: Any) -> Output:
        """Batch call: feed everything, then compute. Identical to any streaming schedule."""
        for m in messages:
            self.feed(m)
        out = self.poll()
        out.extend(self.finish())
        return out

    def _run_heading(self) -> None:
        hp = self.hp
        front = self._grid.frontier
        if not math.isfinite(front):
            return
        if self._t_update is None:
            step = hp.update_interval_s
            self._t_update = (math.floor(self._grid.t[0] / step) + 1) * step
        snaps: list[tuple[float, ...]] = []
        while self._t_update <= front:
            t_up = self._t_update
            # updates on a fixed lattice of the sample clock; sparser once converged
            step = hp.update_interval_s
            if hp.method == "improved" and self._hstate.converged:
                step = hp.converged_interval_s
            self._t_update = (math.floor(t_up / step + 1e-9) + 1) * step
            seg = int(
                self._grid.seg[
                    min(
                        int(np.searchsorted(self._grid.t, t_up, side="right")) - 1,
                        len(self._grid.seg) - 1,
                    )
                ]
            )
            if seg != self._hseg:
                self._hstate = hd.HeadingState()
                self._hseg = seg
                self.quality.heading_resets += 1
            span = hp.window_s if hp.method == "paper" else max(hp.window_s, hp.fit_window_s)
            w = self._grid.window(t_up, span, seg)
            if hp.method == "paper":
                counted = hd.update_paper(self._hstate, w, hp, t_up)
            else:
                counted = hd.update_improved(self._hstate, w, hp, t_up, self._grid.lag)
            if counted and self.first_motion_time is None:
                self.first_motion_time = t_up
            if self._hstate.converged and self.convergence_time is None:
                self.convergence_time = t_up
            s = self._hstate
            d = math.nan if s.delta is None else s.delta
            snaps.append(
                (t_up, d, s.rate, s.t_update, s.std, float(s.converged), float(seg), s.lag)
            )
        self._snaps.extend(snaps)
        self._snap_t.extend(s[0] for s in snaps)

    def _robot_samples(
        self,
        t: Array,
        wrist: Array,
        prox: Array,
        elbow: Array | None,
        off: float,
        lists: tuple[list[float], list[list[float]], list[list[float]]] | None = None,
    ) -> None:
        """Elbow and forearm axis from the cuffs (eq. 13), or the robot's own elbow."""
        n = len(t)
        lp = self.params.cuff_to_elbow_m
        if n <= _SMALL:
            M = rows.SCALAR
            tl, wl, pl = lists or (t.tolist(), wrist.tolist(), prox.tolist())
            el = None if elbow is None else elbow.tolist()
            pes: list[tuple[float, ...]] = []
            for j, (w, p) in enumerate(zip(wl, pl, strict=True)):
                xc = rows.unit(M, (w[0] - p[0], w[1] - p[1], w[2] - p[2]))
                pe = (p[0] - lp * xc[0], p[1] - lp * xc[1], p[2] - lp * xc[2])
                if el is not None:
                    pe = tuple(e if math.isfinite(e) else v for e, v in zip(el[j], pe, strict=True))
                self._rowq.push((*w, *pe, *xc))
                pes.append(pe)
            self._robot.append([x - off for x in tl] if off else tl, pes, self.quality)
            return
        M = rows.VECTOR
        xc_v = rows.unit(M, tuple(wrist[:, i] - prox[:, i] for i in range(3)))
        pe_v = tuple(prox[:, i] - lp * xc_v[i] for i in range(3))
        if elbow is not None:
            pe_v = tuple(np.where(np.isfinite(elbow[:, i]), elbow[:, i], pe_v[i]) for i in range(3))
        block = np.column_stack((wrist, *pe_v, *xc_v))
        self._rowq.append(block)
        self._robot.append((t - off).tolist(), block[:, 3:6], self.quality)

    def _rows(self) -> Output:
        """Rows of the robot samples decided since the last poll (eqs. 9–12, §3.4).

        One row at a time in Python floats when few are due (the live case), as arrays
        otherwise; :mod:`estimators.rows` makes both bit-identical."""
        lo, hi = self._n_done, self._n_decided
        if hi <= lo:
            return Output()
        self._n_done = hi
        n = hi - lo
        t = self._row_t[lo:hi]
        dec = self._decisions[lo:hi]
        # compensation rule (§3.4); segment first: a completed cycle sets the tolerated
        # duration from its end on
        boundaries: list[float]
        tt: Any
        disp: Any
        if n <= _SMALL:
            flat: list[float] = []
            boundaries, disp = [], []
            seg = self._segmenter
            for tj, dj, rj in zip(t, dec, self._rowq.take_rows(n), strict=True):
                row = self._row(tj, dj, rj)
                flat.extend(row)
                disp.append(row[_DISP])
                boundaries.extend(seg.push(tj, rj[0], rj[1]))
            tt = t
            # (not np.frombuffer of an array.array, though faster: its base objects would be
            # tracked by the cyclic collector as long as the rows live)
            m = np.fromiter(flat, np.float64, len(flat)).reshape(n, _NCOL)  # np.array: 1.5x
        else:
            block = self._rowq.take_block(n)
            with np.errstate(invalid="ignore", divide="ignore"):  # NaN where no estimate
                m = self._rows_vector(np.array(t), dec, block)
            tt, disp = m[:, 0], m[:, _DISP]
            boundaries = self._segmenter.update(tt, block[:, 0:3])
        codes, changes = self._indicator.update(tt, disp, None, boundaries)
        verdicts = self._judge.update(tt, codes, boundaries, disp)
        episodes = self._episodes.update(tt, codes, disp)
        fb: list[dict[str, Any]] = [{"t": tc, "type": "state", "state": st} for tc, st in changes]
        if verdicts:
            fb.extend(
                {
                    "type": "cycle",
                    "start": v.start,
                    "end": v.end,
                    "outside_fraction": v.outside_fraction,
                    "compensatory": v.compensatory,
                }
                for v in verdicts
                if v.compensatory is not None
            )
            fb.sort(key=lambda f: f.get("t", f.get("end", 0.0)))
        return Output(RowTable(m, codes), fb, list(verdicts), episodes)

    def _row(self, t: float, dec: tuple[bool, int, float], r: Sequence[float]) -> list[float]:
        """One row in Python floats, in ``_LAYOUT`` order (state filled in later)."""
        M = rows.SCALAR
        p = self.params
        with_imu, k, asof = dec
        s = t - p.robot_time_offset_s
        # the heading updates the grid had surely produced when the row was decided
        i = bisect.bisect_right(self._snap_t, min(s, asof) - self._snap_lag) - 1
        snap = self._snaps[i] if i >= 0 else NAN8
        lat = snap[7]
        latency = M.maximum(lat, 0.0) if math.isfinite(lat) else 0.0
        ok_p, q_p, seg_p = self._imu.at(s - latency, asof)
        ok_n, q_n, seg_n = self._imu.at(s, asof)
        ok = ok_p and with_imu and ok_n and seg_n == seg_p
        h, q_ra, x_now, x_a = rows.heading_arm_scalar(s, ok, snap, seg_p, q_n, q_p)
        wrist, p_e, x_c = r[0:3], r[3:6], r[6:9]
        prev_t, prev = self._xc_prev_t, self._xc_prev
        self._xc_prev_t, self._xc_prev = t, x_c
        la = self._arm_len if k in self._arm_free else self._arm_length(t, p_e, k)
        sh = rows.shoulder(p_e, x_a, la)
        nom = self._nominal_at(t, sh, h.good, k)
        angle, disp, conv, elev, azim = rows.angles_scalar(
            x_now, x_c, p_e, sh, nom, p.displacement_norm
        )
        if p.elbow_angle_timing != "fresh":
            angle = self._angle(M, x_now, x_a, x_c, prev, t - prev_t, latency)
        if not with_imu:
            self.quality.rows_without_imu += 1
        good = 1.0 if h.good else 0.0
        return [
            t, *p_e, *sh, angle, h.offset_deg, good, disp, math.nan, *q_ra, h.std_deg,
            h.confidence, elev, azim, *nom, conv, *wrist, la,
        ]  # fmt: skip

    def _rows_vector(self, t: Array, dec: list[tuple[bool, int, float]], block: Array) -> Array:
        """:meth:`_row` for many rows at once, as arrays: (n, ``_NCOL``)."""
        M = rows.VECTOR
        p = self.params
        n = len(t)
        s = t - p.robot_time_offset_s
        imu_l, spec_t, asof_l = zip(*dec, strict=True)
        with_imu = np.array(imu_l, dtype=bool)
        spec = list(spec_t)
        asof = np.array(asof_l)
        if self._snaps:
            si = (
                np.searchsorted(
                    np.array(self._snap_t), np.minimum(s, asof) - self._snap_lag, side="right"
                )
                - 1
            )
            sn = np.array(self._snaps)[np.maximum(si, 0)]
            sn[si < 0] = np.nan
        else:
            sn = np.full((n, 8), np.nan)
        snap = tuple(sn[:, j] for j in range(8))
        latency = np.where(np.isfinite(sn[:, 7]), np.maximum(sn[:, 7], 0.0), 0.0)
        ok_p, q_p, seg_p = self._imu.interp(s - latency, asof)
        ok_n, q_n, seg_n = self._imu.interp(s, asof)
        ok = ok_p & with_imu & ok_n & (seg_n == seg_p)
        h = rows.heading(M, s, ok, snap, seg_p)
        q_ra, x_now, x_a = rows.upper_arm(M, h.delta, h.good, q_n, q_p)
        wrist = block[:, 0:3]
        p_e = tuple(block[:, 3 + i] for i in range(3))
        x_c = tuple(block[:, 6 + i] for i in range(3))
        prev_t = np.concatenate(([self._xc_prev_t], t[:-1]))
        prev = tuple(np.concatenate(([self._xc_prev[i]], x_c[i][:-1])) for i in range(3))
        self._xc_prev_t, self._xc_prev = float(t[-1]), tuple(float(c[-1]) for c in x_c)
        angle = self._angle(M, x_now, x_a, x_c, prev, t - prev_t, latency)
        tl = t.tolist()
        pe_rows = block[:, 3:6].tolist()
        # per row as in _row, but a run of rows whose value can no longer change is filled
        # at once (an analysis has ~10^4 rows and one or two nominal specs)
        la = np.empty(n)
        i = 0
        while i < n:
            k = spec[i]
            if self._arm_length_fixed(k):
                j = _run_end(spec, i)
                la[i:j] = self._arm_len
                i = j
            else:
                la[i] = self._arm_length(tl[i], pe_rows[i], k)
                i += 1
        sh = rows.shoulder(p_e, x_a, la)
        sh_rows = np.column_stack(sh).tolist()
        good = h.good.tolist()
        nom_a = np.empty((n, 3))
        i = 0
        while i < n:
            k = spec[i]
            nom_a[i] = self._nominal_at(tl[i], tuple(sh_rows[i]), good[i], k)
            i += 1
            if self._nom_point is not None:  # set for the rest of this spec's rows
                j = _run_end(spec, i - 1)
                nom_a[i:j] = self._nom_point
                i = j
        nom = tuple(nom_a[:, i] for i in range(3))
        disp = rows.displacement(M, sh, nom, p.displacement_norm)
        conv = rows.conventional_angle(M, p_e, nom, x_c)
        elev, azim = rows.elevation_azimuth(M, x_now)
        self.quality.rows_without_imu += int(np.count_nonzero(~with_imu))
        return np.column_stack(
            (
                t, *p_e, *sh, angle, h.offset_deg, h.good, disp, np.full(n, np.nan), *q_ra,
                h.std_deg, h.confidence, elev, azim, *nom, conv, wrist, la,
            )
        )  # fmt: skip

    def _angle(
        self,
        M: Any,
        x_now: Sequence[Any],
        x_pair: Sequence[Any],
        x_c: Sequence[Any],
        prev: Sequence[Any],
        dt: Any,
        latency: Any,
    ) -> Any:
        """Elbow angle (eq. 11) at the row's time.

        The robot's forearm axis is ``latency`` old while the IMU's upper-arm axis is fresh;
        ``extrapolate`` carries the forearm axis forward along its last robot step (``prev``,
        ``dt`` earlier) so both segments describe the same instant; ``fresh`` pairs them as
        they are; ``paired`` uses the upper arm at the robot's instant.
        """
        mode = self.params.elbow_angle_timing
        if mode == "paired":
            return rows.angle_deg(M, x_pair, x_c)
        if mode == "extrapolate":
            x_c = rows.extrapolate(M, x_c, prev, dt, latency)
        return rows.angle_deg(M, x_now, x_c)

    def _arm_length_fixed(self, k: int) -> bool:
        """Whether :meth:`_arm_length` returns ``_arm_len`` for every row of spec ``k`` from
        here on, whatever the row."""
        kind, _, point = self._specs[k]
        if self.params.arm_length != "calibrate" or kind != "point" or point is None:
            self._arm_free.add(k)  # for good: a spec's kind and point never change
            return True
        return k == self._arm_spec_done

    def _arm_length(self, t: float, p_e: Sequence[float], k: int) -> float:
        """Upper-arm length at a row: the parameter, or measured at the rope reference.

        While the therapist holds the rope end on the shoulder (``shoulder_reference``), the
        shoulder is at ``p_ref`` and the robot measures the elbow, so ``l_A = |p_E − p_ref|``
        (mean elbow over ``arm_reference_s`` after the event). This removes the constant
        offset an assumed length leaves in every shoulder estimate (eq. 12), without
        needing the heading. Out-of-bounds or moving-arm measurements are ignored.
        """
        if self._arm_length_fixed(k):
            return self._arm_len
        p = self.params
        _, t_e, point = self._specs[k]
        if self._arm_spec != k:
            self._arm_spec, self._arm_pts = k, []
        if t <= t_e + p.arm_reference_s:
            self._arm_pts.append(np.array(p_e))
            return self._arm_len
        self._arm_spec_done = k
        pts = np.array(self._arm_pts)
        self._arm_pts = []
        if len(pts) >= 3 and float(np.max(np.std(pts, axis=0))) < 0.01:
            length = float(np.linalg.norm(pts.mean(axis=0) - point))
            lo_b, hi_b = p.arm_length_bounds_m
            if lo_b <= length <= hi_b:
                self._arm_len = length
                self.arm_length_estimate = length
                return length
        self.quality.reject("arm_reference_unusable")
        return self._arm_len

    def _nominal_at(
        self, t: float, shoulder: tuple[float, ...], good: bool, k: int
    ) -> tuple[float, ...]:
        """Nominal shoulder at a row (contract §4): parameter, rope reference, or automatic
        (mean estimate over ``auto_nominal_s`` after convergence / after a reset event)."""
        if k != self._nom_spec:
            self._nom_spec = k
            kind, _, point = self._specs[k]
            self._nom_point = None if point is None else tuple(point.tolist())
            self._nom_acc, self._nom_t0 = [], None
            if point is not None and kind == "point":
                self._ref_point = point
        if self._nom_point is None and good:
            if self._nom_t0 is None:
                self._nom_t0 = t
            self._nom_acc.append(shoulder)
            if t - self._nom_t0 >= self.params.auto_nominal_s:
                m = len(self._nom_acc)
                self._nom_point = tuple(math.fsum(c) / m for c in zip(*self._nom_acc, strict=True))
                self._nom_acc = []
        return NAN3 if self._nom_point is None else self._nom_point

    def _trim(self) -> None:
        # keep what the next rows, grid points and heading windows can still need
        off = self.params.robot_time_offset_s
        keep = (
            self._row_t[self._n_done] if self._n_done < len(self._row_t) else self._robot_frontier
        )
        keep = min(keep - off, self._grid.frontier) - 1.0
        if math.isfinite(keep):
            self._imu.trim(keep)
            self._robot.trim(keep)
        if self._grid_trimmed != self._grid.frontier:
            self._grid_trimmed = self._grid.frontier
            self._grid.trim(self._grid.frontier - max(self.hp.window_s, self.hp.fit_window_s) - 1.0)
        if self._n_done < len(self._row_t):
            s_next = self._row_t[self._n_done] - off
            cut = bisect.bisect_right(self._snap_t, s_next - 1.0) - 2
            if cut > 0:
                del self._snaps[:cut]
                del self._snap_t[:cut]
        # forget rows already emitted (indices stay consistent through the offset); soon:
        # in a service, long lists are what the garbage collector's full passes walk
        if self._n_done > 256:
            k = self._n_done
            del self._row_t[:k]
            del self._decisions[:k]
            self._n_decided -= k
            self._n_done = 0


_KINDS: dict[type, str] = {}


def _kind_of(msg: Any) -> str:
    if hasattr(msg, "gyr"):
        return "imu"
    if hasattr(msg, "proximal"):
        return "robot"
    if hasattr(msg, "type") and hasattr(msg, "t"):
        return "event"
    return "other"


_COINCIDENT_M2 = 1e-12  # squared cuff distance, m², below which the cuffs coincide
_SMALL = 16  # up to this many rows or samples per call take the Python-float path
NAN3 = (math.nan,) * 3
NAN4 = (math.nan,) * 4
NAN8 = (math.nan,) * 8
_WIDTHS = {"elbow": 3, "shoulder": 3, "q_ra": 4, "nominal_shoulder": 3, "wrist": 3}
_LAYOUT: list[tuple[str, int, int]] = []
for _name in ROW_COLUMNS:
    _w = _WIDTHS.get(_name, 1)
    _LAYOUT.append((_name, sum(w for _, _, w in _LAYOUT), _w))
_COL = {name: a for name, a, _ in _LAYOUT}
_SPAN = {name: (a, w) for name, a, w in _LAYOUT}
_NCOL = sum(w for _, _, w in _LAYOUT)
_DISP = _COL["shoulder_displacement_m"]
