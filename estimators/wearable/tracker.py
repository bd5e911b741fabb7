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
from collections import Counter
from dataclasses import dataclass, field
from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray

from estimators.wearable import dh, filters, kernel, steps
from estimators.wearable.dh import F64, I64
from estimators.wearable.model import DEG, Measurement, Model, wants_camera_offsets
from estimators.wearable.params import WearableParams, mirror_rates, mirror_vectors

# row flags (bits; the compiled steps set them: :mod:`.steps`)
FOREARM_MISSING = steps.FOREARM_MISSING  # no forearm sample paired: elbow angles, wrist empty
CAMERA_USED = steps.CAMERA_USED
CAMERA_STALE = steps.CAMERA_STALE
NOT_AT_REST = steps.NOT_AT_REST  # the start was not at rest: the zero-pose start is doubtful
MOUNTING_MISMATCH = steps.MOUNTING_MISMATCH  # gravity at rest disagrees with the mounting
INCONSISTENT = steps.INCONSISTENT  # innovations far larger than the noise model
RESTARTED = steps.RESTARTED  # the filter restarted after a gap
INITIALISING = steps.INITIALISING  # inside the start's rest window

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
    tp: F64  # the tracker's parameters for :mod:`.steps`
    have: NDArray[np.bool_]  # (8, 6) the slots a step measures by what it has (steps.HAVE_*)
    x: F64  # the filter's state and covariance (x0, P0 until the first step)
    P: F64
    x0: F64  # the start's (the zero pose at rest, contract §8 "Start")
    P0: F64
    mon: F64  # the run's bookkeeping (:mod:`.steps`' layout)
    nis_buf: F64
    counts: I64
    # the newest sample time seen per stream, and the samples waiting for their partners
    # (:func:`.steps.pair`'s queues)
    t_seen: F64 = field(default_factory=lambda: np.full(3, -math.inf))
    bufs: list[F64] = field(default_factory=lambda: [np.empty((64, 7)) for _ in range(3)])
    ptr: I64 = field(default_factory=lambda: np.zeros(6, dtype=np.intp))
    rejected: Counter[str] = field(default_factory=Counter)
    # the σ's doubt after a large shoulder rotation (:func:`.steps.widen`): the first row's
    # time and the running peak of log(g) + (t − t_first)/τ; then :func:`.steps.unobserved`'s
    # bounds (axial, drift), the previous row's t, θ0, θ1 and pronation's axial
    doubt: F64 = field(
        default_factory=lambda: np.array([math.nan, -math.inf, 0.0, 0.0, *[math.nan] * 3, 0.0])
    )
    # the σ's terms: floor², share², doubt², (3, 5), and its scalar settings (7,)
    # (:func:`.steps.widen`, ``steps.K_*``)
    widen: F64 = field(default_factory=lambda: np.zeros((3, 5)))
    knobs: F64 = field(default_factory=lambda: np.zeros(7))

    @property
    def steps(self) -> int:
        return int(self.mon[steps.M_STEPS])


