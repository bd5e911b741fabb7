"""Segment kinematics of the inertial-robotic method (Passon et al. 2020, §3.2.1, §3.3).

All positions in metres in the robot frame R unless noted; arrays are (N, 3).
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators import quaternion as quat

Array: TypeAlias = NDArray[np.float64]
GRAVITY = np.array([0.0, 0.0, 9.81])


def unit(v: Array) -> Array:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n  # type: ignore[no-any-return]


def elbow_from_cuffs(wrist: Array, proximal: Array, cuff_to_elbow_m: float) -> tuple[Array, Array]:
    """Elbow position (eq. 13) and forearm axis ``x_C`` (elbow → wrist), both (N, 3).

    ``p_E = p_P + l_p · normalize(p_P − p_W)``.
    """
    x_c = unit(wrist - proximal)
    return proximal - cuff_to_elbow_m * x_c, x_c


def elbow_angle_deg(x_a: Array, x_c: Array) -> Array:
    """Elbow flexion (eq. 11): angle between ``x_A`` (shoulder → elbow) and ``x_C``; 0° extended."""
    c = np.clip(np.sum(x_a * x_c, axis=-1), -1.0, 1.0)
    return np.degrees(np.arccos(c))  # type: ignore[no-any-return]


def shoulder_position(p_e: Array, x_a: Array, upper_arm_length_m: float | Array) -> Array:
    """Shoulder (eq. 12): ``p_S = p_E − l_A · x_A``."""
    la = np.asarray(upper_arm_length_m, dtype=np.float64)
    if la.ndim == 1:
        la = la[:, None]
    out: Array = p_e - la * x_a
    return out


def conventional(p_e: Array, x_c: Array, nominal_shoulder: Array) -> tuple[Array, Array]:
    """The robot-only baseline: the shoulder is assumed fixed at the nominal point.

    Returns ``(x_A, elbow angle °)`` with ``x_A = normalize(p_E − p_S,nom)``.
    """
    x_a = unit(p_e - nominal_shoulder)
    return x_a, elbow_angle_deg(x_a, x_c)


def joint_specific_force(f: Array, gyr: Array, gyr_dot: Array, r: Array) -> Array:
    """Specific force at the joint in the IMU frame (eq. 1).

    ``f_E = f + ω × (ω × r) + ω̇ × r``; f (N,3) m/s², ω (N,3) rad/s, ω̇ (N,3) rad/s², r (3,) m.
    """
    out: Array = f + np.cross(gyr, np.cross(gyr, r)) + np.cross(gyr_dot, r)
    return out


def inertial_acceleration(q_ia: Array, f: Array) -> Array:
    """Acceleration in the inertial frame I (eq. 2): ``q ⊗ f ⊗ q* − [0, 0, 9.81]``."""
    out: Array = quat.rotate(q_ia, f) - GRAVITY
    return out
