"""Self-check with every error off: the sensor readings are the exact physics of the truth."""

from __future__ import annotations

import numpy as np

from simulator import SimConfig, Simulation, quat, simulate
from simulator.imu import GRAVITY
from tests.simulator.conftest import Streams, decode_all


def strapdown(q0: np.ndarray, gyr: np.ndarray, dt: float) -> np.ndarray:
    """Quaternion integration of body rates with a 2-sample coning correction, (N,4)."""
    rotvec = 0.5 * (gyr[:-1] + gyr[1:]) * dt + np.cross(gyr[:-1], gyr[1:]) * dt * dt / 12.0
    prod = np.vstack((q0, quat.from_rotvec(rotvec)))
    # Inclusive scan q0 ⊗ dq1 ⊗ … ⊗ dqi in log2(N) vectorised rounds (order preserved).
    shift = 1
    while shift < prod.shape[0]:
        prod[shift:] = quat.multiply(prod[:-shift], prod[shift:])
        shift *= 2
    return np.asarray(prod / np.linalg.norm(prod, axis=1, keepdims=True))


def orientation_error_deg(sim: Simulation, streams: Streams) -> np.ndarray:
    q = strapdown(sim.truth.q_imu[0], streams.gyr, 1.0 / sim.config.imu_rate_hz)
    return np.degrees(quat.angle_between(q, sim.truth.q_imu))


def specific_force_residual(sim: Simulation, streams: Streams) -> tuple[np.ndarray, np.ndarray]:
    """(measured acceleration in R from the accelerometer, residual vs. d²p/dt² of the truth)."""
    dt = 1.0 / sim.config.imu_rate_hz
    acc_world = quat.rotate(sim.truth.q_imu, streams.acc) - np.array([0.0, 0.0, GRAVITY])
    p = sim.truth.imu_position
    second = (p[2:] - 2 * p[1:-1] + p[:-2]) / dt**2
    return acc_world[1:-1], acc_world[1:-1] - second


def test_gyro_integration_reproduces_orientation(
    ideal_sim: Simulation, ideal_streams: Streams
) -> None:
    err = orientation_error_deg(ideal_sim, ideal_streams)
    assert ideal_sim.truth.t[-1] >= 480.0
    assert err.max() < 0.1, f"strapdown drifted {err.max():.3f}° over the session"
    # The arm really turns: the check is not trivially met by a still sensor.
    turned = np.degrees(quat.angle_between(ideal_sim.truth.q_imu[0], ideal_sim.truth.q_imu))
    assert turned.max() > 40.0


def test_specific_force_matches_position(ideal_sim: Simulation, ideal_streams: Streams) -> None:
    acc, residual = specific_force_residual(ideal_sim, ideal_streams)
    rms = np.sqrt(np.mean(residual**2))
    assert rms < 2e-4, rms  # finite-difference error of the check at 100 Hz
    assert np.abs(residual).max() < 5e-3
    assert np.sqrt(np.mean(acc**2)) > 0.1  # there is acceleration to get wrong
    assert np.abs(acc).max() > 0.5


def test_rest_reads_gravity_only(ideal_sim: Simulation, ideal_streams: Streams) -> None:
    rest = ideal_sim.truth.phase == 0
    assert rest.sum() == 500
    assert np.abs(ideal_streams.gyr[rest]).max() < 1e-6
    expected = quat.rotate(
        quat.conjugate(ideal_sim.truth.q_imu[rest]), np.array([0.0, 0.0, GRAVITY])
    )
    assert np.abs(ideal_streams.acc[rest] - expected).max() < 2e-6
    assert np.ptp(ideal_sim.truth.shoulder[rest], axis=0).max() == 0.0
    np.testing.assert_array_equal(
        ideal_sim.truth.shoulder[rest][0], ideal_sim.truth.nominal_shoulder
    )


def test_wobble_keeps_physics_consistent() -> None:
    """Soft-tissue wobble moves the sensor, and the readings follow that motion exactly."""
    base = simulate(SimConfig(seed=3, duration_s=120.0, ideal=True))
    sim = simulate(SimConfig(seed=3, duration_s=120.0, ideal=True, wobble=True))
    streams = decode_all(sim)
    assert orientation_error_deg(sim, streams).max() < 0.05
    _, residual = specific_force_residual(sim, streams)
    assert np.sqrt(np.mean(residual**2)) < 1e-3
    shift_mm = 1e3 * np.linalg.norm(sim.truth.imu_position - base.truth.imu_position, axis=1)
    tilt_deg = np.degrees(quat.angle_between(sim.truth.q_imu, base.truth.q_imu))
    assert 1.5 < shift_mm.max() < 10.0, shift_mm.max()
    assert 0.3 < tilt_deg.max() < 3.0, tilt_deg.max()
    # The bone does not wobble.
    np.testing.assert_array_equal(sim.truth.q_ra, base.truth.q_ra)


def test_frames_follow_the_convention(default_sim: Simulation) -> None:
    tr = default_sim.truth
    s = default_sim.subject
    rot = quat.to_matrix(tr.q_ra)
    x, y, z = rot[:, :, 0], rot[:, :, 1], rot[:, :, 2]
    upper = tr.elbow - tr.shoulder
    fore = tr.wrist - tr.elbow
    np.testing.assert_allclose(np.linalg.norm(upper, axis=1), s.upper_arm_m, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(fore, axis=1), s.forearm_m, atol=1e-9)
    np.testing.assert_allclose(x, upper / s.upper_arm_m, atol=1e-9)
    assert np.abs(np.einsum("ij,ij->i", z, fore)).max() < 1e-9  # z ⟂ arm plane
    assert np.einsum("ij,ij->i", y, fore).min() > 0  # y toward the forearm (anterior)
    assert z[:, 0].mean() > 0.5  # z lateral (+x of R) for the right arm
    # IMU = A rotated by the mounting misalignment (wobble adds at most a few degrees).
    mis = np.degrees(quat.angle_between(tr.q_ra, tr.q_imu))
    assert abs(np.median(mis) - s.mount_angle_deg) < 1.0
    assert 1.0 <= s.mount_angle_deg <= 3.0
    # The elbow angle is the angle between the segments and never singular.
    cos = np.einsum("ij,ij->i", upper, fore) / (s.upper_arm_m * s.forearm_m)
    np.testing.assert_allclose(tr.elbow_angle_deg, np.degrees(np.arccos(cos)), atol=1e-6)
    assert tr.elbow_angle_deg.min() > 20.0 and tr.elbow_angle_deg.max() < 125.0


def test_quaternion_helpers_round_trip() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    np.testing.assert_allclose(quat.from_matrix(quat.to_matrix(q)), q, atol=1e-12)
    v = rng.normal(size=(200, 3))
    np.testing.assert_allclose(
        quat.rotate(q, v), np.einsum("nij,nj->ni", quat.to_matrix(q), v), atol=1e-12
    )
    r = rng.normal(size=(200, 3))
    axis = r / np.linalg.norm(r, axis=1, keepdims=True)
    np.testing.assert_allclose(
        quat.from_rotvec(r), quat.from_axis_angle(axis, np.linalg.norm(r, axis=1)), atol=1e-12
    )