def initial_state(params: WearableParams) -> TrackerState:
    model = Model.build(params, camera_offsets=False)  # until a camera message comes
    geo = model.geo
    zero = dh.pose(np.zeros(5), geo.upper_arm_m, geo.forearm_m)
    tp = np.zeros(steps.T_SIZE)
    tp[steps.T_MAX_GAP] = params.max_gap_s
    tp[steps.T_REST_S] = params.rest_s
    tp[steps.T_DRIFT] = params.vertical_drift_dps
    tp[steps.T_INIT_SIGMA] = params.init_sigma_deg
    tp[steps.T_VERT_INIT] = params.vertical_init_deg
    tp[steps.T_REST_GYRO] = params.rest_gyro_dps * DEG
    tp[steps.T_MOUNT_TOL] = params.mounting_tolerance_deg
    tp[steps.T_NIS_WINDOW] = params.nis_window
    tp[steps.T_NIS_LIMIT] = params.nis_limit
    tp[steps.T_LEFT] = params.side == "left"
    tp[steps.T_FOREARM] = model.use_forearm
    # "up" in each IMU's frame at the zero pose (what gravity reads at the start's rest)
    tp[steps.T_UP_U : steps.T_UP_U + 3] = (zero.R_SU @ geo.R_UI)[2]
    tp[steps.T_UP_F : steps.T_UP_F + 3] = (zero.R_SF @ geo.R_FI)[2]
    tp[steps.T_TOL] = params.forearm_tolerance_s
    tp[steps.T_MISSING] = params.forearm_missing_s
    tp[steps.T_CAM_AGE] = params.camera_max_age_s
    tp[steps.T_CAMERA] = params.camera
    tp[steps.T_FIX_REACH] = params.camera_fix_reach_m
    tp[steps.T_SIGMA_POS] = params.sigma_pos_m
    tp[steps.T_MAX_GYRO] = params.max_gyro_rads
    tp[steps.T_MAX_ACC] = params.max_acc_ms2
    tp[steps.T_MOUNT_GAIN] = params.sigma_mounting_gain
    tp[steps.T_CAM_HOLD] = params.camera_hold_s
    tp[steps.T_CHANGE_GAIN] = params.sigma_mounting_change_gain
    tp[steps.T_CHANGE_U] = params.sigma_upper_change_gain
    tp[steps.T_CHANGE_TAU] = params.mounting_change_tau_s
    tp[steps.T_SPLIT] = params.sigma_elbow_split_deg
    tp[steps.T_SPLIT_TAU] = params.elbow_split_tau_s
    tp[steps.T_DIS_GAIN] = params.sigma_camera_disagree_gain
    tp[steps.T_DIS_TAU] = params.camera_disagree_tau_s
    tp[steps.T_OFF_TAU] = params.camera_offset_tau_s
    tp[steps.T_DROP_SHARE] = params.sigma_dropout_share
    tp[steps.T_DROP_CAP] = params.sigma_dropout_cap_deg
    tp[steps.T_MU_IDX : steps.T_MU_IDX + 3] = -1
    tp[steps.T_MU_IDX : steps.T_MU_IDX + model.i_mu.size] = model.i_mu
    pairs, signs = _mounting_pairs(model, zero)
    tp[steps.T_MOUNT_IDX : steps.T_MOUNT_IDX + 10] = pairs.ravel()
    tp[steps.T_MOUNT_SIGN : steps.T_MOUNT_SIGN + 10] = signs.ravel()
    # the slots a step measures, by what was paired with it (steps.HAVE_* bits)
    bits = np.arange(8)
    have = model.measured(
        (bits & steps.HAVE_FOREARM) > 0,
        (bits & steps.HAVE_ELBOW) > 0,
        (bits & steps.HAVE_WRIST) > 0,
    )
    x0, P0 = model.initial()
    mon, nis_buf, counts = steps.new_state(params.nis_window)
    state = TrackerState(model, tp, have, x0, P0, x0, P0, mon, nis_buf, counts)
    terms = (params.sigma_floor_deg, params.sigma_share, params.sigma_doubt)
    state.widen = np.square(np.array(terms, dtype=np.float64)).reshape(3, 5)
    state.knobs = np.array(  # in steps.K_* order
        [
            params.sigma_pronation_vertical_deg,
            params.doubt_rotation_deg,
            params.doubt_tau_s,
            params.sigma_axial_share,
            params.axial_tau_s,
            params.pronation_drift_dps,
            params.pronation_axial_tau_s,
        ]
    )
    return state


def _mounting_pairs(model: Model, zero: dh.Pose) -> tuple[NDArray[np.intp], F64]:
    """(2, 5) the mounting state turning each IMU about each angle's axis at the zero pose
    (the upper arm's about shoulder flexion's and abduction's, both IMUs' about the elbow's;
    −1: none): the state whose direction is nearest that axis, for any mounting; and (2, 5)
    the sign its departure takes in the angle's error. An IMU's turn about an angle's axis
    reads as the angle turned back, the forearm IMU's as the elbow's, the upper arm's as the
    whole chain's, the elbow's forth: the elbow's error is the upper arm's turn minus the
    forearm's, both about its axis."""
    pairs = np.full((2, 5), -1, dtype=np.intp)
    signs = np.zeros((2, 5))
    for r, (idx, slot, R_seg, R_xi, joints) in enumerate(
        (
            (model.i_mu, kernel.GYR_U, zero.R_SU, model.geo.R_UI, (0, 1, 3)),
            (model.i_mf, kernel.GYR_F, zero.R_SF, model.geo.R_FI, (3,)),
        )
    ):
        if not idx.size:
            continue
        dirs = R_seg @ R_xi @ model.mis_basis[slot][:, : idx.size]  # the states' axes in S
        for j in joints:
            proj = zero.axes[j] @ dirs
            c = int(np.argmax(np.abs(proj)))
            pairs[r, j] = idx[c]
            signs[r, j] = np.sign(proj[c]) * (-1.0 if r == 1 else 1.0)
    return pairs, signs


