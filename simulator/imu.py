"""Upper-arm IMU: exact kinematics at the sensor, soft-tissue wobble, and sensor errors.

Angular velocity and specific force come from the exact (smooth) trajectories of
:mod:`simulator.arm` by 4th-order central differences with a 1 ms step, evaluated on a grid
of at least 200 Hz that contains the sample times. Their truncation error is ~1e-8 (rad/s,
m/s²), far below any sensor noise; the ideal-mode self-check in the tests bounds it.

Sensor frame: ``R_imu = R_A · R_wobble(t) · R_mount`` (body-fixed rotations). The sensor sits at
``r0 = (l_A − d, 0, 0) + radial offset`` in A from the shoulder, plus the wobble translation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray
from scipy.signal import cont2discrete, lfilter, ss2tf

from simulator import quat
from simulator.arm import ArmModel, Pose
from simulator.subject import Subject

F64: TypeAlias = NDArray[np.float64]

GRAVITY = 9.81  # m/s², along −z of R
STEP_S = 1e-3  # finite-difference step
MIN_GRID_HZ = 200.0  # the wobble ODE runs at least this fast
CHUNK = 50_000  # grid points per evaluation batch (~100 MB of temporaries)
WOBBLE_AXIAL = 0.5  # tissue moves less along the bone than across it


@dataclass(frozen=True)
class ImuTruth:
    """True IMU motion at the sample times (N samples); frames as in the module docstring."""

    pose: Pose  # joints and segment frame A at the sample times
    position: F64  # (N,3) m, sensor centre in R
    q_segment: F64  # (N,4) A in R
    q_sensor: F64  # (N,4) sensor frame in R
    gyr: F64  # (N,3) rad/s, error-free, sensor frame
    acc: F64  # (N,3) m/s², error-free specific force, sensor frame


def _stencil(f: F64) -> tuple[F64, F64, F64]:
    """Value, first and second derivative from values at offsets −2h…2h along axis 0."""
    fm2, fm1, f0, fp1, fp2 = f
    h = STEP_S
    d1 = (fm2 - 8 * fm1 + 8 * fp1 - fp2) / (12 * h)
    d2 = (-fm2 + 16 * fm1 - 30 * f0 + 16 * fp1 - fp2) / (12 * h * h)
    return f0, d1, d2


def mount_geometry(subject: Subject) -> tuple[F64, F64, F64]:
    """Sensor position ``r0`` in A (from the shoulder), tangential unit vector, mount quaternion."""
    g = np.radians(subject.imu_radial_angle_deg)
    radial_dir = np.array([0.0, np.sin(g), np.cos(g)])
    r0 = np.array([subject.upper_arm_m - subject.imu_to_elbow_m, 0.0, 0.0])
    r0 = r0 + subject.imu_radial_m * radial_dir
    tangential = np.cross([1.0, 0.0, 0.0], radial_dir)
    q_mount = quat.from_axis_angle(
        np.array(subject.mount_axis), np.radians(subject.mount_angle_deg)
    )
    return r0, tangential, q_mount


def _oscillator(u: F64, dt: float, hz: float, zeta: float) -> tuple[F64, F64]:
    """Response x, ẋ of ẍ + 2ζωẋ + ω²x = u, zero initial state, along axis 0 (exact for
    piecewise-linear input)."""
    w = 2 * np.pi * hz
    a = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
    b = np.array([[0.0], [1.0]])
    ad, bd, cd, dd, _ = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), dt, method="foh")
    out = []
    for row in range(2):
        num, den = ss2tf(ad, bd, cd[row : row + 1], dd[row : row + 1])
        out.append(np.asarray(lfilter(num[0], den, u, axis=0), dtype=np.float64))
    return out[0], out[1]


def _vee_skew(m: F64) -> F64:
    """Vector of the skew-symmetric part of (N,3,3) matrices."""
    return 0.5 * np.stack(
        (m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]), axis=-1
    )


def _bone(arm: ArmModel, tau: F64, r0: F64) -> tuple[Pose, F64, F64, F64]:
    """Pose, body rate ω and its derivative ω̇ of A (N,3), acceleration of the point ``r0`` in R.

    RᵀṘ = [ω]× and RᵀR̈ = [ω̇]× + [ω]×², whose skew parts give ω and ω̇.
    """
    n = tau.shape[0]
    offsets = np.arange(-2, 3) * STEP_S
    pose = arm.pose((tau[None, :] + offsets[:, None]).ravel())
    s, _, dds = _stencil(pose.shoulder.reshape(5, n, 3))
    rot, drot, ddrot = _stencil(pose.rot.reshape(5, n, 3, 3))
    omega = _vee_skew(np.einsum("nji,njk->nik", rot, drot))
    omega_dot = _vee_skew(np.einsum("nji,njk->nik", rot, ddrot))
    acc = dds + np.einsum("nij,j->ni", ddrot, r0)
    joints = Pose(s, pose.elbow.reshape(5, n, 3)[2], pose.wrist.reshape(5, n, 3)[2], rot)
    return joints, omega, omega_dot, acc


def grid_points(n_samples: int, rate_hz: float) -> int:
    """Size of the evaluation grid behind ``n_samples`` IMU samples (for progress bars)."""
    return (n_samples - 1) * max(1, int(np.ceil(MIN_GRID_HZ / rate_hz))) + 1


def imu_truth(
    arm: ArmModel,
    subject: Subject,
    n_samples: int,
    rate_hz: float,
    progress: Callable[[int], None] | None = None,
) -> ImuTruth:
    """Exact sensor motion and readings at session times ``i / rate_hz``, i < ``n_samples``.

    ``progress`` is called with the number of grid points done after each chunk.
    """
    sub = max(1, int(np.ceil(MIN_GRID_HZ / rate_hz)))
    dt = 1.0 / (rate_hz * sub)
    n = (n_samples - 1) * sub + 1
    r0, tangential, q_mount = mount_geometry(subject)

    # Pass 1, in chunks to bound memory: the bone's motion at the samples, and the bone's
    # acceleration at the sensor (in A) on the whole grid, which drives the soft tissue.
    acc_bone_a = np.empty((n, 3))
    shoulder, elbow, wrist = (np.empty((n_samples, 3)) for _ in range(3))
    rot = np.empty((n_samples, 3, 3))
    omega, omega_dot, acc_bone = (np.empty((n_samples, 3)) for _ in range(3))
    for first in range(0, n, CHUNK):
        idx = np.arange(first, min(first + CHUNK, n))
        pose, w, dw, acc = _bone(arm, idx.astype(np.float64) * dt, r0)
        acc_bone_a[idx] = np.einsum("nji,nj->ni", pose.rot, acc)
        on = idx % sub == 0
        k = idx[on] // sub
        shoulder[k], elbow[k], wrist[k], rot[k] = (
            pose.shoulder[on],
            pose.elbow[on],
            pose.wrist[on],
            pose.rot[on],
        )
        omega[k], omega_dot[k], acc_bone[k] = w[on], dw[on], acc[on]
        if progress is not None:
            progress(idx.shape[0])

    # Soft tissue: base-excited oscillators (3 translations in A, 1 rotation about a fixed
    # axis of A) whose quasi-static deflection is −compliance × acceleration.
    w2 = (2 * np.pi * subject.wobble_hz) ** 2
    trans_gain = subject.wobble_mm_per_m_s2 * 1e-3 * np.array([WOBBLE_AXIAL, 1.0, 1.0])
    rot_gain = np.radians(subject.wobble_deg_per_m_s2)
    if trans_gain.any() or rot_gain:
        drive = np.column_stack(
            (-w2 * trans_gain * acc_bone_a, -w2 * rot_gain * (acc_bone_a @ tangential))
        )
        x, dx = _oscillator(drive, dt, subject.wobble_hz, subject.wobble_damping)
        ddx = drive - 2 * subject.wobble_damping * np.sqrt(w2) * dx - w2 * x
        x, dx, ddx = x[::sub], dx[::sub], ddx[::sub]
    else:
        x = dx = ddx = np.zeros((n_samples, 4))

    # Pass 2: the sensor = bone point r0 + wobble, rotated by wobble and mounting.
    wob, dwob, ddwob = x[:, :3], dx[:, :3], ddx[:, :3]
    alpha, dalpha = x[:, 3], dx[:, 3]
    position = shoulder + np.einsum("nij,nj->ni", rot, r0 + wob)
    relative = (
        np.cross(omega_dot, wob)
        + np.cross(omega, np.cross(omega, wob))
        + 2 * np.cross(omega, dwob)
        + ddwob
    )  # d²/dt² of R·w, in A
    acc_world = acc_bone + np.einsum("nij,nj->ni", rot, relative)
    axis = np.array(subject.wobble_axis)
    q_wobble = quat.from_axis_angle(np.broadcast_to(axis, (n_samples, 3)), alpha)
    q_segment = quat.continuous(quat.from_matrix(rot))
    q_sensor = quat.continuous(quat.multiply(quat.multiply(q_segment, q_wobble), q_mount))
    # Angular velocity of R_A·R_w·R_m in the sensor frame (wobble is about a fixed axis).
    omega_w = quat.rotate(quat.conjugate(q_wobble), omega) + dalpha[:, None] * axis
    gyr = quat.rotate(quat.conjugate(q_mount), omega_w)
    acc_out = quat.rotate(quat.conjugate(q_sensor), acc_world + np.array([0.0, 0.0, GRAVITY]))
    joints = Pose(shoulder, elbow, wrist, rot)
    return ImuTruth(joints, position, q_segment, q_sensor, gyr, acc_out)


@dataclass(frozen=True)
class ImuReadings:
    """Measured samples (N,3) and the gyro bias actually applied (N,3), sensor frame."""

    gyr: F64  # rad/s
    acc: F64  # m/s²
    gyro_bias: F64  # rad/s


def add_errors(
    truth: ImuTruth,
    subject: Subject,
    rng: np.random.Generator,
    rate_hz: float,
    *,
    gyro_noise_rad_s: float,
    acc_noise_m_s2: float,
    gyro_bias_walk_dps: float,
) -> ImuReadings:
    """Bias (constant + random walk), white noise. A zero magnitude switches a term off.

    All random numbers are drawn whatever the magnitudes, so switching one error off leaves
    the others unchanged.
    """
    n = truth.gyr.shape[0]
    walk_steps = rng.standard_normal((n, 3))
    gyro_white = rng.standard_normal((n, 3))
    acc_white = rng.standard_normal((n, 3))
    scale = np.sqrt(rate_hz / 100.0)  # fixed noise density: rms grows with the bandwidth
    bias0 = np.radians(np.array(subject.gyro_bias_dps))
    walk = np.cumsum(walk_steps, axis=0) * np.radians(gyro_bias_walk_dps) / np.sqrt(rate_hz)
    walk -= walk[0]
    bias = bias0 + walk if bias0.any() else np.zeros((n, 3))
    gyr = truth.gyr + bias + gyro_noise_rad_s * scale * gyro_white
    acc = truth.acc + np.array(subject.acc_bias_m_s2) + acc_noise_m_s2 * scale * acc_white
    return ImuReadings(gyr, acc, bias)
