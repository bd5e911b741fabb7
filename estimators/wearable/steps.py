"""The tracker's per-sample bookkeeping, compiled (numba), and the batch driver.

:mod:`.tracker` pairs the streams in Python and hands each message's steps here as arrays:
:func:`begin` (the restart after a gap), the filter's step, :func:`finish` (the drift bound
about the vertical, the start's rest and mounting check of contract §8 "Start", the innovation
monitor, the σ terms and the row's numbers). :func:`track` loops the three over a message's
steps inside numba with the EKF (:func:`.kernel.ekf_step_packed`, the same step a single call
runs); the UKF calls :func:`begin` and :func:`finish` around its Python update. A step's
numbers do not depend on how the steps were grouped into calls.

The state between calls is three arrays: ``mon`` (layout ``M_*``), the innovation window
``nis_buf`` (a ring of ``nis_window`` values) and ``counts`` (rejections by reason, ``C_*``;
the caller moves them into its counter). ``tp`` holds the tracker's parameters (``T_*``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators.jit import aot, jit
from estimators.wearable import kernel, mounting

# row flags (the tracker's public names re-export these)
FOREARM_MISSING = 1  # no forearm sample paired: elbow angles and wrist empty
CAMERA_USED = 2
CAMERA_STALE = 4
NOT_AT_REST = 8  # the start was not at rest: the zero-pose initialisation is doubtful
MOUNTING_MISMATCH = 16  # gravity at rest disagrees with the mounting: segment's angles empty
INCONSISTENT = 32  # innovations far larger than the noise model: the model does not fit
RESTARTED = 64  # the filter restarted after a gap
INITIALISING = 128  # inside the start's rest window

# per step, what was paired with the upper-arm sample (bits of ``avail``)
HAVE_FOREARM, HAVE_ELBOW, HAVE_WRIST = 1, 2, 4

# ``mon``: the run's state
(M_HAVE_X, M_T_LAST, M_T_START, M_VERT, M_REST_N, M_REST_NF, M_GYRO_MAX, M_CHECKED) = range(8)
(M_STICKY, M_NIS_SUM, M_NIS_LEN, M_NIS_POS, M_RESTARTED, M_STEPS) = range(8, 14)
M_ACC_U, M_ACC_F = 14, 17  # (3,) each: sums of the specific force over the rest window
M_T_CAM = 20  # the last step with a camera position (−inf: none yet)
# the averages (over ``T_CHANGE_TAU``) of each angle's paired mounting departure (5,) and of
# the upper-arm IMU's mounting states (3,): what :func:`finish` measures their change from
M_SLOW, M_SLOW_U = 21, 26
M_SPLIT = 29  # how much of the elbow's split from the forearm IMU's turn has been seen (0–1)
# the camera against the estimate: θ0…θ3's disagreement (4,) rad, averaged; the offsets'
# average (6,) m; whether a camera position has come since the (re)start; the σ grown while
# the camera is away (deg); the last row's θ0…θ3 (4,) deg, kept from then on
M_DIS, M_OFF_SLOW, M_CAM_SEEN, M_DROP, M_PREV = 30, 34, 40, 41, 42
M_SIZE = 46
# ``counts``: rejections by reason
COUNT_NAMES = (
    "gap_restart",
    "inconsistent_model",
    "start_not_at_rest",
    "mounting_mismatch_upperarm",
    "mounting_mismatch_forearm",
    "forearm_unpaired",
    "forearm_missing",
    "camera_stale",
    "camera_superseded",
    "time_backwards_upperarm",
    "time_backwards_forearm",
    "time_backwards_camera",
    "nonfinite_upperarm",
    "nonfinite_forearm",
    "nonfinite_camera",
    "out_of_range_upperarm",
    "out_of_range_forearm",
    "out_of_range_camera",
)
C_GAP, C_INCONSISTENT, C_NOT_AT_REST, C_MOUNT_U, C_MOUNT_F = range(5)
C_UNPAIRED, C_FORE_MISSING, C_STALE, C_SUPERSEDED = range(5, 9)
C_BACKWARDS, C_NONFINITE, C_RANGE = 9, 12, 15  # + the stream (kind)
# ``tp``: parameters
(T_MAX_GAP, T_REST_S, T_DRIFT, T_INIT_SIGMA, T_REST_GYRO, T_MOUNT_TOL) = range(6)
(T_NIS_WINDOW, T_NIS_LIMIT, T_LEFT, T_FOREARM) = range(6, 10)
T_UP_U, T_UP_F = 10, 13  # (3,) each: "up" in each IMU's frame at the zero pose
(T_TOL, T_MISSING, T_CAM_AGE, T_CAMERA, T_FIX_REACH, T_SIGMA_POS) = range(16, 22)
T_MAX_GYRO, T_MAX_ACC, T_VERT_INIT = 22, 23, 24
# the σ from the mounting states without a camera (:func:`finish`): the gain, how long a camera
# position counts (s), and (2, 5) the states paired with each angle (−1: none)
T_MOUNT_GAIN, T_CAM_HOLD, T_MOUNT_IDX = 25, 26, 27
T_MOUNT_SIGN = 37  # (2, 5) the sign each paired state's departure takes in the angle's error
# the σ from the mounting states' change (:func:`finish`): its gain, the upper arm's whole
# turn's gain (no camera), the averages' time constant (s), the upper-arm states (3,) (−1: none)
T_CHANGE_GAIN, T_CHANGE_U, T_CHANGE_TAU, T_MU_IDX = 47, 48, 49, 50
# the elbow's σ until its split is seen without a camera (:func:`finish`): deg, and s of turn
T_SPLIT, T_SPLIT_TAU = 53, 54
# the camera's disagreement (:func:`finish`): its gain, its average's and the offsets' average's
# time constants (s); the σ's share of the arm's motion while the camera is away, and its cap
T_DIS_GAIN, T_DIS_TAU, T_OFF_TAU, T_DROP_SHARE, T_DROP_CAP = 55, 56, 57, 58, 59
T_SIZE = 60
# :func:`widen`'s scalar settings, one (6,) array (:class:`.params.WearableParams`: the
# pronation's vertical term, deg; the rotation's doubt threshold, deg, and fading, s; the
# straight-elbow share and its fading, s; the hanging forearm's drift, deg/s)
(K_VERTICAL, K_ROTATION, K_TAU, K_AXIAL, K_AXIAL_TAU, K_DRIFT, K_AXIAL_TAU_P) = range(7)
# the streams (``kind``) and their sample buffers: rows (t, u (3), v (3)), a queue from
# ``ptr[2 kind]`` of ``ptr[2 kind + 1]`` rows
K_UPPER, K_FORE, K_CAMERA = range(3)


def new_state(nis_window: int) -> tuple[Any, Any, Any]:
    """``mon``, ``nis_buf``, ``counts`` of a tracker that has seen nothing."""
    mon = np.zeros(M_SIZE)
    mon[M_T_CAM] = -math.inf
    return mon, np.zeros(max(nis_window, 1)), np.zeros(len(COUNT_NAMES), np.intp)


@jit
def pair(
    kind: int,
    t: Any,
    u: Any,
    v: Any,
    upper: Any,
    fore: Any,
    cam: Any,
    ptr: Any,
    t_seen: Any,
    tp: Any,
    counts: Any,
    final: bool,
) -> Any:
    """Queue one message's samples of stream ``kind`` (``t`` (N,) s, ``u``, ``v`` (N, 3); a
    sample with a value that is not finite, or beyond any body-worn IMU's range, is counted
    and dropped) and pair every upper-arm sample whose forearm
    partner is settled, sample by sample as they arrive (so grouping does not matter); with
    ``final`` (end of data), also those still waiting. The buffer of ``kind`` must have room
    for N more rows. Returns the steps: ``t`` (K,), ``z`` (K, 6, 3) in kernel slots, ``avail``,
    ``flags``, ``fix_deg`` (K,) as :func:`finish` takes them.

    Pairing: a forearm sample within ``forearm_tolerance_s`` of an upper-arm sample is used
    with it; an upper-arm sample waits (in sample time) for its partner at most
    ``forearm_missing_s``, then steps on without it. The newest camera sample at or before an
    upper-arm sample is used with it once; one older than ``camera_max_age_s`` is stale."""
    m = ptr[1] + (t.shape[0] if kind == K_UPPER else 0)
    out_t = np.empty(m)
    z = np.zeros((m, 6, 3))
    avail = np.zeros(m, dtype=np.intp)
    flags = np.zeros(m, dtype=np.intp)
    fix = np.full(m, math.inf)
    buf = upper if kind == K_UPPER else (fore if kind == K_FORE else cam)
    k = 0
    for i in range(t.shape[0]):
        finite = math.isfinite(t[i])
        big = False
        for c in range(3):
            finite = finite and math.isfinite(u[i, c]) and math.isfinite(v[i, c])
            if kind != K_CAMERA:
                big = big or abs(u[i, c]) > tp[T_MAX_GYRO] or abs(v[i, c]) > tp[T_MAX_ACC]
        if not finite:
            counts[C_NONFINITE + kind] += 1
            continue
        if big:
            counts[C_RANGE + kind] += 1
            continue
        if t[i] <= t_seen[kind]:
            counts[C_BACKWARDS + kind] += 1
            continue
        t_seen[kind] = t[i]
        r = ptr[2 * kind] + ptr[2 * kind + 1]
        buf[r, 0] = t[i]
        for c in range(3):
            buf[r, 1 + c] = u[i, c]
            buf[r, 4 + c] = v[i, c]
        ptr[2 * kind + 1] += 1
        k = _drain(upper, fore, cam, ptr, t_seen, tp, counts, False, out_t, z, avail, flags, fix, k)
    if final:
        k = _drain(upper, fore, cam, ptr, t_seen, tp, counts, True, out_t, z, avail, flags, fix, k)
    for q in range(3):  # an empty queue starts again at the buffer's top
        if ptr[2 * q + 1] == 0:
            ptr[2 * q] = 0
    return out_t[:k], z[:k], avail[:k], flags[:k], fix[:k]


@jit
def _drain(
    upper: Any,
    fore: Any,
    cam: Any,
    ptr: Any,
    t_seen: Any,
    tp: Any,
    counts: Any,
    final: bool,
    out_t: Any,
    z: Any,
    avail: Any,
    flags: Any,
    fix: Any,
    k: int,
) -> int:
    """:func:`pair`'s pairing of the queued upper-arm samples into steps ``k``, ``k`` + 1, …;
    returns the next ``k``."""
    use_fore = tp[T_FOREARM] != 0.0
    tol = tp[T_TOL]
    while ptr[1] > 0:
        hu = ptr[0]
        tu = upper[hu, 0]
        fi = -1
        if use_fore:
            while ptr[3] > 0 and fore[ptr[2], 0] < tu - tol:
                ptr[2] += 1
                ptr[3] -= 1
                counts[C_UNPAIRED] += 1
            if ptr[3] > 0 and fore[ptr[2], 0] <= tu + tol:
                fi = ptr[2]
                ptr[2] += 1
                ptr[3] -= 1
            elif ptr[3] == 0 and not final:
                # nothing from the forearm at or after tu yet: wait, unless it is missing
                waited = t_seen[K_UPPER] - max(tu, t_seen[K_FORE])
                if t_seen[K_FORE] < tu - tol and waited < tp[T_MISSING]:
                    return k
        ptr[0] += 1
        ptr[1] -= 1
        best = -1
        fl = 0
        while ptr[5] > 0 and cam[ptr[4], 0] <= tu:
            c = ptr[4]
            ptr[4] += 1
            ptr[5] -= 1
            if tu - cam[c, 0] > tp[T_CAM_AGE]:
                counts[C_STALE] += 1
                fl = CAMERA_STALE
                continue
            if best >= 0:
                counts[C_SUPERSEDED] += 1
            best = c
        for c in range(3):
            z[k, kernel.GYR_U, c] = upper[hu, 1 + c]
            z[k, kernel.ACC_U, c] = upper[hu, 4 + c]
        if best >= 0 and tp[T_CAMERA] != 0.0:
            fl = CAMERA_USED
            avail[k] |= HAVE_ELBOW | HAVE_WRIST
            for c in range(3):
                z[k, kernel.ELBOW, c] = cam[best, 1 + c]
                z[k, kernel.WRIST, c] = cam[best, 4 + c]
            # the camera's bound on the turn about the vertical: its position noise over the
            # arm's horizontal reach (none when the arm hangs too close to the vertical)
            reach = max(
                math.hypot(cam[best, 1], cam[best, 2]), math.hypot(cam[best, 4], cam[best, 5])
            )
            if reach >= tp[T_FIX_REACH]:
                fix[k] = math.degrees(tp[T_SIGMA_POS] / reach)
        if fi >= 0:
            avail[k] |= HAVE_FOREARM
            for c in range(3):
                z[k, kernel.GYR_F, c] = fore[fi, 1 + c]
                z[k, kernel.ACC_F, c] = fore[fi, 4 + c]
        elif use_fore:
            fl |= FOREARM_MISSING
            counts[C_FORE_MISSING] += 1
        out_t[k] = tu
        flags[k] = fl
        k += 1
    return k


@jit
def begin(x: Any, P: Any, mon: Any, tp: Any, counts: Any, t: float, x0: Any, P0: Any) -> Any:
    """Start a step at upper-arm time ``t`` s: (re)start at ``x0``, ``P0`` on the first sample
    or after a gap longer than the parameter's; returns ``x``, ``P`` and the step ``ts`` s."""
    if mon[M_HAVE_X] == 0.0 or t - mon[M_T_LAST] > tp[T_MAX_GAP]:
        if mon[M_HAVE_X] != 0.0:
            counts[C_GAP] += 1
            mon[M_RESTARTED] = 1.0
        x = x0.copy()
        P = P0.copy()
        mon[M_HAVE_X] = 1.0
        mon[M_T_START] = t
        for k in range(6):
            mon[M_ACC_U + k] = 0.0
        mon[M_REST_N] = mon[M_REST_NF] = mon[M_GYRO_MAX] = mon[M_CHECKED] = 0.0
        mon[M_STICKY] = mon[M_NIS_SUM] = mon[M_NIS_LEN] = mon[M_NIS_POS] = 0.0
        mon[M_VERT] = tp[T_INIT_SIGMA] + tp[T_VERT_INIT]
        for k in range(M_SLOW, M_SIZE):  # the mounting states start again from nominal
            mon[k] = 0.0
        ts = 0.0
    else:
        ts = t - mon[M_T_LAST]
    mon[M_T_LAST] = t
    return x, P, ts


