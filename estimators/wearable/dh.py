"""Denavit–Hartenberg model of the arm (Alizadegan & Behzadipour 2016, §2.1, tables 1–4,
eqs. 10–15), written onto the contract's frames and angles (contract §8).

Frames and angles are the contract's: S (x forward, y left, z up, origin at the shoulder),
``R_SU = Ry(−θ0)·Rx(−θ1)·Rz(θ2)`` and ``R_UF = Ry(−θ4)·Rz(θ5)`` for a right arm. The joint
vector is ``θ = [θ0, θ1, θ2, θ4, θ5]`` (paper eq. 2), in radians, indices 0..4 here.

Mapping onto the paper: every DH row is ``Rz(γ)·Tz(λ)·Rx(β)·Tx(δ)`` (eq. 10) and the rows
have the structure of the paper's tables (joint rows 1–3 at the shoulder, a fixed row 4 with
``γ = π/2`` that carries the upper-arm length to the elbow, joint rows 5–6 at the elbow, a row
7 with the forearm length to the wrist). The paper's base frame 0 is not drawn in a usable
way in the text; ours is fixed by a constant rotation ``R_S0`` chosen so that each DH joint
turns about the contract's axis with the contract's sign: frame 0 has ``x`` down, ``y``
forward and ``z`` to the right (−y_S), so a positive γ1 = θ0 is ``Ry(−θ0)``; the β's are
the paper's ±π/2 with the signs that make rows 2, 3, 5, 6 equal ``Rx(−θ1)``, ``Rz(θ2)``,
``Ry(−θ4)`` and ``Rz(θ5)``; λ4 = −l_u and λ7 = −l_f because U's and F's z point up (proximally)
in the zero pose where the paper's point distally. The IMU mounting (the paper's u and f rows,
tables 1 and 3) is the contract's fixed pose of the IMU in its segment (position + rotation);
:func:`paper_mounting` converts the paper's strap parameters (l_u3, θ_u4, l_u5) into it.

The recursive kinematics (eqs. 12–14) is evaluated in S coordinates: joint ``j`` turns about
the unit axis ``a_j`` (the z axis of the DH frame before it, in S), the frame after joint ``k``
turns at ``w_k = Σ_{j≤k} a_j θ̇_j`` (eq. 12), accelerates at
``α_k = Σ_{j≤k} a_j θ̈_j + w_{j−1} × a_j θ̇_j`` (eq. 13), and a point ``r`` fixed in it at
``p̈ = p̈_o + α × r + ω × (ω × r)`` (eq. 14). The same sums are differentiated analytically
with respect to θ, θ̇ and θ̈ for the EKF (an infinitesimal change of θ_m turns everything
beyond joint m about ``a_m``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, TypeAlias

import numpy as np
from numpy.typing import NDArray

F64: TypeAlias = NDArray[np.float64]
I64: TypeAlias = NDArray[np.intp]

G = 9.81  # m/s², gravity; the paper's eq. 9
JOINTS = (
    "shoulder_flexion",
    "shoulder_abduction",
    "shoulder_rotation",
    "elbow_flexion",
    "forearm_pronation",
)
UPPER = 2  # index of the last joint of the upper arm (θ2)
FORE = 4  # index of the last joint of the forearm (θ5)
_HALF_PI = 0.5 * np.pi

# R_S0: columns are frame 0's axes in S (x down, y forward, z = −y_S).
R_S0: F64 = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])


def dh(gamma: float, lam: float, beta: float, delta: float) -> tuple[F64, F64]:
    """Eq. 10: ``Rz(γ)·Tz(λ)·Rx(β)·Tx(δ)`` as (R (3,3), p (3,)), angles rad, lengths m."""
    cg, sg, cb, sb = np.cos(gamma), np.sin(gamma), np.cos(beta), np.sin(beta)
    r = np.array([[cg, -sg * cb, sg * sb], [sg, cg * cb, -cg * sb], [0.0, sb, cb]])
    p = np.array([delta * cg, delta * sg, lam])
    return r, p


def dh_table(theta: F64, upper_arm_m: float, forearm_m: float) -> list[tuple[float, ...]]:
    """The contract's DH table, rows (γ, λ, β, δ) 1–7 (cf. the paper's tables 2 and 4).

    Frame 3 is the upper arm (U up to a constant turn), frame 4 is at the elbow, frame 6 is the
    forearm F and frame 7 is at the wrist.
    """
    t0, t1, t2, t4, t5 = (float(v) for v in theta)
    return [
        (t0, 0.0, _HALF_PI, 0.0),
        (t1 + _HALF_PI, 0.0, -_HALF_PI, 0.0),
        (t2, 0.0, 0.0, 0.0),
        (_HALF_PI, -upper_arm_m, _HALF_PI, 0.0),
        (t4, 0.0, -_HALF_PI, 0.0),
        (t5, 0.0, 0.0, 0.0),
        (0.0, -forearm_m, 0.0, 0.0),
    ]


# Frame 3 of the table in U's axes (x3 = −y_U, y3 = x_U, z3 = z_U); frame 6 is F itself.
R_U3: F64 = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
_JOINT_ROWS = (0, 1, 2, 4, 5)  # the table rows whose γ is a joint angle
_RX = {b: dh(0.0, 0.0, b, 0.0)[0] for b in (0.0, _HALF_PI, -_HALF_PI)}


class Pose(NamedTuple):
    """Arm pose in S: joint axes ``axes`` (5,3); ``R_SU``, ``R_SF`` (3,3); ``elbow``, ``wrist``
    (3,) m."""

    axes: F64
    R_SU: F64
    R_SF: F64
    elbow: F64
    wrist: F64


def pose(theta: F64, upper_arm_m: float, forearm_m: float) -> Pose:
    """Forward kinematics of the DH chain (eqs. 10, 11) for ``θ`` (5,) rad."""
    rot = R_S0
    pos = np.zeros(3)
    axes = np.empty((5, 3))
    frames: list[tuple[F64, F64]] = []
    j = 0
    for i, (gamma, lam, beta, _) in enumerate(dh_table(theta, upper_arm_m, forearm_m)):
        if i in _JOINT_ROWS:
            axes[j] = rot[:, 2]
            j += 1
        if lam:  # eq. 11: the rows here translate along z only (δ = 0)
            pos = pos + lam * rot[:, 2]
        cg, sg = math.cos(gamma), math.sin(gamma)
        rot = rot @ (np.array([[cg, -sg, 0.0], [sg, cg, 0.0], [0.0, 0.0, 1.0]]) @ _RX[beta])
        frames.append((rot, pos))
    r_su = frames[2][0] @ R_U3.T
    return Pose(axes, r_su, frames[5][0], frames[3][1], frames[6][1])


def rot_x(a: float) -> F64:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> F64:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> F64:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quat_to_matrix(q: F64 | tuple[float, ...]) -> F64:
    """Rotation matrix of a unit quaternion ``[w, x, y, z]`` (Hamilton, active)."""
    w, x, y, z = (float(v) for v in np.asarray(q, dtype=np.float64) / np.linalg.norm(q))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(r: F64) -> F64:
    """Unit quaternion ``[w, x, y, z]`` (w ≥ 0) of a rotation matrix."""
    tr = float(np.trace(r))
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(r)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k])
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (r[k, j] - r[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (r[j, i] + r[i, j]) / s
        q[1 + k] = (r[k, i] + r[i, k]) / s
    out = np.array(q)
    return out if out[0] >= 0 else -out


def contract_rotations(theta: F64) -> tuple[F64, F64]:
    """``R_SU`` and ``R_SF`` written out from contract §8 (the check of the DH chain)."""
    t0, t1, t2, t4, t5 = (float(v) for v in theta)
    r_su = rot_y(-t0) @ rot_x(-t1) @ rot_z(t2)
    return r_su, r_su @ rot_y(-t4) @ rot_z(t5)


def paper_mounting(along_m: float, strap_rad: float, radius_m: float) -> tuple[F64, F64]:
    """The paper's strap parameters (table 1: l_u3, θ_u4, l_u5; table 3: l_f6, θ_f7, l_f8) as
    the contract's mounting: (position (3,) m, rotation IMU→segment (3,3)).

    The IMU sits ``along_m`` down the segment's long axis from its proximal joint, on the skin
    at ``radius_m``; its z axis points out of the skin at ``strap_rad`` about the long axis,
    measured from forward (x) toward lateral (−y), so π/2 puts z along the elbow's flexion axis
    (table 7's reading); its y axis points proximally along the segment (the paper's DH row 5,
    β = π/2, turns the long axis into y).
    """
    radial = np.array([np.cos(strap_rad), -np.sin(strap_rad), 0.0])
    y_axis = np.array([0.0, 0.0, 1.0])
    x_axis = np.cross(y_axis, radial)
    rot = np.column_stack((x_axis, y_axis, radial))
    return np.array([0.0, 0.0, -along_m]) + radius_m * radial, rot


@dataclass(frozen=True, slots=True)
class Geometry:
    """Arm and mounting geometry (right arm, contract §8), metres.

    ``r_u``/``r_f`` (3,): IMU positions in U/F; ``R_UI``/``R_FI`` (3,3): IMU axes in U/F.
    """

    upper_arm_m: float
    forearm_m: float
    r_u: F64
    R_UI: F64
    r_f: F64
    R_FI: F64


class Sensors(NamedTuple):
    """Predicted readings: gyros (rad/s) and specific forces (m/s²) in each IMU's frame (3,);
    elbow and wrist positions (3,) in S. ``J*`` are their Jacobians (3, 3·5): columns
    ``[∂/∂θ̈ (5), ∂/∂θ̇ (5), ∂/∂θ (5)]``, the state order of eq. 1 (None unless asked)."""

    gyr_u: F64
    acc_u: F64
    gyr_f: F64
    acc_f: F64
    elbow: F64
    wrist: F64
    J_gyr_u: F64 | None
    J_acc_u: F64 | None
    J_gyr_f: F64 | None
    J_acc_f: F64 | None
    J_elbow: F64 | None
    J_wrist: F64 | None


_GZ = np.array([0.0, 0.0, G])
_MASK_U = np.array([1.0, 1.0, 1.0, 0.0, 0.0])[:, None]


def _cross(a: F64, b: F64) -> F64:
    """Row-wise cross product (numpy's np.cross is slow for small arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def sensors(
    theta: F64,
    dtheta: F64,
    ddtheta: F64,
    geo: Geometry,
    body: bool = True,
    jacobian: bool = True,
) -> Sensors:
    """Predicted IMU readings and joint positions (eqs. 12–18, 11) with analytic Jacobians.

    ``theta``, ``dtheta``, ``ddtheta`` (5,) in rad, rad/s, rad/s². ``body=False`` leaves the
    body acceleration out of the accelerometers (the inclinometer model of models B, C).
    """
    ps = pose(theta, geo.upper_arm_m, geo.forearm_m)
    a = ps.axes
    # eq. 12, 13 in S: partial angular velocities and accelerations after each joint
    wj = a * dtheta[:, None]
    w = np.cumsum(wj, axis=0)
    wprev = np.vstack((np.zeros((1, 3)), w[:-1]))
    wxa = _cross(wprev, a)
    alpha = np.cumsum(a * ddtheta[:, None] + wxa * dtheta[:, None], axis=0)
    w_u, w_f, al_u, al_f = w[UPPER], w[FORE], alpha[UPPER], alpha[FORE]
    elbow = ps.elbow
    d_u = ps.R_SU @ geo.r_u
    d_f = ps.R_SF @ geo.r_f
    d_w = ps.wrist - elbow
    R_SIu = ps.R_SU @ geo.R_UI
    R_SIf = ps.R_SF @ geo.R_FI

    def acc_at(al: F64, om: F64, r: F64) -> F64:
        return _cross1(al, r) + _cross1(om, _cross1(om, r))  # eq. 14 with a fixed origin term

    acc_e = acc_at(al_u, w_u, elbow)
    pdd_u = acc_at(al_u, w_u, d_u)
    pdd_f = acc_e + acc_at(al_f, w_f, d_f)
    v_au = (pdd_u if body else 0.0) + _GZ  # eqs. 17, 18: specific force = gravity + body acc
    v_af = (pdd_f if body else 0.0) + _GZ
    gyr_u, acc_u = w_u @ R_SIu, v_au @ R_SIu
    gyr_f, acc_f = w_f @ R_SIf, v_af @ R_SIf
    wrist = ps.wrist
    if not jacobian:
        return Sensors(gyr_u, acc_u, gyr_f, acc_f, elbow, wrist, None, None, None, None, None, None)

    # Derivatives as (15, 3) arrays: rows 0–4 ∂/∂θ̈_m, 5–9 ∂/∂θ̇_m, 10–14 ∂/∂θ_m.
    # ∂/∂θ_m: everything beyond joint m turns about a_m.
    mask_u = _MASK_U
    du, df = w_u - w, w_f - w
    zero = np.zeros((5, 3))
    dw_u = np.vstack((zero, a * mask_u, _cross(a, du) * mask_u))
    dw_f = np.vstack((zero, a, _cross(a, df)))
    dal_u = np.vstack(
        (
            a,
            wxa + _cross(a, du),
            _cross(a, (al_u - alpha) - _cross(w, du)) + _cross(w, _cross(a, du)),
        )
    ) * np.vstack((mask_u, mask_u, mask_u))
    dal_f = np.vstack(
        (
            a,
            wxa + _cross(a, df),
            _cross(a, (al_f - alpha) - _cross(w, df)) + _cross(w, _cross(a, df)),
        )
    )
    # a_m × v for single vectors v, as one product with the stacked axes
    cross_a = a @ _skew_stack(ps.elbow, d_u, d_f, d_w, w_u, w_f, v_au, v_af)
    de, ddu, ddf, dwr, ax_wu, ax_wf, ax_vu, ax_vf = (
        cross_a[:, 3 * k : 3 * k + 3] for k in range(8)
    )
    de, ddu, ax_wu, ax_vu = de * mask_u, ddu * mask_u, ax_wu * mask_u, ax_vu * mask_u
    zeros10 = np.zeros((10, 3))

    def dacc(dal: F64, dom: F64, al: F64, om: F64, r: F64, dr: F64) -> F64:
        """∂(α × r + ω × (ω × r)) for (15, 3) ∂α, ∂ω and ∂r (only θ rows move r)."""
        k_r, k_om = _skew(r), _skew(om)
        out = dal @ k_r + dom @ _skew(_cross1(om, r)) - (dom @ k_r) @ k_om
        out[10:] += -(dr @ _skew(al)) + (dr @ k_om) @ k_om
        return out

    # gyros: z = R_SI^T ω, ∂z/∂θ_m = R_SI^T (∂ω − a_m × ω) for joints before the IMU
    g_u = dw_u.copy()
    g_u[10:] -= ax_wu
    g_f = dw_f.copy()
    g_f[10:] -= ax_wf
    if body:
        e_all = dacc(dal_u, dw_u, al_u, w_u, elbow, de)
        a_u = dacc(dal_u, dw_u, al_u, w_u, d_u, ddu)
        a_f = e_all + dacc(dal_f, dw_f, al_f, w_f, d_f, ddf)
    else:
        a_u = np.zeros((15, 3))
        a_f = np.zeros((15, 3))
    a_u[10:] -= ax_vu
    a_f[10:] -= ax_vf
    j_gu = (g_u @ R_SIu).T
    j_gf = (g_f @ R_SIf).T
    j_au = (a_u @ R_SIu).T
    j_af = (a_f @ R_SIf).T
    j_e = np.vstack((zeros10, de)).T
    j_w = np.vstack((zeros10, de + dwr)).T
    return Sensors(gyr_u, acc_u, gyr_f, acc_f, elbow, wrist, j_gu, j_au, j_gf, j_af, j_e, j_w)


def _skew(v: F64) -> F64:
    """``K`` with ``a @ K == a × v`` for rows ``a``."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def _skew_stack(*vs: F64) -> F64:
    """Side-by-side :func:`_skew` of several vectors, (3, 3·k)."""
    x, y, z = np.array(vs).T
    o = np.zeros_like(x)
    return np.array([[o, -z, y], [z, o, -x], [-y, x, o]]).transpose(0, 2, 1).reshape(3, -1)


def _cross1(a: F64, b: F64) -> F64:
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
