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

import math
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray
from vqf import VQF

from estimators import heading as hd
from estimators import kinematics as kin
from estimators import quaternion as quat
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


@dataclass
class Output:
    """New rows (``ROW_COLUMNS``, arrays of equal length) and feedback since the last poll."""

    rows: dict[str, Array] = field(default_factory=dict)
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
                self.rows = {k: np.concatenate((v, other.rows[k])) for k, v in self.rows.items()}
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


# ------------------------------------------------------------------------------ stage 1: IMU


class _ImuStage:
    """6D orientation and elbow-acceleration terms at the IMU rate (frame I)."""

    def __init__(self, p: PipelineParams) -> None:
        self.p = p
        self.mount = np.array(p.mounting_quat, dtype=np.float64)
        self.mount /= np.linalg.norm(self.mount)
        # lever arm IMU → elbow in the sensor frame (eq. 1's r = [d, 0, 0] in A)
        self.r = quat.rotate(self.mount, EX * p.imu_to_elbow_m)
        self.ts: float | None = None
        self.probe: list[tuple[Array, Array, Array]] = []
        self.vqf: VQF | None = None
        self.last: tuple[float, Array, Array] | None = None
        self.seg = 0
        self.gyro_lp: LowPass | None = None
        self.gyro_zi: Array | None = None
        self.gyro_prev: Array | None = None
        # processed buffer
        self.t = np.empty(0)
        self.segid = np.empty(0, dtype=np.int64)
        self.q = np.empty((0, 4))  # q_IA (segment frame)
        self.q_is = np.empty((0, 4))  # the 6D filter's sensor orientation
        self.acc = np.empty((0, 3))  # specific force, sensor frame
        self.v = np.empty((0, 3))  # paper method: eq. 1–2 acceleration (sequential filter)

    def _reset(self) -> None:
        assert self.ts is not None
        self.vqf = VQF(self.ts, tauAcc=self.p.vqf_tau_acc_s)
        self.gyro_zi = None
        self.gyro_prev = None

    def process(self, t: Array, gyr: Array, acc: Array, q: Quality) -> None:
        if self.ts is None:
            self.probe.append((t, gyr, acc))
            if sum(len(c[0]) for c in self.probe) < self.p.rate_probe_samples:
                return
            t = np.concatenate([c[0] for c in self.probe])
            gyr = np.concatenate([c[1] for c in self.probe])
            acc = np.concatenate([c[2] for c in self.probe])
            self.probe = []
            dt = float(np.median(np.diff(t[: self.p.rate_probe_samples])))
            self.ts = min(max(dt, 1e-3), 0.1)  # contract: 10..1000 Hz
            if self.p.method == "paper":
                self.gyro_lp = LowPass(self.p.lowpass_order, self.p.gyro_lowpass_hz, 1.0 / self.ts)
            self._reset()
        assert self.ts is not None
        ts = self.ts
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

    def _run(self, t: Array, gyr: Array, acc: Array) -> None:
        """Orientation and acceleration terms of one contiguous piece of samples."""
        if len(t) == 0:
            return
        assert self.vqf is not None
        out = self.vqf.updateBatch(np.ascontiguousarray(gyr), np.ascontiguousarray(acc))
        q_is = np.asarray(out["quat6D"], dtype=np.float64)
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
            self.v = np.concatenate((self.v, v))
        self.t = np.concatenate((self.t, t))
        self.segid = np.concatenate((self.segid, np.full(len(t), self.seg)))
        self.q = np.concatenate((self.q, quat.mul(q_is, self.mount)))
        self.q_is = np.concatenate((self.q_is, q_is))
        self.acc = np.concatenate((self.acc, acc))

    def trim(self, t_keep: float) -> None:
        i = max(0, int(np.searchsorted(self.t, t_keep)) - 2)
        if i > 0:
            self.t, self.segid = self.t[i:], self.segid[i:]
            self.q = self.q[i:]
            if len(self.v):
                self.v = self.v[i:]
            self.q_is, self.acc = self.q_is[i:], self.acc[i:]

    def smooth(self, g: Array, half: float) -> tuple[Idx, Array]:
        """Acceleration terms (v, u) at grid times ``g``, anti-aliased by a centred Hann
        kernel of half-width ``half`` (s). Centred, so it shifts nothing in time: a lag
        between the two sides would turn into a heading bias on circular paths.
        Returns ``(ok, x)`` with x (n, 6); ok where the whole kernel lies in one segment."""
        n, ng = len(self.t), len(g)
        ts = self.ts or 0.01
        m = int(math.ceil(2.0 * half / ts)) + 2
        if n < m:
            return np.zeros(ng, bool), np.full((ng, 15), np.nan)
        lo = np.clip(np.searchsorted(self.t, g - half, side="left"), 0, n - m)
        idx = lo[:, None] + np.arange(m)[None, :]
        tt = self.t[idx] - g[:, None]
        w = np.where(np.abs(tt) < half, 0.5 + 0.5 * np.cos(np.pi * tt / half), 0.0)
        wsum = w.sum(axis=1)
        ok = (
            (self.t[lo] <= g - half + ts)
            & (self.t[lo + m - 1] >= g + half - ts)
            & (self.segid[lo] == self.segid[lo + m - 1])
            & (wsum > 0)
        )
        base = int(lo.min())
        x = self.channels(base, int(lo.max()) + m)[idx - base]  # (ng, m, 15)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.einsum("gm,gmc->gc", w, x) / wsum[:, None]
        return ok, out

    def channels(self, lo: int, hi: int) -> Array:
        """Fusion channels of samples ``lo:hi`` (n, 15): the acceleration term v (used as
        is), the lever term u = q r q* (differentiated after the low-pass), and the sensor
        axes in I (for the bias and lever fits). Computed only when the grid needs them."""
        if self.p.method == "paper":
            v = self.v[lo:hi]
            return np.concatenate((v, np.zeros((len(v), 12))), axis=1)
        c = quat.matrix_columns(self.q_is[lo:hi])
        acc, r = self.acc[lo:hi], self.r
        cx, cy, cz = c[:, 0:3], c[:, 3:6], c[:, 6:9]
        v = cx * acc[:, 0:1] + cy * acc[:, 1:2] + cz * acc[:, 2:3] - kin.GRAVITY
        u = cx * r[0] + cy * r[1] + cz * r[2]
        return np.concatenate((v, u, c), axis=1)

    def _bracket(self, s: Array) -> tuple[Idx, Idx, Idx, Array]:
        n = len(self.t)
        i1 = np.searchsorted(self.t, s, side="left")
        i1c = np.clip(i1, 1, max(n - 1, 1))
        i0 = i1c - 1
        ok = (i1 > 0) & (i1 < n) & (self.segid[i0] == self.segid[i1c])
        w = np.clip((s - self.t[i0]) / (self.t[i1c] - self.t[i0]), 0.0, 1.0)
        return ok, i0, i1c, w

    def interp(self, s: Array) -> tuple[Idx, Array, Idx]:
        """Orientation q_IA at times ``s`` (nlerp); ``ok`` where both neighbours exist in
        one segment; also the segment ids."""
        if len(self.t) < 2:
            return np.zeros(len(s), bool), np.full((len(s), 4), np.nan), np.zeros(len(s), np.int64)
        ok, i0, i1, w = self._bracket(s)
        return ok, quat.nlerp(self.q[i0], self.q[i1], w), self.segid[i1]

    def interp_channels(self, s: Array) -> tuple[Idx, Array]:
        """Fusion channels linearly interpolated at ``s`` (no anti-alias: the paper's way)."""
        if len(self.t) < 2:
            return np.zeros(len(s), bool), np.full((len(s), 15), np.nan)
        ok, i0, i1, w = self._bracket(s)
        base = int(i0.min()) if len(i0) else 0
        x = self.channels(base, int(i1.max()) + 1 if len(i1) else 0)
        x0, x1 = x[i0 - base], x[i1 - base]
        return ok, x0 + w[:, None] * (x1 - x0)