@jit
def _check_rest(mon: Any, tp: Any, counts: Any) -> None:
    """The end of the start's rest window: did the gyros stay still, and does the mean specific
    force point up as the mounting at the zero pose says (within the tolerance)?"""
    mon[M_CHECKED] = 1.0
    sticky = int(mon[M_STICKY])
    if mon[M_GYRO_MAX] > tp[T_REST_GYRO]:
        counts[C_NOT_AT_REST] += 1
        mon[M_STICKY] = sticky | NOT_AT_REST
        return  # the accelerometers moved too: no mounting verdict from them
    for seg in range(2):
        n = mon[M_REST_N] if seg == 0 else mon[M_REST_NF]
        if seg == 1 and n == 0.0:
            continue
        acc, up = (M_ACC_U, T_UP_U) if seg == 0 else (M_ACC_F, T_UP_F)
        dot = 0.0
        norm2 = 0.0
        for c in range(3):
            mean = mon[acc + c] / max(n, 1.0)
            dot += mean * tp[up + c]
            norm2 += mean * mean
        cos = dot / max(math.sqrt(norm2), 1e-9)
        if math.degrees(math.acos(max(-1.0, min(1.0, cos)))) > tp[T_MOUNT_TOL]:
            counts[C_MOUNT_U if seg == 0 else C_MOUNT_F] += 1
            sticky |= MOUNTING_MISMATCH
    mon[M_STICKY] = sticky


