"""The fusion grid's fast paths against the plain code they replace (kept here as oracles):
the same bits in every output, for both methods, with and without the anti-alias kernel and
the high-pass, across IMU resets and robot gaps, advanced in one step or as data arrives."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import sparse

from backend import wire
from estimators import grid_stage, imu_stage
from estimators import kinematics as kin
from estimators import quaternion as quat
from estimators.filters import LowPass, dc_group_delay_s
from estimators.grid_stage import GridStage
from estimators.imu_stage import ImuStage
from estimators.output import Quality
from estimators.params import PipelineParams
from estimators.robot_stage import RobotStage
from tests.conftest import Session

NCH = 18


# ---------------------------------------------------------------- the plain code (oracles)


def _ref_channels(imu: ImuStage, lo: int, hi: int) -> np.ndarray:
    rows = imu.buf.view()[lo:hi]
    if imu.p.method == "paper":
        v = rows[:, imu.V : imu.V + 3]
        return np.concatenate((v, np.zeros((len(v), 12))), axis=1)
    c = quat.matrix_columns(rows[:, imu.QS : imu.QS + 4])
    acc, r = rows[:, imu.ACC : imu.ACC + 3], imu.r
    cx, cy, cz = c[:, 0:3], c[:, 3:6], c[:, 6:9]
    v = cx * acc[:, 0:1] + cy * acc[:, 1:2] + cz * acc[:, 2:3] - kin.GRAVITY
    u = cx * r[0] + cy * r[1] + cz * r[2]
    return np.concatenate((v, u, c), axis=1)


def _ref_smooth(imu: ImuStage, g: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    t, segid = np.ascontiguousarray(imu.t), imu.segid
    n, ng = len(t), len(g)
    ts = imu.ts or 0.01
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
    x = _ref_channels(imu, base, int(lo.max()) + m)
    kernel = sparse.csr_matrix(
        (w.ravel(), (idx - base).ravel(), np.arange(0, ng * m + 1, m)), shape=(ng, len(x))
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.asarray(kernel @ x) / wsum[:, None]
    return ok, out


def _ref_interp_channels(imu: ImuStage, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if len(imu.tl) < 2:
        return np.zeros(len(s), bool), np.full((len(s), 15), np.nan)
    t, segid = np.ascontiguousarray(imu.t), imu.segid
    n = len(t)
    i1 = np.searchsorted(t, s, side="left")
    i1c = np.clip(i1, 1, max(n - 1, 1))
    i0 = i1c - 1
    ok = (i1 > 0) & (i1 < n) & (segid[i0] == segid[i1c])
    w = np.clip((s - t[i0]) / (t[i1c] - t[i0]), 0.0, 1.0)
    base = int(i0.min()) if len(i0) else 0
    x = _ref_channels(imu, base, int(i1c.max()) + 1 if len(i1c) else 0)
    x0, x1 = x[i0 - base], x[i1c - base]
    return ok, x0 + w[:, None] * (x1 - x0)


class _RefGrid:
    """GridStage as it was before its fast paths (session 9)."""

    def __init__(self, p: PipelineParams) -> None:
        self.p = p
        self.dt = 1.0 / p.fusion_rate_hz
        self.half = 2.0 * self.dt if p.use_antialias else 0.0
        self.lp = LowPass(p.lowpass_order, p.lowpass_cutoff_hz, p.fusion_rate_hz)
        self.hp = LowPass(2, p.highpass, p.fusion_rate_hz, "highpass") if p.highpass > 0 else None
        self.hp_zi: np.ndarray | None = None
        tilt_hz = 1.0 / (2.0 * math.pi * p.vqf_tau_acc_s)
        self.tilt = LowPass(1, tilt_hz, p.fusion_rate_hz, "highpass")
        self.tilt_zi: np.ndarray | None = None
        self.lag = dc_group_delay_s(p.lowpass_order, p.lowpass_cutoff_hz, p.fusion_rate_hz)
        self.settle = int(math.ceil(3.0 * self.lag * p.fusion_rate_hz))
        self.k_next: int | None = None
        self.zi: np.ndarray | None = None
        self.hist_y = np.empty((0, NCH))
        self.hist_x = np.empty((0, NCH))
        self.hist_g = np.empty(0)
        self.since = 0
        self.imu_seg = -1
        self.t = np.empty(0)
        self.a = np.empty((0, 3))
        self.b = np.empty((0, 3))
        self.pos = np.empty((0, 3))
        self.valid = np.empty(0, dtype=bool)
        self.seg = np.empty(0, dtype=np.int64)
        self.cl = np.empty((0, 18))

    def advance(self, imu: ImuStage, robot: RobotStage, until: float) -> None:
        if not imu.tl or not robot.tl:
            return
        if self.k_next is None:
            self.k_next = int(math.ceil(max(imu.tl[0], robot.tl[0]) / self.dt))
        k_end = int(math.floor(until / self.dt))
        if k_end * self.dt > until:
            k_end -= 1
        if k_end < self.k_next:
            return
        g = np.arange(self.k_next, k_end + 1, dtype=np.float64) * self.dt
        self.k_next = k_end + 1
        if self.half > 0:
            ok_i, vu = _ref_smooth(imu, g, self.half)
        else:
            ok_i, vu = _ref_interp_channels(imu, g)
        segs = imu.segid[np.clip(np.searchsorted(imu.t, g), 0, len(imu.tl) - 1)]
        ok_r, p = robot.interp(g)
        ok = ok_i & ok_r
        x = np.concatenate((vu, p), axis=1)
        parts = []
        brk = np.flatnonzero(np.diff(ok.astype(np.int8)) != 0) + 1
        seg_brk = np.flatnonzero(np.diff(segs) != 0) + 1
        bounds = np.unique(np.concatenate(([0], brk, seg_brk, [len(g)])))
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
            if not ok[lo]:
                self.zi = None
                continue
            xs = x[lo:hi]
            if self.zi is None or int(segs[lo]) != self.imu_seg:
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
                d2 = (yy[2:] - 2.0 * yy[1:-1] + yy[:-2]) / (self.dt * self.dt)
                m = len(d2)
                since = self.since + np.arange(1, m + 1)
                ab = np.concatenate(
                    (yy[1:-1, 0:3] + d2[:, 3:6], d2[:, 15:18], yy[1:-1, 6:15], d2[:, 6:15]), axis=1
                )
                if self.tilt is not None:
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

    def trim(self, t_keep: float) -> None:
        i = int(np.searchsorted(self.t, t_keep))
        if i > 0:
            self.t, self.a, self.b = self.t[i:], self.a[i:], self.b[i:]
            self.pos, self.valid, self.seg = self.pos[i:], self.valid[i:], self.seg[i:]
            self.cl = self.cl[i:]


# ---------------------------------------------------------------- comparisons

_PARAMS = {
    "improved": PipelineParams(),
    "paper": PipelineParams(method="paper"),
    "improved-plain": PipelineParams(antialias=False, highpass_hz=0.0),
    "paper-antialias": PipelineParams(method="paper", antialias=True, highpass_hz=0.1),
}


def _messages(session: Session, drop: str) -> list[wire.Message]:
    out = []
    for m in session.messages:
        if not isinstance(m, (wire.ImuMessage, wire.RobotMessage)) or m.t[0] >= 70.0:
            continue
        t0 = float(m.t[0])
        if drop == "imu" and isinstance(m, wire.ImuMessage) and 30.0 <= t0 < 33.0:
            continue  # a reset: a second IMU segment
        if drop == "imu-short" and isinstance(m, wire.ImuMessage) and 30.0 <= t0 < 30.08:
            continue  # a bridged gap
        if drop == "robot" and isinstance(m, wire.RobotMessage) and 30.0 <= t0 < 32.0:
            continue
        out.append(m)
    return out


def _arrays(g: GridStage | _RefGrid) -> list[np.ndarray]:
    return [g.t, g.a, g.b, g.pos, g.valid, g.seg, g.cl]


def _same(new: GridStage, ref: _RefGrid) -> None:
    for x, y in zip(_arrays(new), _arrays(ref), strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()
    assert new.frontier == (float(ref.t[-1]) if len(ref.t) else -math.inf)


@pytest.mark.parametrize("name", list(_PARAMS))
@pytest.mark.parametrize("drop", ["none", "imu", "imu-short", "robot"])
def test_grid_is_the_plain_codes(short_session: Session, name: str, drop: str) -> None:
    """Advanced after every robot message (the live schedule, with the pipeline's trim every
    second), and in one step: the plain code's bits."""
    p = _PARAMS[name]
    imu, robot, q = ImuStage(p), RobotStage(p), Quality()
    new, ref = GridStage(p), _RefGrid(p)
    for i, m in enumerate(_messages(short_session, drop)):
        if isinstance(m, wire.ImuMessage):
            imu.process(m.t, m.gyr, m.acc, q)
        else:
            robot.append(m.t.tolist(), m.elbow if m.elbow is not None else m.wrist, q)
            until = min(imu.tl[-1] - new.half, robot.tl[-1]) if imu.tl else -math.inf
            if i % 7 == 0 or i % 11 == 0:  # irregular steps, some of one grid point or none
                new.advance(imu, robot, until)
                ref.advance(imu, robot, until)
                _same(new, ref)
            if i % 97 == 0 and len(ref.t):
                keep = float(ref.t[-1]) - 20.0
                new.trim(keep)
                ref.trim(keep)
                _same(new, ref)
    one = GridStage(p)
    one.advance(imu, robot, robot.tl[-1])
    ref.advance(imu, robot, robot.tl[-1])
    new.advance(imu, robot, robot.tl[-1])
    _same(new, ref)
    one_ref = _RefGrid(p)
    one_ref.advance(imu, robot, robot.tl[-1])
    _same(one, one_ref)


