"""Per-row formulas of the pipeline's last stage (paper eqs. 9–12), written once for both
Python floats and numpy arrays.

The live service polls after every robot sample, so a row is usually computed alone; numpy's
per-call overhead would then cost ~20× the arithmetic. ``rehab analyze`` computes thousands
of rows at once, where numpy wins. Both run the *same* expressions below, with a namespace
``M`` that is either :data:`SCALAR` (floats) or :data:`VECTOR` (arrays of shape (n,)):

- arithmetic (``+ - * /``), comparisons and ``sqrt`` are IEEE-exact in both;
- the transcendental functions are Python's ``math`` in both (mapped over the array in
  :data:`VECTOR`), because numpy's may be SIMD versions with other last bits; ``%`` is
  ``np.remainder`` in :data:`VECTOR`, which is exact like Python's (``fmod``, then the same
  sign fix-up);
- sums are written out in a fixed order (numpy's reductions pair terms differently);
- both branches of a ``where`` are evaluated, so nothing may raise on NaN or on the
  discarded branch: squares are ``x * x`` (``**`` raises on overflow), divisors are kept
  non-zero, ``acos`` gets clipped input.

So a row has bit-identical values however the rows are batched (tested).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from functools import partial
from types import SimpleNamespace
from typing import Any, NamedTuple

import numpy as np

RAD2DEG = 180.0 / math.pi
TWO_PI = 2.0 * math.pi
DRIFT_STD_RAD_S = math.radians(0.1)  # heading uncertainty growth between updates, rad/s
NAN = math.nan
INF = math.inf


def _s_where(c: Any, a: Any, b: Any) -> Any:
    return a if c else b


def _s_maximum(a: float, b: float) -> float:
    return a if (a >= b or a != a) else b  # NaN propagates, as np.maximum


def _s_clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x  # NaN passes, as np.clip


def _s_mod(x: float, m: float) -> float:
    return x % m if math.isfinite(x) else NAN


def _s_atan2(y: float, x: float) -> float:
    return math.atan2(y, x)


def _s_trig(f: Callable[[float], float]) -> Callable[[float], float]:
    def g(x: float) -> float:
        return f(x) if math.isfinite(x) else NAN

    return g


def _s_not(a: bool) -> bool:
    return not a


# The two namespaces are plain objects, not classes of static methods: the same attribute
# calls, and a compiled build (scripts/build_native.py) keeps them as they are.
SCALAR: Any = SimpleNamespace(
    where=_s_where,
    maximum=_s_maximum,
    clip=_s_clip,
    mod=_s_mod,
    atan2=_s_atan2,
    cos=_s_trig(math.cos),
    sin=_s_trig(math.sin),
    acos=math.acos,  # only ever given clipped input
    sqrt=math.sqrt,  # only ever given sums of squares
    isfinite=math.isfinite,
    not_=_s_not,
)
"""Namespace for Python floats and bools."""


def _v_map(f: Callable[..., float], *a: Any) -> Any:
    cols = [np.asarray(x, dtype=np.float64).tolist() for x in a]
    return np.fromiter(map(f, *cols), dtype=np.float64, count=len(cols[0]))


def _v_trig(f: Callable[[float], float], x: Any) -> Any:
    """:func:`_s_trig` ``(f)`` over an array: ``math`` straight on the finite values (a
    Python wrapper per element cost twice the function), NaN where not finite."""
    a = np.asarray(x, dtype=np.float64)
    fin = np.isfinite(a)
    if fin.all():
        return np.fromiter(map(f, a.tolist()), dtype=np.float64, count=len(a))
    out = np.fromiter(map(f, np.where(fin, a, 0.0).tolist()), dtype=np.float64, count=len(a))
    out[~fin] = NAN
    return out


def _v_mod(x: Any, m: float) -> Any:
    # np.remainder is Python's float % (fmod, exact, then the same sign fix-up)
    a = np.asarray(x, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(a), np.remainder(a, m), NAN)


def _v_not(a: Any) -> Any:
    return ~a


VECTOR: Any = SimpleNamespace(
    where=np.where,
    maximum=np.maximum,
    clip=np.clip,
    sqrt=np.sqrt,  # correctly rounded, as math.sqrt
    isfinite=np.isfinite,
    mod=_v_mod,
    atan2=partial(_v_map, math.atan2),
    cos=partial(_v_trig, math.cos),
    sin=partial(_v_trig, math.sin),
    acos=partial(_v_map, math.acos),
    not_=_v_not,
)
"""Namespace for numpy arrays of shape (n,), bit-identical to ``SCALAR``."""


def nlerp(M: Any, a: Sequence[Any], b: Sequence[Any], s: Any) -> tuple[Any, ...]:
    """Normalised linear interpolation of unit quaternions ``a``, ``b`` (w, x, y, z), shortest
    arc, ``s`` in [0, 1]. Between IMU samples it differs from slerp far below sensor noise."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    sign = M.where(((aw * bw + ax * bx) + ay * by) + az * bz < 0.0, -1.0, 1.0)
    w = aw + s * (sign * bw - aw)
    x = ax + s * (sign * bx - ax)
    y = ay + s * (sign * by - ay)
    z = az + s * (sign * bz - az)
    n = M.sqrt(((w * w + x * x) + y * y) + z * z)
    n = M.where(n > 0.0, n, NAN)
    return w / n, x / n, y / n, z / n