@jit
def finish(
    x: Any,
    P: Any,
    mon: Any,
    nis_buf: Any,
    tp: Any,
    counts: Any,
    t: float,
    ts: float,
    z: Any,
    avail: int,
    flags: int,
    fix_deg: float,
    nis: float,
    ia: Any,
    fa: Any,
    out: Any,
    i: int,
) -> None:
    """After the filter's step at ``t`` (over ``ts`` s, with readings ``z`` (6, 3) in kernel
    slots, ``avail`` bits, the pairing's ``flags`` and the camera's bound ``fix_deg`` on the turn
    about the vertical, +inf without one): the monitors, then row ``i`` of ``out`` (19, N):
    tracker.COLUMNS, tracker.STD_COLUMNS, flags (angles in degrees, NaN where not available)."""
    mon[M_STEPS] += 1.0
    mon[M_VERT] = min(mon[M_VERT] + tp[T_DRIFT] * ts, fix_deg)
    if mon[M_CHECKED] == 0.0:
        if t - mon[M_T_START] < tp[T_REST_S]:
            g = 0.0
            for c in range(3):
                mon[M_ACC_U + c] += z[kernel.ACC_U, c]
                g += z[kernel.GYR_U, c] * z[kernel.GYR_U, c]
            mon[M_REST_N] += 1.0
            g = math.sqrt(g)
            if avail & HAVE_FOREARM:
                gf = 0.0
                for c in range(3):
                    mon[M_ACC_F + c] += z[kernel.ACC_F, c]
                    gf += z[kernel.GYR_F, c] * z[kernel.GYR_F, c]
                mon[M_REST_NF] += 1.0
                g = max(g, math.sqrt(gf))
            mon[M_GYRO_MAX] = max(mon[M_GYRO_MAX], g)
        else:
            _check_rest(mon, tp, counts)
    # the innovation monitor: mean NIS over the last nis_window steps
    w = int(tp[T_NIS_WINDOW])
    n = int(mon[M_NIS_LEN])
    pos = int(mon[M_NIS_POS])
    mon[M_NIS_SUM] += nis
    if n < w:
        nis_buf[(pos + n) % w] = nis
        n += 1
    else:
        mon[M_NIS_SUM] -= nis_buf[pos]
        nis_buf[pos] = nis
        pos = (pos + 1) % w
    mon[M_NIS_LEN], mon[M_NIS_POS] = n, pos
    sticky = int(mon[M_STICKY])
    if n == w and mon[M_NIS_SUM] / w > tp[T_NIS_LIMIT]:
        if not sticky & INCONSISTENT:
            counts[C_INCONSISTENT] += 1
        sticky |= INCONSISTENT
    else:
        sticky &= ~INCONSISTENT
    mon[M_STICKY] = sticky
    flags |= sticky
    if mon[M_RESTARTED] != 0.0:
        flags |= RESTARTED
    if t - mon[M_T_START] < tp[T_REST_S]:
        flags |= INITIALISING
    o = kernel.emit(x, P, ia, fa, math.radians(mon[M_VERT]))
    since = t - mon[M_T_CAM]  # since the last camera position (inf: none yet)
    if avail & HAVE_ELBOW:
        mon[M_T_CAM] = t
    blind = t - mon[M_T_CAM] > tp[T_CAM_HOLD]  # no camera position for a while (or at all)
    if tp[T_MOUNT_GAIN] > 0.0:
        # a mounting state that has just moved is being learnt again: the change from its
        # average over T_CHANGE_TAU (first step: from nominal, as the states start there)
        a = min(1.0, ts / tp[T_CHANGE_TAU])
        for j in range(5):  # the paired states' departures: their signed sum (the elbow's:
            dep = 0.0  # the two IMUs' turns about its axis, one minus the other) where it
            sq = 0.0  # exceeds their quadrature sum
            for r in range(2):
                k = int(tp[T_MOUNT_IDX + 5 * r + j])
                if k >= 0:
                    dep += tp[T_MOUNT_SIGN + 5 * r + j] * x[k]
                    sq += x[k] * x[k]
            d = max(abs(dep), math.sqrt(sq))
            change = dep - mon[M_SLOW + j]
            mon[M_SLOW + j] += a * change
            if blind and d != 0.0:
                o[5 + j] = math.hypot(o[5 + j], tp[T_MOUNT_GAIN] * math.degrees(d))
            if (blind or j == 3) and change != 0.0:  # the elbow's with a camera too
                o[5 + j] = math.hypot(o[5 + j], tp[T_CHANGE_GAIN] * math.degrees(change))
        turned = 0.0  # the upper-arm IMU's whole turn (its long axis's state is paired with
        for c in range(3):  # no angle, yet tilts flexion's and abduction's split once raised)
            k = int(tp[T_MU_IDX + c])
            if k >= 0:
                dc = x[k] - mon[M_SLOW_U + c]
                mon[M_SLOW_U + c] += a * dc
                turned += dc * dc
        if blind and turned != 0.0:
            for j in range(2):
                o[5 + j] = math.hypot(o[5 + j], tp[T_CHANGE_U] * math.degrees(math.sqrt(turned)))
    if tp[T_SPLIT] > 0.0:
        # Without a camera the elbow's flexion and the forearm IMU's turn about the elbow's
        # axis are one quantity to gravity and the gyros until the forearm turns about its
        # own axis (pronation turns that axis away from the elbow's); until then the EKF's P
        # holds only what the kinematic accelerations split (second order). A camera's
        # positions see the flexion itself.
        if blind:
            p5 = o[4]
            s5 = math.sin(math.radians(p5)) if p5 == p5 else 0.0
            mon[M_SPLIT] = min(1.0, mon[M_SPLIT] + ts * s5 * s5 / tp[T_SPLIT_TAU])
            o[8] = math.hypot(o[8], tp[T_SPLIT] * (1.0 - mon[M_SPLIT]))
        else:
            mon[M_SPLIT] = 1.0
    if tp[T_DIS_GAIN] > 0.0 or tp[T_DROP_SHARE] > 0.0:
        _camera_doubt(x, mon, tp, since, z, avail, blind, o, ia, fa)
    if tp[T_LEFT] != 0.0:  # back from the virtual right arm (params.mirror_vectors)
        o[11] = -o[11]
        o[14] = -o[14]
    bad = (flags & MOUNTING_MISMATCH) != 0
    no_fore = bad or tp[T_FOREARM] == 0.0 or (flags & FOREARM_MISSING) != 0
    out[0, i] = t
    for j in range(5):
        gone = bad or (no_fore and j >= 3)
        out[1 + j, i] = math.nan if gone else o[j]
        out[12 + j, i] = math.nan if gone else o[5 + j]
    for c in range(3):
        out[6 + c, i] = math.nan if bad else o[10 + c]
        out[9 + c, i] = math.nan if no_fore else o[13 + c]
    # the whole arm's turn about the vertical (unobservable without a camera, carried by the
    # gyros alone, contract §8 "Start"): the EKF's σ of it and the drift bound
    out[17, i] = math.hypot(o[16], mon[M_VERT])
    out[18, i] = flags


