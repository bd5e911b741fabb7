"""Streaming wearable tracker: upper-arm, forearm and camera samples in, joint angles out.

Pure and driven by sample timestamps. The state is passed in and out (:class:`TrackerState`);
:func:`feed` takes one stream's samples (one message) and returns the rows it completed, one
per upper-arm IMU sample (contract §8). Feeding a recording message by message or in any
grouping gives the same rows as :func:`run` on all of it, because every decision depends only
on the order of the samples, never on how they were grouped.

Pairing: a forearm sample within ``forearm_tolerance_s`` of an upper-arm sample is used with
it; an upper-arm sample waits (in sample time) for its forearm partner at most
``forearm_missing_s``, then steps on without it (its forearm angles are left empty and
flagged). The newest camera sample at or before an upper-arm sample is used with it once
(a camera sample older than ``camera_max_age_s`` is rejected as stale).

Bad input is rejected and counted in ``state.rejected`` by reason; rows carry ``flags``
(bits below); angles that cannot be trusted are NaN (empty in joints.csv), never made up.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from estimators.wearable import dh, filters, kernel
from estimators.wearable.dh import F64
from estimators.wearable.model import DEG, Measurement, Model
from estimators.wearable.params import WearableParams, mirror_rates, mirror_vectors

FOREARM_MISSING = 1  # no forearm sample paired: elbow angles and wrist empty
CAMERA_USED = 2
CAMERA_STALE = 4
NOT_AT_REST = 8  # the start was not at rest: the zero-pose initialisation is doubtful
MOUNTING_MISMATCH = 16  # gravity at rest disagrees with the mounting: segment's angles empty
INCONSISTENT = 32  # innovations far larger than the noise model: the model does not fit
RESTARTED = 64  # the filter restarted after a gap
INITIALISING = 128  # inside the start's rest window

COLUMNS = (
    "t",
    "shoulder_flexion_deg",
    "shoulder_abduction_deg",
    "shoulder_rotation_deg",
    "elbow_flexion_deg",
    "forearm_pronation_deg",
    "elbow_x",
    "elbow_y",
    "elbow_z",
    "wrist_x",
    "wrist_y",
    "wrist_z",
)
STD_COLUMNS = (*(f"{c[:-4]}_std_deg" for c in COLUMNS[1:6]), "vertical_std_deg")
_NAN3 = np.full(3, np.nan)
Kind = Literal["upperarm", "forearm", "camera"]


@dataclass
class TrackerState:
    """Everything carried between calls (like scipy.signal's ``zi``)."""

    model: Model
    x: F64 | None = None
    P: F64 | None = None
    t_last: float = -math.inf  # last processed upper-arm sample
    t_seen: dict[str, float] = field(
        default_factory=lambda: {"upperarm": -math.inf, "forearm": -math.inf, "camera": -math.inf}
    )
    upper: deque[tuple[float, F64, F64]] = field(default_factory=deque)
    fore: deque[tuple[float, F64, F64]] = field(default_factory=deque)
    cam: deque[tuple[float, F64, F64]] = field(default_factory=deque)
    t_start: float = math.nan  # start of the current run (rest window)
    rest_acc_u: F64 = field(default_factory=lambda: np.zeros(3))
    rest_acc_f: F64 = field(default_factory=lambda: np.zeros(3))
    rest_n: int = 0
    rest_nf: int = 0
    rest_gyro_max: float = 0.0
    rest_checked: bool = False
    sticky: int = 0  # flags holding for the rest of the run
    nis: deque[float] = field(default_factory=deque)
    nis_sum: float = 0.0
    restarted: bool = False
    vertical_deg: float = 0.0  # drift bound of the turn about the vertical (params)
    rejected: Counter[str] = field(default_factory=Counter)
    steps: int = 0


def initial_state(params: WearableParams) -> TrackerState:
    return TrackerState(Model.build(params))


Rows = dict[str, F64]


def _empty_rows() -> dict[str, list[float]]:
    return {c: [] for c in (*COLUMNS, *STD_COLUMNS, "flags")}


def feed(
    params: WearableParams,
    state: TrackerState,
    kind: Kind,
    t: F64,
    u: F64,
    v: F64,
) -> tuple[Rows, TrackerState]:
    """Take one message: ``t`` (N,) s; IMU: ``u`` gyro (N,3) rad/s, ``v`` specific force (N,3)
    m/s² in the IMU frame; camera: ``u`` elbow, ``v`` wrist (N,3) m in S. Returns completed
    rows (columns :data:`COLUMNS`, :data:`STD_COLUMNS`, ``flags``) and the state."""
    out = _empty_rows()
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    u = np.asarray(u, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    if not (len(t) == len(u) == len(v)):
        state.rejected[f"shape_{kind}"] += 1
        return _as_arrays(out), state
    if params.side == "left":  # onto the virtual right arm (params.MIRROR)
        if kind == "camera":
            u, v = mirror_vectors(u), mirror_vectors(v)
        else:
            u, v = mirror_rates(u), mirror_vectors(v)
    buf = {"upperarm": state.upper, "forearm": state.fore, "camera": state.cam}[kind]
    # per-sample checks, vectorised over the message (each sample's verdict is its own)
    with np.errstate(invalid="ignore"):
        finite = (np.isfinite(t) & np.isfinite(u).all(axis=1) & np.isfinite(v).all(axis=1)).tolist()
        in_range = (
            [True] * len(t)
            if kind == "camera"
            else (
                (np.abs(u).max(axis=1, initial=0.0) <= params.max_gyro_rads)
                & (np.abs(v).max(axis=1, initial=0.0) <= params.max_acc_ms2)
            ).tolist()
        )
    ts_list = t.tolist()
    for i in range(len(t)):
        ti = ts_list[i]
        if not finite[i]:
            state.rejected[f"nonfinite_{kind}"] += 1
            continue
        if not in_range[i]:
            state.rejected[f"out_of_range_{kind}"] += 1  # beyond any body-worn IMU's range
            continue
        if ti <= state.t_seen[kind]:
            state.rejected[f"time_backwards_{kind}"] += 1
            continue
        state.t_seen[kind] = ti
        buf.append((ti, u[i].copy(), v[i].copy()))
        _drain(params, state, out, final=False)
    return _as_arrays(out), state


def flush(params: WearableParams, state: TrackerState) -> tuple[Rows, TrackerState]:
    """End of data: process the upper-arm samples still waiting for a forearm partner."""
    out = _empty_rows()
    _drain(params, state, out, final=True)
    return _as_arrays(out), state


def run(
    params: WearableParams,
    streams: list[tuple[Kind, F64, F64, F64]],
) -> tuple[Rows, TrackerState]:
    """Batch: all messages ``(kind, t, u, v)`` in arrival order, then :func:`flush`."""
    state = initial_state(params)
    parts: list[Rows] = []
    for kind, t, u, v in streams:
        rows, state = feed(params, state, kind, t, u, v)
        parts.append(rows)
    rows, state = flush(params, state)
    parts.append(rows)
    return concat(parts), state


def concat(parts: list[Rows]) -> Rows:
    keys = (*COLUMNS, *STD_COLUMNS, "flags")
    return {k: np.concatenate([p[k] for p in parts]) if parts else np.zeros(0) for k in keys}


def _as_arrays(out: dict[str, list[float]]) -> Rows:
    return {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}


def _drain(
    params: WearableParams, state: TrackerState, out: dict[str, list[float]], final: bool
) -> None:
    """Process every upper-arm sample whose forearm partner is settled."""
    model = state.model
    while state.upper:
        tu = state.upper[0][0]
        fore: tuple[float, F64, F64] | None = None
        if model.use_forearm:
            tol = params.forearm_tolerance_s
            while state.fore and state.fore[0][0] < tu - tol:
                state.fore.popleft()
                state.rejected["forearm_unpaired"] += 1
            if state.fore and state.fore[0][0] <= tu + tol:
                fore = state.fore.popleft()
            elif not state.fore and not final:
                # nothing from the forearm at or after tu yet: wait, unless it is missing
                waited = state.t_seen["upperarm"] - max(tu, state.t_seen["forearm"])
                if state.t_seen["forearm"] < tu - tol and waited < params.forearm_missing_s:
                    return
        _, gu, au = state.upper.popleft()
        _step(params, state, tu, gu, au, fore, out)


def _restart(params: WearableParams, state: TrackerState, t: float) -> None:
    state.x, state.P = state.model.initial()
    state.t_start = t
    state.rest_acc_u = np.zeros(3)
    state.rest_acc_f = np.zeros(3)
    state.rest_n = state.rest_nf = 0
    state.rest_gyro_max = 0.0
    state.rest_checked = False
    state.sticky = 0
    state.nis.clear()
    state.nis_sum = 0.0
    state.vertical_deg = params.init_sigma_deg


def _camera(
    params: WearableParams, state: TrackerState, t: float
) -> tuple[F64 | None, F64 | None, int]:
    """The newest camera sample at or before ``t`` (used once), and flags."""
    best: tuple[float, F64, F64] | None = None
    stale = 0
    while state.cam and state.cam[0][0] <= t:
        c = state.cam.popleft()
        if t - c[0] > params.camera_max_age_s:
            state.rejected["camera_stale"] += 1
            stale = CAMERA_STALE
            continue
        if best is not None:
            state.rejected["camera_superseded"] += 1
        best = c
    if best is None or not params.camera:
        return None, None, stale
    return best[1], best[2], CAMERA_USED


def _step(
    params: WearableParams,
    state: TrackerState,
    t: float,
    gyr_u: F64,
    acc_u: F64,
    fore: tuple[float, F64, F64] | None,
    out: dict[str, list[float]],
) -> None:
    model = state.model
    flags = 0
    if state.x is None or t - state.t_last > params.max_gap_s:
        if state.x is not None:
            state.rejected["gap_restart"] += 1
            state.restarted = True
        _restart(params, state, t)
        ts = 0.0
    else:
        ts = t - state.t_last
    if state.restarted:
        flags |= RESTARTED
    state.t_last = t
    elbow_c, wrist_c, cflags = _camera(params, state, t)
    flags |= cflags
    gyr_f = acc_f = None
    if fore is not None:
        gyr_f, acc_f = fore[1], fore[2]
    elif model.use_forearm:
        flags |= FOREARM_MISSING
        state.rejected["forearm_missing"] += 1
    assert state.x is not None and state.P is not None
    x, P = state.x, state.P
    m = Measurement(gyr_u, acc_u, gyr_f, acc_f, elbow_c, wrist_c)
    x, P, nis = filters.step(params.filter, model, x, P, ts, m)
    state.x, state.P = x, P
    state.steps += 1
    state.vertical_deg += params.vertical_drift_dps * ts
    if elbow_c is not None:
        reach = max(
            float(np.hypot(*elbow_c[:2])),
            float(np.hypot(*wrist_c[:2])) if wrist_c is not None else 0.0,
        )
        if reach >= params.camera_fix_reach_m:
            fix = math.degrees(params.sigma_pos_m / reach)
            state.vertical_deg = min(state.vertical_deg, fix)
    _monitor(params, state, t, m, nis)
    flags |= state.sticky
    if t - state.t_start < params.rest_s:
        flags |= INITIALISING
    _emit(params, state, t, flags, out)


def _monitor(
    params: WearableParams, state: TrackerState, t: float, m: Measurement, nis: float
) -> None:
    """The start's rest and mounting check (contract §8 "Start") and the innovation monitor."""
    if not state.rest_checked:
        if t - state.t_start < params.rest_s:
            state.rest_acc_u += m.acc_u
            state.rest_n += 1
            g = float(np.linalg.norm(m.gyr_u))
            if m.acc_f is not None and m.gyr_f is not None:
                state.rest_acc_f += m.acc_f
                state.rest_nf += 1
                g = max(g, float(np.linalg.norm(m.gyr_f)))
            state.rest_gyro_max = max(state.rest_gyro_max, g)
        else:
            _check_rest(params, state)
    state.nis.append(nis)
    state.nis_sum += nis
    if len(state.nis) > params.nis_window:
        state.nis_sum -= state.nis.popleft()
    if len(state.nis) == params.nis_window and state.nis_sum / params.nis_window > params.nis_limit:
        if not state.sticky & INCONSISTENT:
            state.rejected["inconsistent_model"] += 1
        state.sticky |= INCONSISTENT
    else:
        state.sticky &= ~INCONSISTENT


def _check_rest(params: WearableParams, state: TrackerState) -> None:
    state.rest_checked = True
    if state.rest_gyro_max > params.rest_gyro_dps * DEG:
        state.rejected["start_not_at_rest"] += 1
        state.sticky |= NOT_AT_REST
        return  # the accelerometers moved too: no mounting verdict from them
    geo = state.model.geo
    zero = dh.pose(np.zeros(5), geo.upper_arm_m, geo.forearm_m)
    up = np.array([0.0, 0.0, 1.0])
    checks = [(state.rest_acc_u, state.rest_n, zero.R_SU @ geo.R_UI, "upperarm")]
    if state.rest_nf:
        checks.append((state.rest_acc_f, state.rest_nf, zero.R_SF @ geo.R_FI, "forearm"))
    for acc, n, r_si, name in checks:
        mean = acc / max(n, 1)
        expect = up @ r_si
        cos = float(mean @ expect) / max(float(np.linalg.norm(mean)), 1e-9)
        if math.degrees(math.acos(max(-1.0, min(1.0, cos)))) > params.mounting_tolerance_deg:
            state.rejected[f"mounting_mismatch_{name}"] += 1
            state.sticky |= MOUNTING_MISMATCH


def _emit(
    params: WearableParams, state: TrackerState, t: float, flags: int, out: dict[str, list[float]]
) -> None:
    model = state.model
    assert state.x is not None and state.P is not None
    o = kernel.emit(state.x, state.P, *model.packed, math.radians(state.vertical_deg))
    # the whole arm's turn about the vertical (unobservable without a camera, carried by the
    # gyros alone, contract §8 "Start"): the EKF's σ of it and the drift bound
    vert = math.hypot(float(o[16]), state.vertical_deg)
    elbow, wrist = o[10:13], o[13:16]
    if params.side == "left":
        elbow, wrist = mirror_vectors(elbow), mirror_vectors(wrist)
    deg = o[0:5]
    sdeg = o[5:10]
    if not model.use_forearm or flags & FOREARM_MISSING:
        deg[3:] = np.nan
        sdeg[3:] = np.nan
        wrist = _NAN3
    if flags & MOUNTING_MISMATCH:
        deg[:] = np.nan
        sdeg[:] = np.nan
        elbow = wrist = _NAN3
    vals = (t, *deg.tolist(), *elbow.tolist(), *wrist.tolist())
    for c, val in zip(COLUMNS, vals, strict=True):
        out[c].append(val)
    for c, val in zip(STD_COLUMNS, (*sdeg.tolist(), vert), strict=True):
        out[c].append(val)
    out["flags"].append(float(flags))
