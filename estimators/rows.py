"""Per-row formulas of the pipeline's last stage (paper eqs. 9–12), in Python floats.

The live service computes one row per robot sample and ``rehab analyze`` all of them, through
these same functions, row by row: a row has the same value however the rows are batched.
NaN marks what cannot be computed (no heading, no IMU, no nominal shoulder).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

RAD2DEG = 180.0 / math.pi
TWO_PI = 2.0 * math.pi
DRIFT_STD_RAD_S = math.radians(0.1)  # heading uncertainty growth between updates, rad/s
NAN = math.nan
NAN3 = (NAN, NAN, NAN)
NAN4 = (NAN, NAN, NAN, NAN)

Vec = tuple[float, float, float]
Quat = tuple[float, float, float, float]


def nlerp(a: Sequence[float], b: Sequence[float], s: float) -> Quat:
    """Normalised linear interpolation of unit quaternions ``a``, ``b`` (w, x, y, z), shortest
    arc, ``s`` in [0, 1]. Between IMU samples it differs from slerp far below sensor noise."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    if ((aw * bw + ax * bx) + ay * by) + az * bz < 0.0:
        bw, bx, by, bz = -bw, -bx, -by, -bz
    w = aw + s * (bw - aw)
    x = ax + s * (bx - ax)
    y = ay + s * (by - ay)
    z = az + s * (bz - az)
    n = math.sqrt(((w * w + x * x) + y * y) + z * z)
    if not n > 0.0:
        n = NAN
    return w / n, x / n, y / n, z / n


def predict(q: Sequence[float], w: Sequence[float], dw: Sequence[float], dt: float) -> Quat:
    """The orientation ``dt`` s after unit quaternion ``q`` (w, x, y, z) at the body rate
    ``w`` (rad/s, in the rotated frame) changing at ``dw`` (rad/s²): ``q ⊗ (1, θ/2)`` with
    the rotation vector ``θ = w·dt + dw·dt²/2``, normalised. Over the ≤ 0.05 s it bridges
    the neglected terms are third order."""
    h = 0.5 * dt
    bx, by, bz = (w[0] + dw[0] * h) * h, (w[1] + dw[1] * h) * h, (w[2] + dw[2] * h) * h
    aw, ax, ay, az = q
    rw = aw - ((ax * bx + ay * by) + az * bz)
    rx = (aw * bx + ax) + (ay * bz - az * by)
    ry = (aw * by + ay) + (az * bx - ax * bz)
    rz = (aw * bz + az) + (ax * by - ay * bx)
    n = math.sqrt(((rw * rw + rx * rx) + ry * ry) + rz * rz)
    if not n > 0.0:
        n = NAN
    return rw / n, rx / n, ry / n, rz / n


def heading_arm(
    s: float,
    ok: bool,
    snap: Sequence[float],
    seg: float,
    q_now: Sequence[float],
    q_pair: Sequence[float],
) -> tuple[tuple[float, float, float, float, bool], Quat, Vec, Vec]:
    """The heading at row time ``s`` (s) from the latest update snapshot
    ``(t, δ, rate, t_update, std, converged, segment, latency)``: drift predicted linearly
    (improved method), its uncertainty grown by 0.1 °/s since the update; then
    ``q_RA = Rz(δ) ⊗ q_IA`` (eqs. 9–10) now, its x axis now, and the x axis ``x_A`` at the
    instant the robot measured the elbow (``q_pair``). ``ok``: the IMU orientation exists at
    the row; ``seg``: its IMU segment (a reset voids the heading).

    Returns ``(δ rad, std °, confidence 0..1, δ in [0, 360) °, converged)``, ``q_RA``, its x
    axis now and ``x_A``; NaN where no converged heading applies."""
    _, d, rate, t_upd, std0, conv, sseg, _ = snap
    if not (ok and math.isfinite(d) and sseg == seg):
        return (NAN, NAN, 0.0, NAN, False), NAN4, NAN3, NAN3
    since = s - t_upd
    delta = d + rate * since
    if not since > 0.0:  # max(0, since), NaN stays NaN
        since = 0.0 if since == since else since
    grow = DRIFT_STD_RAD_S * since
    std_deg = math.sqrt(std0 * std0 + grow * grow) * RAD2DEG
    if math.isfinite(std_deg):
        r = std_deg / 3.0
        conf = 1.0 / (1.0 + r * r)
    else:
        std_deg, conf = NAN, 0.0
    if not math.isfinite(delta):
        return (delta, std_deg, conf, NAN, False), NAN4, NAN3, NAN3
    h = (delta, std_deg, conf, (delta % TWO_PI) * RAD2DEG, conv > 0.0)
    if not h[4]:
        return h, NAN4, NAN3, NAN3
    c, sn = math.cos(delta / 2.0), math.sin(delta / 2.0)
    w, x, y, z = q_now
    qw, qx, qy, qz = c * w - sn * z, c * x - sn * y, c * y + sn * x, c * z + sn * w
    ax, ay, az = x_axis(q_pair)
    cd, sd = math.cos(delta), math.sin(delta)
    return h, (qw, qx, qy, qz), x_axis((qw, qx, qy, qz)), (cd * ax - sd * ay, sd * ax + cd * ay, az)