@jit
def _camera_doubt(
    x: Any,
    mon: Any,
    tp: Any,
    since: float,
    z: Any,
    avail: int,
    blind: bool,
    o: Any,
    ia: Any,
    fa: Any,
) -> None:
    """θ0…θ3's σ in ``o`` (:func:`kernel.emit`'s) once a camera has been seen: with its
    positions, their disagreement with the estimate; while it is away, a share of the arm's
    motion since (the camera corrected the IMUs' mountings, which now carry the angles alone:
    after a 2-s dropout in the ROM moves the elbow came back 9° off, and the EKF's σ of it,
    0.35°, let the camera pull it back only over seconds)."""
    seen = mon[M_CAM_SEEN] != 0.0
    if not seen and not avail & HAVE_ELBOW:
        return  # no camera yet (a camera-less session: never)
    moved = 0.0
    for j in range(4):
        if seen:
            moved += abs(o[j] - mon[M_PREV + j])
        mon[M_PREV + j] = o[j]
    if avail & HAVE_ELBOW:
        # against the offsets as averaged over T_OFF_TAU: the EKF explains part of an angle's
        # error by moving the camera's offset states (constants), away from that average
        off = kernel.camera_offsets(x, ia)
        a = min(1.0, since / tp[T_OFF_TAU])
        for c in range(6):
            if seen:
                mon[M_OFF_SLOW + c] += a * (off[c] - mon[M_OFF_SLOW + c])
            else:
                mon[M_OFF_SLOW + c] = off[c]
        mon[M_CAM_SEEN] = 1.0
        th = np.empty(5)
        for j in range(5):
            th[j] = math.radians(o[j])
        # ridge: a prior of 0.3 rad on each angle's share, in the camera's noise (σp/0.3)²
        ridge = (tp[T_SIGMA_POS] / 0.3) ** 2
        d = kernel.camera_angles(
            th, fa[0], fa[1], z, (avail & HAVE_WRIST) != 0, mon[M_OFF_SLOW : M_OFF_SLOW + 6], ridge
        )
        a = min(1.0, since / tp[T_DIS_TAU])
        for j in range(4):
            mon[M_DIS + j] += a * (d[j] - mon[M_DIS + j])
        mon[M_DROP] = 0.0
    else:
        mon[M_DROP] = min(tp[T_DROP_CAP], mon[M_DROP] + tp[T_DROP_SHARE] * moved)
    for j in range(4):
        dis = 0.0 if blind else tp[T_DIS_GAIN] * math.degrees(abs(mon[M_DIS + j]))
        o[5 + j] = math.hypot(o[5 + j], math.hypot(dis, mon[M_DROP]))


