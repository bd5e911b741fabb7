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

from dataclasses import dataclass
from typing import NamedTuple, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.wearable import kernel

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
R_S0: F64 = kernel.R_S0


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
R_U3: F64 = kernel.R_U3


class Pose(NamedTuple):
    """Arm pose in S: joint axes ``axes`` (5,3); ``R_SU``, ``R_SF`` (3,3); ``elbow``, ``wrist``
    (3,) m."""

    axes: F64
    R_SU: F64
    R_SF: F64
    elbow: F64
    wrist: F64


def pose(theta: F64, upper_arm_m: float, forearm_m: float) -> Pose:
    """Forward kinematics of the DH chain (eqs. 10, 11) for ``θ`` (5,) rad (the rows of
    :func:`dh_table`, evaluated by :func:`estimators.wearable.kernel.pose`)."""
    axes, r_su, r_sf, elbow, wrist = kernel.pose(
        np.asarray(theta, dtype=np.float64), float(upper_arm_m), float(forearm_m)
    )
    return Pose(axes, r_su, r_sf, elbow, wrist)


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
    The arithmetic is :func:`estimators.wearable.kernel.sensors` (compiled).
    """
    f = np.float64
    vals, jac = kernel.sensors(
        np.asarray(theta, dtype=f),
        np.asarray(dtheta, dtype=f),
        np.asarray(ddtheta, dtype=f),
        float(geo.upper_arm_m),
        float(geo.forearm_m),
        np.asarray(geo.r_u, dtype=f),
        np.ascontiguousarray(geo.R_UI, dtype=f),
        np.asarray(geo.r_f, dtype=f),
        np.ascontiguousarray(geo.R_FI, dtype=f),
        body,
        jacobian,
    )
    gu, au, gf, af, e, w = (vals[k] for k in range(6))
    if not jacobian:
        return Sensors(gu, au, gf, af, e, w, None, None, None, None, None, None)
    jgu, jau, jgf, jaf, je, jw = (np.ascontiguousarray(jac[k].T) for k in range(6))
    return Sensors(gu, au, gf, af, e, w, jgu, jau, jgf, jaf, je, jw)