def predict(
    M: Any, q: Sequence[Any], w: Sequence[Any], dw: Sequence[Any], dt: Any
) -> tuple[Any, ...]:
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
    n = M.sqrt(((rw * rw + rx * rx) + ry * ry) + rz * rz)
    n = M.where(n > 0.0, n, NAN)
    return rw / n, rx / n, ry / n, rz / n


def nlerp_scalar(
    a: Sequence[float], b: Sequence[float], s: float
) -> tuple[float, float, float, float]:
    """``nlerp(SCALAR, ...)`` with the ``where`` branches taken as ``if`` (bit-identical,
    tested): one row's orientation look-up calls it twice."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    if ((aw * bw + ax * bx) + ay * by) + az * bz < 0.0:  # no NaN here: -b is -1.0 · b
        bw, bx, by, bz = -bw, -bx, -by, -bz
    w = aw + s * (bw - aw)
    x = ax + s * (bx - ax)
    y = ay + s * (by - ay)
    z = az + s * (bz - az)
    n = math.sqrt(((w * w + x * x) + y * y) + z * z)
    if not n > 0.0:
        n = NAN
    return w / n, x / n, y / n, z / n


def predict_scalar(
    q: Sequence[float], w: Sequence[float], dw: Sequence[float], dt: float
) -> tuple[float, float, float, float]:
    """``predict(SCALAR, ...)`` with the ``where`` taken as ``if`` (bit-identical, tested)."""
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


class Heading(NamedTuple):
    """Heading offset per row and what follows from it (all (n,) or floats)."""

    delta: Any  # rad, NaN where unusable
    std_deg: Any  # heading uncertainty, °, NaN where none
    confidence: Any  # 0..1
    offset_deg: Any  # δ in [0, 360) °, NaN where none
    good: Any  # bool: a converged heading applies


def heading(
    M: Any,
    s: Any,
    ok: Any,
    snap: Sequence[Any],
    seg: Any,
) -> Heading:
    """The heading at row time ``s`` (s) from the latest update snapshot
    ``(t, δ, rate, t_update, std, converged, segment, latency)``: drift predicted linearly
    (improved method), its uncertainty grown by 0.1 °/s since the update. ``ok``: the IMU
    orientation exists at the row; ``seg``: its IMU segment (a reset voids the heading)."""
    _, d, rate, t_upd, std0, conv, sseg, _ = snap
    use = ok & M.isfinite(d) & (sseg == seg)
    since = M.maximum(0.0, s - t_upd)
    delta = M.where(use, d + rate * (s - t_upd), NAN)
    grow = DRIFT_STD_RAD_S * since
    std = M.where(use, M.sqrt(std0 * std0 + grow * grow), INF)
    good = use & (conv > 0.0) & M.isfinite(delta)
    std_deg = std * RAD2DEG
    finite = M.isfinite(std_deg)
    r = std_deg / 3.0
    conf = M.where(finite, 1.0 / (1.0 + r * r), 0.0)
    offset = M.where(M.isfinite(delta) & ok, M.mod(delta, TWO_PI) * RAD2DEG, NAN)
    return Heading(delta, M.where(finite, std_deg, NAN), conf, offset, good)


def upper_arm(
    M: Any, delta: Any, good: Any, q_now: Sequence[Any], q_pair: Sequence[Any]
) -> tuple[tuple[Any, ...], tuple[Any, ...], tuple[Any, ...]]:
    """``q_RA = Rz(δ) ⊗ q_IA`` (eqs. 9–10) now, its x axis now, and the x axis ``x_A`` at the
    instant the robot measured the elbow (``q_pair``); NaN where not ``good``."""
    h = delta / 2.0
    c, sn = M.cos(h), M.sin(h)
    w, x, y, z = q_now
    qw = M.where(good, c * w - sn * z, NAN)
    qx = M.where(good, c * x - sn * y, NAN)
    qy = M.where(good, c * y + sn * x, NAN)
    qz = M.where(good, c * z + sn * w, NAN)
    xn = _x_axis(qw, qx, qy, qz)
    pw, px, py, pz = q_pair
    ax, ay, az = _x_axis(pw, px, py, pz)
    cd, sd = M.cos(delta), M.sin(delta)
    xa = (
        M.where(good, cd * ax - sd * ay, NAN),
        M.where(good, sd * ax + cd * ay, NAN),
        M.where(good, az, NAN),
    )
    return (qw, qx, qy, qz), xn, xa


NAN3 = (NAN, NAN, NAN)
NAN4 = (NAN, NAN, NAN, NAN)


def heading_arm_scalar(
    s: float,
    ok: bool,
    snap: Sequence[float],
    seg: float,
    q_now: Sequence[float],
    q_pair: Sequence[float],
) -> tuple[
    tuple[float, float, float, float, bool], tuple[float, ...], tuple[float, ...], tuple[float, ...]
]:
    """``heading(SCALAR, ...)`` then ``upper_arm(SCALAR, ...)`` for one row, the same
    expressions in the same order (bit-identical, tested) with the ``where`` branches taken
    as ``if``: the live pipeline computes one row per robot sample, where the generic
    namespace's calls cost twice the arithmetic. Returns the heading as a plain tuple in
    :class:`Heading`'s order (a named tuple costs as much as the rest of the heading),
    ``q_RA``, its x axis now and ``x_A`` at the robot's instant."""
    _, d, rate, t_upd, std0, conv, sseg, _ = snap
    if not (ok and math.isfinite(d) and sseg == seg):
        return (NAN, NAN, 0.0, NAN, False), NAN4, NAN3, NAN3
    since = s - t_upd
    delta = d + rate * since
    if not since > 0.0:  # M.maximum(0.0, since): NaN stays NaN
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
    pw, px, py, pz = q_pair
    ax, ay, az = (
        1.0 - 2.0 * (py * py + pz * pz),
        2.0 * (px * py + pw * pz),
        2.0 * (px * pz - pw * py),
    )
    cd, sd = math.cos(delta), math.sin(delta)
    return (
        h,
        (qw, qx, qy, qz),
        (1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy + qw * qz), 2.0 * (qx * qz - qw * qy)),
        (cd * ax - sd * ay, sd * ax + cd * ay, az),
    )