@jit
def track(
    x: Any,
    P: Any,
    mon: Any,
    nis_buf: Any,
    tp: Any,
    counts: Any,
    t: Any,
    z: Any,
    have: Any,
    avail: Any,
    flags: Any,
    fix_deg: Any,
    ia: Any,
    fa: Any,
    x0: Any,
    P0: Any,
    mis: Any,
    basis: Any,
) -> Any:
    """EKF steps at upper-arm times ``t`` (N,) s: per step ``z`` (N, 6, 3), ``avail``,
    ``flags``, ``fix_deg`` (N,) as :func:`finish` takes them; ``have`` (8, 6): the slots a
    step measures by its ``avail`` bits (:meth:`.model.Model.measured`); ``mis`` (6, 5) and
    ``basis`` (6, 3, 3): the mounting states (:mod:`.mounting`; ``mis`` all −1 without them).
    Returns ``x``, ``P`` and the rows ``out`` (19, N)."""
    out = np.empty((19, t.shape[0]))
    mounted = mis.max() >= 0
    for i in range(t.shape[0]):
        x, P, ts = begin(x, P, mon, tp, counts, t[i], x0, P0)
        if mounted:  # the product's mounting states: the same step with them in h and H
            x, P, nis = mounting.ekf_step(x, P, ts, z[i], have[avail[i]], ia, fa, mis, basis)
        else:
            x, P, nis = kernel.ekf_step_packed(x, P, ts, z[i], have[avail[i]], ia, fa)
        finish(
            x, P, mon, nis_buf, tp, counts, t[i], ts, z[i], avail[i], flags[i], fix_deg[i],
            nis, ia, fa, out, i,
        )  # fmt: skip
    return x, P, out