Rows = dict[str, F64]


_KIND = {"upperarm": steps.K_UPPER, "forearm": steps.K_FORE, "camera": steps.K_CAMERA}


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
    return block_rows(feed_block(params, state, kind, t, u, v)), state


def feed_block(
    params: WearableParams, state: TrackerState, kind: Kind, t: F64, u: F64, v: F64
) -> F64:
    """:func:`feed` (the state updated in place) returning its rows as one (19, N) block
    (:func:`block_rows` makes them rows): a caller that keeps many messages' rows joins the
    blocks once instead of building a dict of 19 views per message."""
    t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
    u = np.ascontiguousarray(u, dtype=np.float64).reshape(-1, 3)
    v = np.ascontiguousarray(v, dtype=np.float64).reshape(-1, 3)
    if not (len(t) == len(u) == len(v)):
        state.rejected[f"shape_{kind}"] += 1
        t, u, v = t[:0], u[:0], v[:0]
    if kind == "camera" and len(t) and not state.model.i_cam.size and wants_camera_offsets(params):
        add_camera_offsets(params, state)
    if params.side == "left":  # onto the virtual right arm (params.MIRROR)
        if kind == "camera":
            u, v = mirror_vectors(u), mirror_vectors(v)
        else:
            u, v = mirror_rates(u), mirror_vectors(v)
    return _run(params, state, _KIND[kind], t, u, v, final=False)


def add_camera_offsets(params: WearableParams, state: TrackerState) -> None:
    """The camera's offset states join the filter with its first message (a camera-less
    session never carries them: 6 of 39 states, ~0.15 s of an 8-minute analysis). Until a
    camera row they are independent of every other state (a prior of their own, no process
    coupling or walk), so adding them then is the filter that had them from the start."""
    model = Model.build(params)
    n = state.model.n
    x_new, P_new = model.initial()  # the new states' prior: the tail (they come last)

    def grow(x: F64, P: F64) -> tuple[F64, F64]:
        Pn = P_new.copy()
        Pn[:n, :n] = P  # (P_new is diagonal: no cross terms to clear)
        return np.concatenate((x, x_new[n:])), Pn

    state.x, state.P = grow(state.x, state.P)
    state.x0, state.P0 = grow(state.x0, state.P0)
    state.model = model


def flush(params: WearableParams, state: TrackerState) -> tuple[Rows, TrackerState]:
    """End of data: process the upper-arm samples still waiting for a forearm partner."""
    return block_rows(flush_block(params, state)), state


def flush_block(params: WearableParams, state: TrackerState) -> F64:
    """:func:`flush` returning the rows as one (19, N) block."""
    empty = np.zeros((0, 3))
    return _run(params, state, steps.K_UPPER, np.zeros(0), empty, empty, final=True)


def run(
    params: WearableParams,
    streams: list[tuple[Kind, F64, F64, F64]],
) -> tuple[Rows, TrackerState]:
    """Batch: all messages ``(kind, t, u, v)`` in arrival order, then :func:`flush`."""
    state = initial_state(params)
    blocks = [feed_block(params, state, kind, t, u, v) for kind, t, u, v in streams]
    blocks.append(flush_block(params, state))
    return block_rows(join_blocks(blocks)), state


class _Block(dict[str, F64]):
    """Rows as the views of one (19, N) block (:func:`_run`'s ``out``): :func:`concat` joins
    the blocks in one call instead of each column's thousands of pieces."""

    block: F64


def block_rows(out: F64) -> Rows:
    """The rows of a (19, N) block (:func:`feed_block`): each column a view of it."""
    rows = _Block(zip(ROW_KEYS, out, strict=True))
    rows.block = out
    return rows


def join_blocks(blocks: list[F64]) -> F64:
    """Messages' (19, N) blocks as one (the one itself when there is one)."""
    if len(blocks) == 1:
        return blocks[0]
    return np.concatenate(blocks, axis=1) if blocks else np.zeros((len(ROW_KEYS), 0))