def _s_acos_deg(c: float) -> float:
    return math.acos(-1.0 if c < -1.0 else 1.0 if c > 1.0 else c) * RAD2DEG  # NaN passes


def angles_scalar(
    x_now: Sequence[float],
    x_c: Sequence[float],
    p_e: Sequence[float],
    sh: Sequence[float],
    nom: Sequence[float],
    norm: str,
) -> tuple[float, float, float, float, float]:
    """For one row, with the expressions of the generic functions (bit-identical, tested):
    ``angle_deg(x_now, x_c)``, ``displacement(sh, nom)``, ``conventional_angle(p_e, nom,
    x_c)`` and ``elevation_azimuth(x_now)``."""
    angle = _s_acos_deg((x_now[0] * x_c[0] + x_now[1] * x_c[1]) + x_now[2] * x_c[2])
    dx, dy, dz = sh[0] - nom[0], sh[1] - nom[1], sh[2] - nom[2]
    sq = dx * dx + dy * dy
    if norm == "3d":
        sq = sq + dz * dz
    x, y, z = p_e[0] - nom[0], p_e[1] - nom[1], p_e[2] - nom[2]
    n = math.sqrt((x * x + y * y) + z * z)
    if not n > 0.0:
        n = NAN
    conv = _s_acos_deg(((x / n) * x_c[0] + (y / n) * x_c[1]) + (z / n) * x_c[2])
    elev = _s_acos_deg(-x_now[2])
    return angle, math.sqrt(sq), conv, elev, math.atan2(x_now[0], x_now[1]) * RAD2DEG