def test_smooth_without_the_compiled_product_is_the_same(
    short_session: Session, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The public sparse product (a scipy without ``_sparsetools.csr_matvecs``) gives the bits
    of the direct call."""
    p = PipelineParams()
    imu, q = ImuStage(p), Quality()
    for m in _messages(short_session, "imu"):
        if isinstance(m, wire.ImuMessage):
            imu.process(m.t, m.gyr, m.acc, q)
    g = np.arange(500, 1500) * 0.04
    fast = imu.smooth(g, 0.08)
    monkeypatch.setattr(imu_stage, "csr_matvecs", None)
    slow = imu.smooth(g, 0.08)
    ref = _ref_smooth(imu, g, 0.08)
    for x, y, z in zip(fast, slow, ref, strict=True):
        assert x.tobytes() == y.tobytes() == z.tobytes()
    assert not fast[0].all() and fast[0].any()  # the reset at 30 s: both kinds of samples


@pytest.mark.parametrize("drop", ["none", "imu"])
def test_grid_without_the_compiled_filter_is_the_same(
    short_session: Session, drop: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The public filter call (a scipy without ``_sosfilt``) gives the grid the same bits."""
    p = PipelineParams()
    imu, robot, q = ImuStage(p), RobotStage(p), Quality()
    fast, ref = GridStage(p), _RefGrid(p)
    for m in _messages(short_session, drop):
        if isinstance(m, wire.ImuMessage):
            imu.process(m.t, m.gyr, m.acc, q)
        else:
            robot.append(m.t.tolist(), m.elbow if m.elbow is not None else m.wrist, q)
    until = robot.tl[-1]
    fast.advance(imu, robot, until / 2)
    monkeypatch.setattr(grid_stage, "_sosfilt", None)
    slow = GridStage(p)
    slow.advance(imu, robot, until / 2)
    _same(slow, fast)
    slow.advance(imu, robot, until)
    ref.advance(imu, robot, until)
    _same(slow, ref)