# ------------------------------------------------------------------------------ stage 2: robot


class _RobotStage:
    def __init__(self, p: PipelineParams) -> None:
        self.p = p
        self.t = np.empty(0)  # physical time (stamp − offset)
        self.segid = np.empty(0, dtype=np.int64)
        self.p_e = np.empty((0, 3))
        self.seg = 0
        self.base = 0  # global index of self.t[0]

    def append(self, s: Array, p_e: Array, q: Quality) -> None:
        prev = self.t[-1] if len(self.t) else None
        seg = np.zeros(len(s), dtype=np.int64)
        tt = s if prev is None else np.concatenate(([prev], s))
        d = np.diff(tt)
        for gi in np.flatnonzero(d > self.p.robot_max_bridge_s):
            q.robot_gaps += 1
            q.gaps.append({"stream": "robot", "t": float(tt[gi]), "duration_s": float(d[gi])})
            seg[gi + (0 if prev is not None else 1) :] += 1
        nb = int(np.count_nonzero((d > 2.5 / 25.0) & (d <= self.p.robot_max_bridge_s)))
        q.robot_bridged_gaps += nb
        seg += self.seg
        if len(seg):
            self.seg = int(seg[-1])
        self.t = np.concatenate((self.t, s))
        self.segid = np.concatenate((self.segid, seg))
        self.p_e = np.concatenate((self.p_e, p_e))

    def interp(self, g: Array) -> tuple[Idx, Array]:
        n = len(self.t)
        if n < 2:
            return np.zeros(len(g), bool), np.full((len(g), 3), np.nan)
        i1 = np.clip(np.searchsorted(self.t, g, side="left"), 1, n - 1)
        i0 = i1 - 1
        ok = (g >= self.t[0]) & (g <= self.t[-1]) & (self.segid[i0] == self.segid[i1])
        w = np.clip((g - self.t[i0]) / (self.t[i1] - self.t[i0]), 0.0, 1.0)
        return ok, self.p_e[i0] + w[:, None] * (self.p_e[i1] - self.p_e[i0])

    def trim(self, t_keep: float) -> None:
        i = max(0, int(np.searchsorted(self.t, t_keep)) - 2)
        if i > 0:
            self.t, self.segid, self.p_e = self.t[i:], self.segid[i:], self.p_e[i:]
            self.base += i


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
        if not len(imu.t) or not len(robot.t):
            return
        if self.k_next is None:
            self.k_next = int(math.ceil(max(imu.t[0], robot.t[0]) / self.dt))
        k_end = int(math.floor(until / self.dt))
        if k_end < self.k_next:
            return
        g = np.arange(self.k_next, k_end + 1, dtype=np.float64) * self.dt
        self.k_next = k_end + 1
        if self.half > 0:
            ok_i, vu = imu.smooth(g, self.half)
        else:
            ok_i, vu = imu.interp_channels(g)
        segs = imu.segid[np.clip(np.searchsorted(imu.t, g), 0, len(imu.t) - 1)]
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
        self._imu_pending: list[tuple[Array, Array, Array]] = []
        self._robot_pending: list[tuple[Array, Array, Array, Array | None]] = []
        self._imu_frontier = -math.inf  # last IMU stamp fed
        self._robot_frontier = -math.inf
        # rows: robot samples in order; decided[i] = (with_imu, nominal_spec)
        self._row_t: list[float] = []
        self._n_decided = 0
        self._decisions: list[tuple[bool, int]] = []
        self._n_done = 0
        self._row_wrist: list[Array] = []
        self._row_pe: list[Array] = []
        self._row_xc: list[Array] = []
        # heading
        self._hstate = hd.HeadingState()
        self._hseg = 0
        self._t_update: float | None = None
        # heading after each update: t, delta, rate, t_update, std, converged, imu segment,
        # robot latency
        self._snaps = np.empty((0, 8))
        self._snap_t = np.empty(0)
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
        self._nom_point: Array | None = None
        self._nom_acc: list[Array] = []
        self._nom_t0: float | None = None
        self._ref_point: Array | None = None  # the last rope-measured point (for l_A)
        self._arm_len = p.upper_arm_length_m
        self._arm_spec = -1
        self._arm_spec_done = -1
        self._arm_pts: list[Array] = []
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
        self._xc_prev = np.zeros(3)

    # ------------------------------------------------------------------ feeding

    def feed(self, msg: Any) -> bool:
        """Take one decoded message (IMU, robot or event). Returns False if rejected."""
        if hasattr(msg, "gyr"):
            return self.feed_imu(
                msg.t,
                msg.gyr,
                msg.acc,
                getattr(msg, "seq", None),
                getattr(msg, "segment", "upperarm"),
            )
        if hasattr(msg, "proximal"):
            return self.feed_robot(
                msg.t,
                msg.wrist,
                msg.proximal,
                getattr(msg, "elbow", None),
                getattr(msg, "seq", None),
            )
        if hasattr(msg, "type") and hasattr(msg, "t"):
            return self.feed_event(float(msg.t), str(msg.type), getattr(msg, "point", None))
        # optional streams (camera) are valid but not used by the method: counted, not rejected
        self.quality.ignored[type(msg).__name__] = (
            self.quality.ignored.get(type(msg).__name__, 0) + 1
        )
        return False

    def feed_imu(
        self, t: Array, gyr: Array, acc: Array, seq: int | None = None, segment: str = "upperarm"
    ) -> bool:
        if segment != "upperarm":  # forearm/trunk IMUs are for later estimators
            self.quality.ignored[f"imu_{segment}"] = (
                self.quality.ignored.get(f"imu_{segment}", 0) + 1
            )
            return False
        if not self._imu_stream.admit(float(t[0]), seq, self.quality):
            return False
        self._imu_stream.last_t = float(t[-1])
        self._imu_pending.append((t, gyr, acc))
        self.quality.imu_samples += len(t)
        self._imu_frontier = float(t[-1])
        self._decide()
        return True

    def feed_robot(
        self,
        t: Array,
        wrist: Array,
        proximal: Array,
        elbow: Array | None = None,
        seq: int | None = None,
    ) -> bool:
        if not self._robot_stream.admit(float(t[0]), seq, self.quality):
            return False
        # pure Python: per-message numpy calls would cost more than the whole check
        if any(x * x + y * y + z * z <= 1e-12 for x, y, z in (wrist - proximal).tolist()):
            self.quality.reject("coincident_cuffs")
            return False
        self._robot_stream.last_t = float(t[-1])
        self._robot_pending.append((t, wrist, proximal, elbow))
        self._row_t.extend(t.tolist())
        self.quality.robot_samples += len(t)
        self._robot_frontier = float(t[-1])
        self._decide()
        return True

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
        """Mark robot samples ready: the IMU has reached them, or the robot ran ahead by
        ``imu_wait_s`` (then they are emitted without IMU-derived values)."""
        off = self.params.robot_time_offset_s
        wait = self.params.imu_wait_s
        n = len(self._row_t)
        i = self._n_decided
        spec = len(self._specs) - 1
        while i < n:
            tr = self._row_t[i]
            with_imu = self._imu_frontier >= tr - off
            if not with_imu and self._robot_frontier < tr + wait:
                break
            # the latest nominal spec (in feed order) whose time has come
            k = spec
            while k > 0 and self._specs[k][1] > tr:
                k -= 1
            self._decisions.append((with_imu, k))
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
        if self._imu_pending:
            pend, self._imu_pending = self._imu_pending, []
            self._imu.process(
                np.concatenate([c[0] for c in pend]),
                np.concatenate([c[1] for c in pend]),
                np.concatenate([c[2] for c in pend]),
                self.quality,
            )
        off = self.params.robot_time_offset_s
        if self._robot_pending:
            pend_r, self._robot_pending = self._robot_pending, []
            wrist = np.concatenate([c[1] for c in pend_r])
            p_e, x_c = kin.elbow_from_cuffs(
                wrist, np.concatenate([c[2] for c in pend_r]), self.params.cuff_to_elbow_m
            )
            if any(c[3] is not None for c in pend_r):  # a robot that knows the elbow itself
                given = [
                    c[3] if c[3] is not None else np.full((len(c[0]), 3), np.nan) for c in pend_r
                ]
                e = np.concatenate(given)
                p_e = np.where(np.isfinite(e), e, p_e)
            self._row_wrist.append(wrist)
            self._row_pe.append(p_e)
            self._row_xc.append(x_c)
            self._robot.append(np.concatenate([c[0] for c in pend_r]) - off, p_e, self.quality)
        # fusion grid as far as both streams reach (stamps fed so far)
        until = min(self._imu_frontier - self._grid.half, self._robot_frontier - off)
        # The grid only feeds heading updates: advance it (in one vectorised chunk, with the
        # same numbers as sample by sample) when the next update falls due.
        due = self._t_update is None or until >= self._t_update
        if self._imu.ts is not None and due:
            self._grid.advance(self._imu, self._robot, until)
        self._run_heading()
        out = self._rows()
        self._trim()
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
        if snaps:
            self._snaps = np.concatenate((self._snaps, np.array(snaps)))
            self._snap_t = self._snaps[:, 0]

    def _rows(self) -> Output:
        p = self.params
        lo, hi = self._n_done, self._n_decided
        out = Output()
        if hi <= lo:
            return out
        self._n_done = hi
        t = np.asarray(self._row_t[lo:hi])
        s = t - p.robot_time_offset_s
        dec = self._decisions[lo:hi]
        with_imu = np.array([d[0] for d in dec], dtype=bool)
        spec = np.array([d[1] for d in dec], dtype=np.int64)
        wrist, p_e, x_c = self._take_rows(hi - lo)
        n = len(t)
        # heading snapshot: the latest update the grid is sure to have reached by the time
        # this row became ready (two grid steps and the anti-alias half-width back)
        lag = 2.0 * self._grid.dt + self._grid.half + 1e-9
        si = np.searchsorted(self._snap_t, s - lag, side="right") - 1
        sn = self._snaps[np.maximum(si, 0)] if len(self._snaps) else np.full((n, 8), np.nan)
        sn = np.where((si >= 0)[:, None], sn, np.nan)
        # pair the robot sample with the IMU at the same physical instant (estimated latency;
        # a robot ahead of the IMU is not corrected, the IMU sample would not be here yet)
        latency = np.where(np.isfinite(sn[:, 7]), np.maximum(sn[:, 7], 0.0), 0.0)
        ok2, q2, seg2 = self._imu.interp(np.concatenate((s - latency, s)))
        ok, q_pair, seg = ok2[:n], q2[:n], seg2[:n]
        q_now = q2[n:]
        ok &= with_imu & ok2[n:] & (seg2[n:] == seg)
        use = ok & np.isfinite(sn[:, 1]) & (sn[:, 6] == seg)
        since = np.maximum(0.0, s - sn[:, 3])
        with np.errstate(invalid="ignore"):
            delta = np.where(use, sn[:, 1] + sn[:, 2] * (s - sn[:, 3]), np.nan)
            std = np.where(use, np.hypot(sn[:, 4], math.radians(0.1) * since), np.inf)
        conv = use & (sn[:, 5] > 0)
        good = ok & conv & np.isfinite(delta)
        q_ra = np.full((n, 4), np.nan)  # the upper arm now (eqs. 9–10)
        q_ra[good] = quat.mul(quat.about_z(delta[good]), q_now[good])
        x_now = quat.x_axis(q_ra)
        # ... and its axis when the robot measured the elbow: Rz(δ) q_IA e_x
        x_a = np.full((n, 3), np.nan)
        x_a[good] = quat.rotate_z(delta[good], quat.x_axis(q_pair[good]))
        angle = self._elbow_angle(t, x_now, x_a, x_c, latency)
        la = self._arm_lengths(t, p_e, spec)
        shoulder = kin.shoulder_position(p_e, x_a, la)
        nominal = self._nominal(t, shoulder, good, spec)
        disp = self._displacement(shoulder, nominal)
        conv_angle = np.full(n, np.nan)
        has_nom = np.all(np.isfinite(nominal), axis=1)
        if np.any(has_nom):
            _, conv_angle[has_nom] = kin.conventional(p_e[has_nom], x_c[has_nom], nominal[has_nom])
        self.quality.rows_without_imu += int(np.count_nonzero(~with_imu))
        # compensation rule (§3.4)
        # segment first: a completed cycle sets the tolerated duration from its end on
        boundaries = self._segmenter.update(t, wrist)
        codes, changes = self._indicator.update(t, disp, None, boundaries)
        verdicts = self._judge.update(t, codes, boundaries, disp)
        episodes = self._episodes.update(t, codes, disp)
        fb: list[dict[str, Any]] = [{"t": tc, "type": "state", "state": st} for tc, st in changes]
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
        std_deg = np.degrees(std)
        out.rows = {
            "t": t,
            "elbow": p_e,
            "shoulder": shoulder,
            "elbow_angle_deg": angle,
            "heading_offset_deg": np.where(
                np.isfinite(delta) & ok, np.degrees(np.mod(delta, 2 * np.pi)), np.nan
            ),
            "heading_converged": good,
            "shoulder_displacement_m": disp,
            "state": codes.astype(np.int8),
            "q_ra": q_ra,
            "heading_std_deg": np.where(np.isfinite(std_deg), std_deg, np.nan),
            "heading_confidence": np.where(
                np.isfinite(std_deg), 1.0 / (1.0 + (std_deg / 3.0) ** 2), 0.0
            ),
            "upper_arm_elevation_deg": np.degrees(np.arccos(np.clip(-x_now[:, 2], -1.0, 1.0))),
            "upper_arm_azimuth_deg": np.degrees(np.arctan2(x_now[:, 0], x_now[:, 1])),
            "nominal_shoulder": nominal,
            "conv_elbow_angle_deg": conv_angle,
            "wrist": wrist,
            "upper_arm_length_m": la,
        }
        out.feedback = fb
        out.cycles = list(verdicts)
        out.episodes = episodes
        return out

    def _elbow_angle(
        self, t: Array, x_now: Array, x_pair: Array, x_c: Array, latency: Array
    ) -> Array:
        """Elbow angle (eq. 11) at the row's time.

        The robot's forearm axis is ``latency`` old while the IMU's upper-arm axis is fresh;
        the forearm axis is carried forward along its last robot step (``extrapolate``)
        so both segments describe the same instant.
        """
        mode = self.params.elbow_angle_timing
        if mode == "paired":
            return kin.elbow_angle_deg(x_pair, x_c)
        prev_t = np.concatenate(([self._xc_prev_t], t[:-1]))
        prev = np.concatenate((self._xc_prev[None], x_c[:-1]))
        self._xc_prev_t, self._xc_prev = float(t[-1]), x_c[-1].copy()
        dt = t - prev_t
        if mode == "extrapolate":
            step = np.where((dt > 0) & (dt < 0.2), latency / np.where(dt > 0, dt, 1.0), 0.0)
            x_c = kin.unit(x_c + step[:, None] * (x_c - prev))
        return kin.elbow_angle_deg(x_now, x_c)

    def _take_rows(self, n: int) -> tuple[Array, Array, Array]:
        def take(buf: list[Array]) -> Array:
            arr = np.concatenate(buf) if len(buf) > 1 else buf[0]
            head, rest = arr[:n], arr[n:]
            buf.clear()
            if len(rest):
                buf.append(rest)
            return head

        return take(self._row_wrist), take(self._row_pe), take(self._row_xc)

    def _arm_lengths(self, t: Array, p_e: Array, spec: Idx) -> Array:
        """Upper-arm length per row: the parameter, or measured at the rope reference.

        While the therapist holds the rope end on the shoulder (``shoulder_reference``), the
        shoulder is at ``p_ref`` and the robot measures the elbow, so ``l_A = |p_E − p_ref|``
        (mean elbow over ``arm_reference_s`` after the event). This removes the constant
        offset an assumed length leaves in every shoulder estimate (eq. 12), without
        needing the heading. Out-of-bounds or moving-arm measurements are ignored.
        """
        p = self.params
        la = np.full(len(t), self._arm_len)
        if p.arm_length != "calibrate":
            return la
        for j0 in range(len(t)):
            k = int(spec[j0])
            kind, t_e, point = self._specs[k]
            if kind != "point" or point is None or k == self._arm_spec_done:
                continue
            if self._arm_spec != k:
                self._arm_spec, self._arm_pts = k, []
            if t[j0] <= t_e + p.arm_reference_s:
                self._arm_pts.append(p_e[j0])
                continue
            self._arm_spec_done = k
            pts = np.array(self._arm_pts)
            self._arm_pts = []
            if len(pts) >= 3 and float(np.max(np.std(pts, axis=0))) < 0.01:
                length = float(np.linalg.norm(pts.mean(axis=0) - point))
                lo_b, hi_b = p.arm_length_bounds_m
                if lo_b <= length <= hi_b:
                    self._arm_len = length
                    self.arm_length_estimate = length
                    la[j0:] = length
                    continue
            self.quality.reject("arm_reference_unusable")
        return la

    def _nominal(self, t: Array, shoulder: Array, good: Idx, spec: Idx) -> Array:
        """Nominal shoulder per row (contract §4): parameter, rope reference, or automatic
        (mean estimate over ``auto_nominal_s`` after convergence / after a reset event)."""
        n = len(t)
        nom = np.full((n, 3), np.nan)
        for j in range(n):
            k = int(spec[j])
            if k != self._nom_spec:
                self._nom_spec = k
                kind, _, point = self._specs[k]
                self._nom_point = point.copy() if point is not None else None
                self._nom_acc, self._nom_t0 = [], None
                if point is not None and kind == "point":
                    self._ref_point = point
            if self._nom_point is None and good[j]:
                if self._nom_t0 is None:
                    self._nom_t0 = float(t[j])
                self._nom_acc.append(shoulder[j])
                if t[j] - self._nom_t0 >= self.params.auto_nominal_s:
                    self._nom_point = np.mean(self._nom_acc, axis=0)
                    self._nom_acc = []
            if self._nom_point is not None:
                nom[j] = self._nom_point
        return nom

    def _displacement(self, shoulder: Array, nominal: Array) -> Array:
        d = shoulder - nominal
        if self.params.displacement_norm == "horizontal":
            out: Array = np.hypot(d[:, 0], d[:, 1])
            return out
        return np.linalg.norm(d, axis=1)  # type: ignore[no-any-return]

    def _trim(self) -> None:
        # keep what the next rows, grid points and heading windows can still need
        keep = (
            self._row_t[self._n_done] if self._n_done < len(self._row_t) else self._robot_frontier
        )
        keep = min(keep - self.params.robot_time_offset_s, self._grid.frontier) - 1.0
        if math.isfinite(keep):
            self._imu.trim(keep)
            self._robot.trim(keep)
        self._grid.trim(self._grid.frontier - max(self.hp.window_s, self.hp.fit_window_s) - 1.0)
        if self._n_done < len(self._row_t):
            s_next = self._row_t[self._n_done] - self.params.robot_time_offset_s
            cut = int(np.searchsorted(self._snap_t, s_next - 1.0, side="right")) - 2
            if cut > 0:
                self._snaps = self._snaps[cut:]
                self._snap_t = self._snaps[:, 0]
        # forget rows already emitted (indices stay consistent through the offset)
        if self._n_done > 4096:
            k = self._n_done
            del self._row_t[:k]
            del self._decisions[:k]
            self._n_decided -= k
            self._n_done = 0