# ahead of time (:mod:`estimators.aot`): the message's arrays as :mod:`.tracker` holds them
_FEED = (
    "Tuple((f8[::1], f8[:, ::1], f8[:, ::1]))(i8, f8[:], f8[:, :], f8[:, :], b1, f8[:, ::1],"
    " f8[:, ::1], f8[:, ::1], i8[::1], f8[::1], f8[::1], f8[:, ::1], f8[::1], f8[::1], f8[::1],"
    " i8[::1], b1[:, ::1], i8[::1], f8[::1], f8[::1], f8[:, ::1], i8[:, ::1], f8[:, :, ::1],"
    " f8[:, ::1], f8[::1], f8[::1])"
)


@aot(_FEED, blas=True)
def feed(
    kind: int,
    t: Any,
    u: Any,
    v: Any,
    final: bool,
    upper: Any,
    fore: Any,
    cam: Any,
    ptr: Any,
    t_seen: Any,
    x: Any,
    P: Any,
    mon: Any,
    nis_buf: Any,
    tp: Any,
    counts: Any,
    have: Any,
    ia: Any,
    fa: Any,
    x0: Any,
    P0: Any,
    mis: Any,
    basis: Any,
    terms: Any,
    doubt: Any,
    knobs: Any,
) -> Any:
    """One message through the EKF: :func:`pair`, :func:`track`, then :func:`widen` of its
    rows (``terms``, ``doubt``, ``knobs`` as it takes them): one call from Python."""
    pt, z, avail, flags, fix = pair(kind, t, u, v, upper, fore, cam, ptr, t_seen, tp, counts, final)
    x, P, out = track(
        x, P, mon, nis_buf, tp, counts, pt, z, have, avail, flags, fix, ia, fa, x0, P0, mis, basis
    )
    widen(out, terms, doubt, knobs)
    return x, P, out


