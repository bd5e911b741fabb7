"""True arm kinematics for the wearable simulator, independent of the estimator's DH code.

Rotations come from scipy's intrinsic Euler angles of contract §8 (``R_SU = Ry(−θ0)·Rx(−θ1)·
Rz(θ2)``, ``R_UF = Ry(−θ4)·Rz(θ5)``); angular velocities and accelerations are obtained by
differentiating the rotations and positions numerically (central differences in time), so
the simulator shares no formula with the filter's recursive kinematics (paper eqs. 12–14).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

F64: TypeAlias = NDArray[np.float64]
ThetaFn: TypeAlias = Callable[[F64], F64]  # t (N,) s -> θ (N, 5) rad
G = 9.81
_H_ROT = 1e-5  # s, step of the rotation derivative
_H_POS = 1e-4  # s, step of the position's second derivative


@dataclass(frozen=True)
class Mount:
    """An IMU on its segment: ``position`` (3,) m and ``rotation`` IMU→segment (3,3);
    ``sta_gain`` turns it about the segment's long axis by that fraction of the segment's own
    axial joint angle (θ2 for the upper arm, θ5 for the forearm): skin sliding over bone."""

    position: F64
    rotation: F64
    sta_gain: float = 0.0


def rotations(theta: F64) -> tuple[F64, F64]:
    """``R_SU`` and ``R_SF`` (N,3,3) for ``θ`` (N,5) rad."""
    th = np.atleast_2d(theta)
    r_su = Rotation.from_euler("YXZ", np.column_stack((-th[:, 0], -th[:, 1], th[:, 2])))
    r_uf = Rotation.from_euler("YZ", np.column_stack((-th[:, 3], th[:, 4])))
    return r_su.as_matrix(), (r_su * r_uf).as_matrix()


def _imu_pose(theta: F64, seg: int, mount: Mount, upper_m: float) -> tuple[F64, F64]:
    """IMU rotation S←I (N,3,3) and position in S (N,3)."""
    r_su, r_sf = rotations(theta)
    axial = theta[:, 2] if seg == 0 else theta[:, 4]
    sta = Rotation.from_rotvec(np.outer(mount.sta_gain * axial, [0.0, 0.0, 1.0])).as_matrix()
    r_seg = r_su if seg == 0 else r_sf
    r_si = r_seg @ sta @ mount.rotation
    pos = np.einsum("nij,nj->ni", r_seg @ sta, np.broadcast_to(mount.position, (len(theta), 3)))
    if seg == 1:
        pos = pos + r_su @ np.array([0.0, 0.0, -upper_m])
    return r_si, pos


def joint_positions(theta: F64, upper_m: float, fore_m: float) -> tuple[F64, F64]:
    """Elbow and wrist (N,3) in S, m."""
    r_su, r_sf = rotations(theta)
    elbow = r_su @ np.array([0.0, 0.0, -upper_m])
    return elbow, elbow + r_sf @ np.array([0.0, 0.0, -fore_m])


def imu_readings(
    theta_fn: ThetaFn, t: F64, seg: int, mount: Mount, upper_m: float
) -> tuple[F64, F64]:
    """Error-free gyro (rad/s) and specific force (m/s²) in the IMU frame, (N,3) each, of the
    upper-arm (``seg`` 0) or forearm (1) IMU."""
    r0, p0 = _imu_pose(theta_fn(t), seg, mount, upper_m)
    _, pp = _imu_pose(theta_fn(t + _H_POS), seg, mount, upper_m)
    _, pm = _imu_pose(theta_fn(t - _H_POS), seg, mount, upper_m)
    acc_s = (pp - 2.0 * p0 + pm) / _H_POS**2 + np.array([0.0, 0.0, G])
    r1 = _imu_pose(theta_fn(t + _H_ROT), seg, mount, upper_m)[0]
    r2 = _imu_pose(theta_fn(t - _H_ROT), seg, mount, upper_m)[0]
    # body rate: R(t)ᵀ·R(t+h) ≈ exp([ω]× h)
    rel = Rotation.from_matrix(np.einsum("nji,njk->nik", r2, r1))
    gyr = rel.as_rotvec() / (2.0 * _H_ROT)
    acc = np.einsum("nji,nj->ni", r0, acc_s)
    return gyr, acc
