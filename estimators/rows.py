"""The pipeline's rows (paper eqs. 9–12, §3.4's nominal shoulder) as one compiled kernel.

:func:`compute` fills the rows of a poll: the live service calls it with one row, ``rehab
analyze`` with all of them, so a row has the same value however the rows are batched (and
the kernel, compiled ahead of time or by numba's JIT, is the only implementation). NaN marks
what cannot be computed (no heading, no IMU, no nominal shoulder).

Per row at robot time ``t`` (``s = t − robot_time_offset``):

1. the heading snapshot ``(t, δ, rate, t_update, std, converged, segment, latency)`` of the
   latest update at or before ``min(s, asof) − lag`` (the updates the fusion grid had surely
   produced when the row was decided);
2. the IMU orientation ``q_IA`` at ``s`` and at ``s − latency`` (the instant the robot
   measured the elbow): normalised linear interpolation of the bracketing samples (shortest
   arc; between IMU samples it differs from slerp far below sensor noise), or, past ``asof``
   (the IMU had only reached ``asof`` when the row was decided), the newest sample at or
   before ``asof`` turned by ``q ⊗ (1, θ/2)``, ``θ = ω·dt + ω̇·dt²/2`` (normalised; the
   neglected terms are third order over the ≤ 0.05 s it bridges);
3. the heading at ``s``: drift predicted linearly (improved method), its uncertainty grown
   by :data:`DRIFT_STD_RAD_S` since the update; ``q_RA = Rz(δ) ⊗ q_IA`` (eqs. 9–10), its x
   axis now and the x axis ``x_A`` at the robot's instant;
4. the shoulder ``p_S = p_E − l_A · x_A`` (eq. 12);
5. the nominal shoulder (contract §4): the spec's point, or automatic, the mean shoulder
   over ``auto_nominal_s`` from the first converged row (``math.fsum``'s exact sum, written
   out: Shewchuk's algorithm as CPython has it), NaN until then;
6. the elbow angle (eq. 11, °) between ``x_A`` and the forearm axis ``x_C`` (``fresh``: the
   upper arm now; ``paired``: at the robot's instant; ``extrapolate``: ``x_C`` carried
   ``latency`` forward along its last robot step); the shoulder's displacement from the
   nominal one (horizontal or 3D, m); the robot-only baseline's elbow angle (the shoulder
   assumed fixed at the nominal point, ``x_A = normalize(p_E − p_S,nom)``); the upper arm's
   elevation (0° hanging, 90° horizontal) and azimuth (0° = +y, 90° = +x).

The kernel calls no other compiled function (:func:`estimators.jit.aot`), so the small
formulas are written out where they are used.
"""

from __future__ import annotations

import math
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.jit import aot

Array: TypeAlias = NDArray[np.float64]

DRIFT_STD_RAD_S = math.radians(0.1)  # heading uncertainty growth between updates, rad/s
TIMING = {"fresh": 0.0, "paired": 1.0, "extrapolate": 2.0}  # elbow-angle timing, prm[5]
# the kernel's outputs, by column name (:data:`estimators.output.ROW_COLUMNS`), in the
# order of its ``cols`` argument; ``state`` is written NaN (the indicator's code is its own
# column)
OUT = (
    "t",
    "elbow",
    "shoulder",
    "elbow_angle_deg",
    "heading_offset_deg",
    "heading_converged",
    "shoulder_displacement_m",
    "state",
    "q_ra",
    "heading_std_deg",
    "heading_confidence",
    "upper_arm_elevation_deg",
    "upper_arm_azimuth_deg",
    "nominal_shoulder",
    "conv_elbow_angle_deg",
    "wrist",
    "upper_arm_length_m",
)
# ``st``: the parameters (0–5: robot time offset (s), the snapshot lag (s), the heading's
# drift std (rad/s), ``auto_nominal_s``, 1 for a 3D displacement, the elbow-angle timing
# (:data:`TIMING`)), then the carried state: the previous row's time and forearm axis (6–9);
# the nominal shoulder's spec (10), whether its point is known (11), the point (12–14), the
# first converged row's time (15), the number of shoulders summed (16), and per axis the
# exact sum's number of partials (17–19), its sum of non-finite values (20–22) and of
# infinities (23–25)
STATE_SIZE = 26
PARTIALS = 64  # ≥ the most partials an exact sum of doubles can hold (≈ 40)