@jit
def widen(out: Any, terms: Any, doubt: Any, knobs: Any) -> None:
    """The reported σ of each angle (rows 12–16 of ``out`` (19, N), degrees, in place): the
    filter's σ with ``terms`` (3, 5) squared: the systematic floor, the share of the angle
    (rows 1–5), the doubt after a large shoulder rotation; and pronation's with a vertical
    forearm, ``vertical`` deg × the squared vertical component of wrist − elbow (0 if unknown).
    The doubt (:func:`doubt_held`: ``rotation`` deg, ``tau`` s, its state ``doubt[:2]``) of the
    shoulder rotation (row 3) at the rows' times (row 0). Then the two terms of
    :func:`unobserved` (``axial`` share, ``axial_tau`` s, ``drift`` deg/s; state
    ``doubt[2:]``): rotation and pronation's split while the elbow is straight, pronation's
    drift while the forearm hangs (pronation's split fading with its own ``axial_tau_p``).
    The seven settings are ``knobs`` (7,) (``K_*``). NaN (no angle) stays NaN.
    One message's rows per call: per row, the arithmetic of the array form it replaced, in
    the same order (the same numbers bit for bit); the state makes any grouping give the same."""
    vertical, rotation, tau = knobs[K_VERTICAL], knobs[K_ROTATION], knobs[K_TAU]
    axial, axial_tau, drift = knobs[K_AXIAL], knobs[K_AXIAL_TAU], knobs[K_DRIFT]
    axial_tau_p = knobs[K_AXIAL_TAU_P]
    n = out.shape[1]
    use_doubt = False
    use_new = axial != 0.0 or drift != 0.0
    use_any = vertical != 0.0 or use_new
    for j in range(5):
        use_doubt = use_doubt or terms[2, j] != 0.0
        use_any = use_any or terms[0, j] != 0.0 or terms[1, j] != 0.0 or terms[2, j] != 0.0
    if not use_any or n == 0:
        return
    h = np.zeros(n)
    if use_doubt:
        doubt_held(out[0], out[3], doubt, rotation, tau, h)
    for k in range(n):
        hh = h[k] * h[k]
        c2 = 0.0
        if vertical != 0.0 or drift != 0.0:
            d0 = out[9, k] - out[6, k]
            d1 = out[10, k] - out[7, k]
            d2 = out[11, k] - out[8, k]
            d0 *= d0
            d1 *= d1
            d2 *= d2
            s = d0 + d1 + d2
            q = d2 / (s if (s != s or s > 1e-12) else 1e-12)  # np.maximum keeps NaN
            c2 = q if q > 0.0 else 0.0  # np.fmax: NaN -> 0
        ax2 = 0.0
        axp2 = 0.0
        dr2 = 0.0
        if use_new:
            unobserved(out, k, doubt, axial, axial_tau, axial_tau_p, drift, c2)
            ax2 = doubt[2] * doubt[2]
            axp2 = doubt[7] * doubt[7]
            dr2 = doubt[3] * doubt[3]
        for j in range(5):
            a = out[1 + j, k]
            e = terms[0, j] + terms[1, j] * (a * a)
            if use_doubt:
                e += terms[2, j] * hh
            if j == 4 and vertical != 0.0:
                w = vertical * c2
                e += w * w
            if use_new and j == 2:
                e += ax2
            if use_new and j == 4:
                e += axp2 + dr2
            sd = out[12 + j, k]
            out[12 + j, k] = math.sqrt(sd * sd + e)