def concat(parts: list[Rows]) -> Rows:
    if parts and all(isinstance(p, _Block) for p in parts):
        return block_rows(join_blocks([p.block for p in parts]))  # type: ignore[attr-defined]
    return {k: np.concatenate([p[k] for p in parts]) if parts else np.zeros(0) for k in ROW_KEYS}


def _run(
    params: WearableParams, state: TrackerState, kind: int, t: F64, u: F64, v: F64, final: bool
) -> F64:
    """A message's samples (stream ``kind``) paired (:func:`.steps.pair`) and the filter's
    steps of the pairs, compiled with the EKF (:func:`.steps.feed`); returns their rows'
    (19, N) block."""
    buf, head, size = state.bufs[kind], int(state.ptr[2 * kind]), int(state.ptr[2 * kind + 1])
    if head + size + len(t) > len(buf):  # room for the message in the stream's queue
        new = buf if size + len(t) <= len(buf) else np.empty((2 * (size + len(t)), 7))
        new[:size] = buf[head : head + size]
        state.bufs[kind] = new
        state.ptr[2 * kind] = 0
    upper, fore, cam = state.bufs
    model = state.model
    ia, fa = model.packed
    x0, P0 = state.x0, state.P0
    if params.filter == "ekf":  # with the σ's widening (one call per message)
        state.x, state.P, out = steps.feed(
            kind, t, u, v, final, upper, fore, cam, state.ptr, state.t_seen, state.x, state.P,
            state.mon, state.nis_buf, state.tp, state.counts, state.have, ia, fa, x0, P0,
            model.mis_idx, model.mis_basis, state.widen, state.doubt, state.knobs,
        )  # fmt: skip
    else:  # the UKF's update in Python between the same bookkeeping
        t, z, avail, flags, fix = steps.pair(
            kind, t, u, v, upper, fore, cam, state.ptr, state.t_seen, state.tp, state.counts, final
        )
        out = np.empty((19, len(t)))
        x, P = state.x, state.P
        for k in range(len(t)):
            x, P, ts = steps.begin(x, P, state.mon, state.tp, state.counts, t[k], x0, P0)
            zk, ak = z[k], int(avail[k])
            fore_k = ak & steps.HAVE_FOREARM
            m = Measurement(
                zk[kernel.GYR_U],
                zk[kernel.ACC_U],
                zk[kernel.GYR_F] if fore_k else None,
                zk[kernel.ACC_F] if fore_k else None,
                zk[kernel.ELBOW] if ak & steps.HAVE_ELBOW else None,
                zk[kernel.WRIST] if ak & steps.HAVE_WRIST else None,
            )
            x, P, nis = filters.step(params.filter, model, x, P, ts, m)
            steps.finish(
                x, P, state.mon, state.nis_buf, state.tp, state.counts, t[k], ts, zk,
                ak, int(flags[k]), float(fix[k]), nis, ia, fa, out, k,
            )  # fmt: skip
        state.x, state.P = x, P
        _widen(state, out)
    _count(state)
    return cast(F64, out)


def _widen(state: TrackerState, out: F64) -> None:
    """The reported σ of each angle (rows 12–16 of ``out``, degrees, in place), compiled
    (:func:`.steps.widen`): the filter's σ with the systematic floor, the share of the angle,
    the doubt after a large shoulder rotation, pronation's with a vertical forearm, and the
    bounds on what no sensor sees (:class:`WearableParams` ``sigma_floor_deg``,
    ``sigma_share``, ``sigma_doubt``, ``doubt_rotation_deg``, ``doubt_tau_s``,
    ``sigma_pronation_vertical_deg``, ``sigma_axial_share``, ``axial_tau_s``,
    ``pronation_drift_dps``, which :func:`initial_state` put into ``state.widen`` and
    ``state.knobs``); NaN (an angle not available) stays NaN."""
    steps.widen(out, state.widen, state.doubt, state.knobs)


ROW_KEYS = (*COLUMNS, *STD_COLUMNS, "flags")


def _count(state: TrackerState) -> None:
    """Move the compiled steps' rejection counts into ``state.rejected``."""
    if np.count_nonzero(state.counts):  # (not .any(): a ufunc reduction costs µs per message)
        for name, c in zip(steps.COUNT_NAMES, state.counts.tolist(), strict=True):
            if c:
                state.rejected[name] += c
        state.counts[:] = 0