def _x_axis(w: Any, x: Any, y: Any, z: Any) -> tuple[Any, Any, Any]:
    return 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)


def unit(M: Any, v: Sequence[Any]) -> tuple[Any, ...]:
    x, y, z = v
    n = M.sqrt((x * x + y * y) + z * z)
    n = M.where(n > 0.0, n, NAN)
    return x / n, y / n, z / n


def unit_scalar(x: float, y: float, z: float) -> tuple[float, float, float]:
    """``unit(SCALAR, (x, y, z))`` with the ``where`` taken as ``if`` (bit-identical, tested)."""
    n = math.sqrt((x * x + y * y) + z * z)
    if not n > 0.0:
        n = NAN
    return x / n, y / n, z / n


def angle_deg(M: Any, a: Sequence[Any], b: Sequence[Any]) -> Any:
    """Angle between unit vectors, ° (eq. 11 for x_A and x_C)."""
    c = (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
    return M.acos(M.clip(c, -1.0, 1.0)) * RAD2DEG


def extrapolate(
    M: Any, x_c: Sequence[Any], prev: Sequence[Any], dt: Any, latency: Any
) -> tuple[Any, ...]:
    """The forearm axis carried ``latency`` s forward along its last robot step (``dt`` s)."""
    step = M.where((dt > 0.0) & (dt < 0.2), latency / M.where(dt > 0.0, dt, 1.0), 0.0)
    return unit(M, tuple(c + step * (c - p) for c, p in zip(x_c, prev, strict=True)))


def conventional_angle(
    M: Any, p_e: Sequence[Any], nominal: Sequence[Any], x_c: Sequence[Any]
) -> Any:
    """The robot-only baseline's elbow angle, °: the shoulder assumed fixed at the nominal
    point, ``x_A = normalize(p_E − p_S,nom)``; NaN without a nominal shoulder."""
    x_a = unit(M, (p_e[0] - nominal[0], p_e[1] - nominal[1], p_e[2] - nominal[2]))
    return angle_deg(M, x_a, x_c)


def elevation_azimuth(M: Any, x: Sequence[Any]) -> tuple[Any, Any]:
    """Upper-arm elevation (0° hanging, 90° horizontal) and azimuth (0° = +y, 90° = +x), °."""
    elev = M.acos(M.clip(-x[2], -1.0, 1.0)) * RAD2DEG
    return elev, M.atan2(x[0], x[1]) * RAD2DEG


def shoulder(p_e: Sequence[Any], x_a: Sequence[Any], la: Any) -> tuple[Any, ...]:
    """Shoulder (eq. 12): ``p_S = p_E − l_A · x_A``."""
    return p_e[0] - la * x_a[0], p_e[1] - la * x_a[1], p_e[2] - la * x_a[2]


def displacement(M: Any, s: Sequence[Any], nom: Sequence[Any], norm: str) -> Any:
    """Distance from the nominal shoulder: horizontal (x, y) or 3D, m."""
    dx, dy, dz = s[0] - nom[0], s[1] - nom[1], s[2] - nom[2]
    sq = dx * dx + dy * dy
    if norm == "3d":
        sq = sq + dz * dz
    return M.sqrt(sq)