@jit
def unobserved(
    out: Any, k: int, doubt: Any, axial: float, axial_tau: float, axial_tau_p: float,
    drift: float, c2: float,
) -> None:  # fmt: skip
    """Two bounds on what no sensor sees, for row ``k`` of ``out``, in ``doubt[2:]``
    ([axial, drift, t, θ0, θ1] of the previous row, then pronation's axial; deg, s):

    - *axial*: with the elbow straight, shoulder rotation and pronation turn about the same
      axis (the arm's), so their split is seen by neither gravity nor the camera. It grows by
      ``axial`` × the upper arm's motion (|Δθ0| + |Δθ1|, deg) weighted by cos² of the elbow
      angle (an unknown elbow counts as straight), and fades as exp(−Δt·sin²/``axial_tau``)
      once the elbow bends (its split is then seen); pronation's copy (``doubt[7]``) fades
      with ``axial_tau_p``.
    - *drift*: with the forearm hanging (``c2`` its squared vertical component) pronation
      is a turn about the vertical; it grows at ``drift`` deg/s·(2 c2 − 1), down to 0 while
      the forearm is nearer horizontal than vertical (gravity then sees pronation)."""
    t = out[0, k]
    dt = t - doubt[4] if doubt[4] == doubt[4] else 0.0
    doubt[4] = t
    el = out[4, k]
    s = math.cos(math.radians(el)) ** 2 if el == el else 1.0
    mv = 0.0
    a0 = out[1, k]
    a1 = out[2, k]
    if a0 == a0 and a1 == a1:
        if doubt[5] == doubt[5]:
            mv = abs(a0 - doubt[5]) + abs(a1 - doubt[6])
        doubt[5] = a0
        doubt[6] = a1
    lost = axial * s * mv
    doubt[2] = doubt[2] * math.exp(-dt * (1.0 - s) / axial_tau) + lost
    doubt[7] = doubt[7] * math.exp(-dt * (1.0 - s) / axial_tau_p) + lost
    doubt[3] = max(0.0, doubt[3] + dt * drift * (2.0 * c2 - 1.0))


@jit
def doubt_held(t: Any, rotation_deg: Any, doubt: Any, rotation: float, tau: float, h: Any) -> None:
    """The excess ``g`` = max(|θ2| − ``rotation``, 0) of the shoulder rotation ``rotation_deg``
    (N,) deg held at its peak and fading as exp(−Δt/``tau``) in sample time ``t`` (N,) s, into
    ``h`` (N,) deg. Kept as a running maximum of log g + (t − t_first)/τ from the first row
    ever (``doubt`` = [t_first, peak], updated), so any grouping of the rows gives the same
    numbers."""
    if t.shape[0] and math.isnan(doubt[0]):
        doubt[0] = t[0]
    for k in range(t.shape[0]):
        g = abs(rotation_deg[k]) - rotation
        x = (t[k] - doubt[0]) / tau
        # no excess (or no angle: NaN, as np.fmax): g of 1e-300, which exp(log) gives back
        lg = math.log(g if g > 1e-300 else 1e-300) + x
        if lg > doubt[1]:
            doubt[1] = lg
        h[k] = math.exp(doubt[1] - x)