def new_state(
    offset_s: float,
    snapshot_lag_s: float,
    auto_nominal_s: float,
    displacement_norm: str,
    angle_timing: str,
) -> tuple[Array, Array]:
    """The kernel's parameters and carried state before the first row: ``(st, partials)``."""
    st = np.zeros(STATE_SIZE)
    st[0:6] = (
        offset_s,
        snapshot_lag_s,
        DRIFT_STD_RAD_S,
        auto_nominal_s,
        1.0 if displacement_norm == "3d" else 0.0,
        TIMING[angle_timing],
    )
    st[6] = -math.inf  # no previous row
    st[10] = -1.0  # no nominal spec yet
    st[15] = math.nan  # no converged row yet
    return st, np.zeros((3, PARTIALS))


@aot(
    "void(f8[:, ::1], f8[:, :], f8[:, :], f8[:, ::1], f8[:, ::1], f8[::1], f8[:, ::1], i8[::1],"
    " f8[:, ::1])"
)
def compute(  # pragma: no cover - compiled
    rin: Any,
    robot: Any,
    imu: Any,
    snaps: Any,
    specs: Any,
    st: Any,
    part: Any,
    col: Any,
    out: Any,
) -> None:
    """Fill ``out`` (n, ≥ ``NCOL``) with n rows, in order (module docstring).

    ``rin`` (n, 5): the row's time ``t`` (s), whether it has the IMU (1/0), its nominal
    spec (index into ``specs``), ``asof`` (s; inf once the IMU had reached the row) and the
    upper-arm length ``l_A`` (m). ``robot`` (n, 9): wrist, elbow ``p_E`` (m) and forearm
    axis ``x_C``. ``imu`` (N, ·): the IMU samples, ascending in time, with the columns
    ``col[0:5]``: time, segment id, ``q_IA`` (w, x, y, z), ``ω_A`` (3, rad/s), ``ω̇_A``
    (3, rad/s²). ``snaps`` (m, 8): heading snapshots, ascending in time. ``specs`` (k, 4):
    each nominal spec's point (m) and 1 if automatic. ``st``, ``part``: the parameters and
    the carried state (:func:`new_state`), updated. ``col[5:]``: ``out``'s first column of
    each :data:`OUT`."""
    nan = math.nan
    rad2deg = 180.0 / math.pi
    two_pi = 2.0 * math.pi
    off, lag, drift, auto_s = st[0], st[1], st[2], st[3]
    norm3d = st[4] > 0.0
    timing = st[5]
    ct, cseg, cq, cw, cdw = col[0], col[1], col[2], col[3], col[4]
    cols = col[5:]
    ni = imu.shape[0]
    ns = snaps.shape[0]
    look = np.empty((2, 6))  # per look-up: q (4), ok (1/0), segment id
    v = np.empty(3)
    for i in range(rin.shape[0]):
        ti = rin[i, 0]
        with_imu = rin[i, 1] > 0.0
        k = int(rin[i, 2])
        asof = rin[i, 3]
        s = ti - off
        # 1. the heading snapshot (bisect_right over the update times)
        x = (asof if asof < s else s) - lag
        lo, hi = 0, ns
        while lo < hi:
            mid = (lo + hi) // 2
            if x < snaps[mid, 0]:
                hi = mid
            else:
                lo = mid + 1
        if lo > 0:
            d, rate, t_upd = snaps[lo - 1, 1], snaps[lo - 1, 2], snaps[lo - 1, 3]
            std0, conv, sseg, lat = (
                snaps[lo - 1, 4],
                snaps[lo - 1, 5],
                snaps[lo - 1, 6],
                snaps[lo - 1, 7],
            )
        else:
            d = rate = t_upd = std0 = conv = sseg = lat = nan
        latency = (lat if lat >= 0.0 else 0.0) if math.isfinite(lat) else 0.0
        # 2. q_IA now (0) and at the robot's instant (1)
        for p in range(2):
            if p == 1 and latency == 0.0:
                for c in range(6):
                    look[1, c] = look[0, c]
                break
            x = s if p == 0 else s - latency
            if ni < 2:
                look[p, 0:4] = nan
                look[p, 4] = 0.0
                look[p, 5] = 0.0
            elif x > asof:
                # predicted from the newest sample at or before asof
                if asof >= imu[ni - 1, ct]:
                    j = ni - 1
                else:
                    lo, hi = 0, ni
                    while lo < hi:
                        mid = (lo + hi) // 2
                        if asof < imu[mid, ct]:
                            hi = mid
                        else:
                            lo = mid + 1
                    j = lo - 1
                jc = j if j > 0 else 0
                h = 0.5 * (x - imu[jc, ct])
                bx = (imu[jc, cw] + imu[jc, cdw] * h) * h
                by = (imu[jc, cw + 1] + imu[jc, cdw + 1] * h) * h
                bz = (imu[jc, cw + 2] + imu[jc, cdw + 2] * h) * h
                aw, ax, ay, az = imu[jc, cq], imu[jc, cq + 1], imu[jc, cq + 2], imu[jc, cq + 3]
                rw = aw - ((ax * bx + ay * by) + az * bz)
                rx = (aw * bx + ax) + (ay * bz - az * by)
                ry = (aw * by + ay) + (az * bx - ax * bz)
                rz = (aw * bz + az) + (ax * by - ay * bx)
                nn = math.sqrt(((rw * rw + rx * rx) + ry * ry) + rz * rz)
                if not nn > 0.0:
                    nn = nan
                look[p, 0], look[p, 1], look[p, 2], look[p, 3] = rw / nn, rx / nn, ry / nn, rz / nn
                look[p, 4] = 1.0 if j >= 0 else 0.0
                look[p, 5] = imu[jc, cseg]
            else:
                # interpolated between the samples around x (bisect_left)
                lo, hi = 0, ni
                while lo < hi:
                    mid = (lo + hi) // 2
                    if imu[mid, ct] < x:
                        lo = mid + 1
                    else:
                        hi = mid
                i1 = lo
                i1c = min(max(i1, 1), ni - 1)
                i0 = i1c - 1
                t0 = imu[i0, ct]
                a = (x - t0) / (imu[i1c, ct] - t0)
                a = 0.0 if a < 0.0 else 1.0 if a > 1.0 else a  # as np.clip (NaN passes)
                aw, ax, ay, az = imu[i0, cq], imu[i0, cq + 1], imu[i0, cq + 2], imu[i0, cq + 3]
                bw, bx, by, bz = imu[i1c, cq], imu[i1c, cq + 1], imu[i1c, cq + 2], imu[i1c, cq + 3]
                if ((aw * bw + ax * bx) + ay * by) + az * bz < 0.0:  # the shortest arc
                    bw, bx, by, bz = -bw, -bx, -by, -bz
                rw = aw + a * (bw - aw)
                rx = ax + a * (bx - ax)
                ry = ay + a * (by - ay)
                rz = az + a * (bz - az)
                nn = math.sqrt(((rw * rw + rx * rx) + ry * ry) + rz * rz)
                if not nn > 0.0:
                    nn = nan
                look[p, 0], look[p, 1], look[p, 2], look[p, 3] = rw / nn, rx / nn, ry / nn, rz / nn
                look[p, 4] = 1.0 if 0 < i1 < ni and imu[i0, cseg] == imu[i1c, cseg] else 0.0
                look[p, 5] = imu[i1c, cseg]
        ok = look[1, 4] > 0.0 and with_imu and look[0, 4] > 0.0 and look[0, 5] == look[1, 5]
        # 3. the heading and the upper arm in R
        h_delta = h_std = h_off = nan
        h_conf = 0.0
        good = False
        qw = qx = qy = qz = xn0 = xn1 = xn2 = xa0 = xa1 = xa2 = nan
        if ok and math.isfinite(d) and sseg == look[1, 5]:
            since = s - t_upd
            h_delta = d + rate * since
            if not since > 0.0:  # max(0, since), NaN stays NaN
                since = 0.0 if since == since else since
            grow = drift * since
            h_std = math.sqrt(std0 * std0 + grow * grow) * rad2deg
            if math.isfinite(h_std):
                r = h_std / 3.0
                h_conf = 1.0 / (1.0 + r * r)
            else:
                h_std = nan
            if math.isfinite(h_delta):
                h_off = (h_delta % two_pi) * rad2deg
                good = conv > 0.0
        if good:
            ch, sh = math.cos(h_delta / 2.0), math.sin(h_delta / 2.0)
            w, x0, y0, z0 = look[0, 0], look[0, 1], look[0, 2], look[0, 3]
            qw, qx = ch * w - sh * z0, ch * x0 - sh * y0
            qy, qz = ch * y0 + sh * x0, ch * z0 + sh * w
            xn0 = 1.0 - 2.0 * (qy * qy + qz * qz)
            xn1 = 2.0 * (qx * qy + qw * qz)
            xn2 = 2.0 * (qx * qz - qw * qy)
            w, x0, y0, z0 = look[1, 0], look[1, 1], look[1, 2], look[1, 3]
            ax = 1.0 - 2.0 * (y0 * y0 + z0 * z0)
            ay = 2.0 * (x0 * y0 + w * z0)
            az = 2.0 * (x0 * z0 - w * y0)
            cd, sd = math.cos(h_delta), math.sin(h_delta)
            xa0, xa1, xa2 = cd * ax - sd * ay, sd * ax + cd * ay, az
        # 4. the shoulder (eq. 12)
        w0, w1, w2 = robot[i, 0], robot[i, 1], robot[i, 2]
        e0, e1, e2 = robot[i, 3], robot[i, 4], robot[i, 5]
        c0, c1, c2 = robot[i, 6], robot[i, 7], robot[i, 8]
        prev_t, p0, p1, p2 = st[6], st[7], st[8], st[9]
        st[6], st[7], st[8], st[9] = ti, c0, c1, c2
        la = rin[i, 4]
        v[0], v[1], v[2] = e0 - la * xa0, e1 - la * xa1, e2 - la * xa2
        # 5. the nominal shoulder
        if k != st[10]:
            st[10] = k
            st[11] = 1.0 - specs[k, 3]
            st[12], st[13], st[14] = specs[k, 0], specs[k, 1], specs[k, 2]
            st[15] = nan
            st[16:26] = 0.0
        if st[11] == 0.0 and good:
            if st[15] != st[15]:
                st[15] = ti
            st[16] += 1.0
            for c in range(3):  # fsum's step: the partials stay exact and non-overlapping
                x = v[c]
                xsave = x
                n_old = int(st[17 + c])
                n_new = 0
                for j in range(n_old):
                    y = part[c, j]
                    if abs(x) < abs(y):
                        x, y = y, x
                    hi_ = x + y
                    lo_ = y - (hi_ - x)
                    if lo_ != 0.0:
                        part[c, n_new] = lo_
                        n_new += 1
                    x = hi_
                if x != 0.0:
                    if not math.isfinite(x):  # a non-finite summand (overflow: not in m)
                        if math.isinf(xsave):
                            st[23 + c] += xsave
                        st[20 + c] += xsave
                        n_new = 0
                    else:
                        part[c, n_new] = x
                        n_new += 1
                st[17 + c] = n_new
            if ti - st[15] >= auto_s:
                for c in range(3):  # fsum's result, correctly rounded; then the mean
                    special = st[20 + c]
                    if special != 0.0:
                        total = special
                    else:
                        m = int(st[17 + c])
                        total = 0.0
                        if m > 0:
                            m -= 1
                            total = part[c, m]
                            lo_ = 0.0
                            while m > 0:
                                x = total
                                m -= 1
                                y = part[c, m]
                                total = x + y
                                lo_ = y - (total - x)
                                if lo_ != 0.0:
                                    break
                            if m > 0 and (
                                (lo_ < 0.0 and part[c, m - 1] < 0.0)
                                or (lo_ > 0.0 and part[c, m - 1] > 0.0)
                            ):
                                y = lo_ * 2.0
                                x = total + y
                                if y == x - total:
                                    total = x
                    st[12 + c] = total / st[16]
                st[11] = 1.0
                st[16:26] = 0.0
        n0 = st[12] if st[11] != 0.0 else nan
        n1 = st[13] if st[11] != 0.0 else nan
        n2 = st[14] if st[11] != 0.0 else nan
        # 6. angles (eq. 11), displacement, the baseline, elevation and azimuth
        if timing == 1.0:  # paired
            u0, u1, u2 = xa0, xa1, xa2
            f0, f1, f2 = c0, c1, c2
        else:
            u0, u1, u2 = xn0, xn1, xn2
            if timing == 2.0:  # extrapolate
                dt = ti - prev_t
                step = latency / dt if 0.0 < dt < 0.2 else 0.0
                f0, f1, f2 = c0 + step * (c0 - p0), c1 + step * (c1 - p1), c2 + step * (c2 - p2)
                nn = math.sqrt((f0 * f0 + f1 * f1) + f2 * f2)
                if not nn > 0.0:
                    nn = nan
                f0, f1, f2 = f0 / nn, f1 / nn, f2 / nn
            else:
                f0, f1, f2 = c0, c1, c2
        cosine = (u0 * f0 + u1 * f1) + u2 * f2
        angle = math.acos(-1.0 if cosine < -1.0 else 1.0 if cosine > 1.0 else cosine) * rad2deg
        dx, dy, dz = v[0] - n0, v[1] - n1, v[2] - n2
        sq = dx * dx + dy * dy
        if norm3d:
            sq = sq + dz * dz
        b0, b1, b2 = e0 - n0, e1 - n1, e2 - n2
        nn = math.sqrt((b0 * b0 + b1 * b1) + b2 * b2)
        if not nn > 0.0:
            nn = nan
        cosine = ((b0 / nn) * c0 + (b1 / nn) * c1) + (b2 / nn) * c2
        base = math.acos(-1.0 if cosine < -1.0 else 1.0 if cosine > 1.0 else cosine) * rad2deg
        cosine = -xn2
        elev = math.acos(-1.0 if cosine < -1.0 else 1.0 if cosine > 1.0 else cosine) * rad2deg
        # the row, by OUT's columns
        out[i, cols[0]] = ti
        out[i, cols[1]], out[i, cols[1] + 1], out[i, cols[1] + 2] = e0, e1, e2
        out[i, cols[2]], out[i, cols[2] + 1], out[i, cols[2] + 2] = v[0], v[1], v[2]
        out[i, cols[3]] = angle
        out[i, cols[4]] = h_off
        out[i, cols[5]] = 1.0 if good else 0.0
        out[i, cols[6]] = math.sqrt(sq)
        out[i, cols[7]] = nan
        j = cols[8]
        out[i, j], out[i, j + 1], out[i, j + 2], out[i, j + 3] = qw, qx, qy, qz
        out[i, cols[9]] = h_std
        out[i, cols[10]] = h_conf
        out[i, cols[11]] = elev
        out[i, cols[12]] = math.atan2(xn0, xn1) * rad2deg
        out[i, cols[13]], out[i, cols[13] + 1], out[i, cols[13] + 2] = n0, n1, n2
        out[i, cols[14]] = base
        out[i, cols[15]], out[i, cols[15] + 1], out[i, cols[15] + 2] = w0, w1, w2
        out[i, cols[16]] = la


def unit(x: float, y: float, z: float) -> tuple[float, float, float]:
    """``(x, y, z)`` normalised (NaN for the zero vector)."""
    n = math.sqrt((x * x + y * y) + z * z)
    if not n > 0.0:
        n = math.nan
    return x / n, y / n, z / n