def x_axis(q: Sequence[float]) -> Vec:
    """The image of the x axis under unit quaternion ``q`` (w, x, y, z)."""
    w, x, y, z = q
    return 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)


def _acos_deg(c: float) -> float:
    return math.acos(-1.0 if c < -1.0 else 1.0 if c > 1.0 else c) * RAD2DEG  # NaN passes


def angles(
    x_now: Sequence[float],
    x_c: Sequence[float],
    p_e: Sequence[float],
    sh: Sequence[float],
    nom: Sequence[float],
    norm: str,
) -> tuple[float, float, float, float, float]:
    """For one row: the elbow angle (eq. 11, °) between the upper arm ``x_now`` and the
    forearm ``x_c``; the shoulder's displacement from the nominal one (horizontal or 3D, m);
    the robot-only baseline's elbow angle (°: the shoulder assumed fixed at the nominal
    point, ``x_A = normalize(p_E − p_S,nom)``); the upper arm's elevation (0° hanging,
    90° horizontal) and azimuth (0° = +y, 90° = +x), °."""
    angle = angle_deg(x_now, x_c)
    dx, dy, dz = sh[0] - nom[0], sh[1] - nom[1], sh[2] - nom[2]
    sq = dx * dx + dy * dy
    if norm == "3d":
        sq = sq + dz * dz
    conv = angle_deg(unit(p_e[0] - nom[0], p_e[1] - nom[1], p_e[2] - nom[2]), x_c)
    elev = _acos_deg(-x_now[2])
    return angle, math.sqrt(sq), conv, elev, math.atan2(x_now[0], x_now[1]) * RAD2DEG


def unit(x: float, y: float, z: float) -> Vec:
    n = math.sqrt((x * x + y * y) + z * z)
    if not n > 0.0:
        n = NAN
    return x / n, y / n, z / n


def angle_deg(a: Sequence[float], b: Sequence[float]) -> float:
    """Angle between unit vectors, ° (eq. 11 for x_A and x_C)."""
    return _acos_deg((a[0] * b[0] + a[1] * b[1]) + a[2] * b[2])


def extrapolate(x_c: Sequence[float], prev: Sequence[float], dt: float, latency: float) -> Vec:
    """The forearm axis carried ``latency`` s forward along its last robot step (``dt`` s)."""
    step = latency / dt if 0.0 < dt < 0.2 else 0.0
    return unit(*(c + step * (c - p) for c, p in zip(x_c, prev, strict=True)))


def shoulder(p_e: Sequence[float], x_a: Sequence[float], la: float) -> Vec:
    """Shoulder (eq. 12): ``p_S = p_E − l_A · x_A``."""
    return p_e[0] - la * x_a[0], p_e[1] - la * x_a[1], p_e[2] - la * x_a[2]
