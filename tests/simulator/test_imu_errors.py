"""IMU error model: noise levels, biases, heading drift, switch independence."""

from __future__ import annotations

import numpy as np

from simulator import SimConfig, quat, simulate
from simulator.subject import Subject
from tests.simulator.conftest import decode_all
from tests.simulator.test_physics import strapdown


def test_noise_levels_and_rate_scaling() -> None:
    base = decode_all(simulate(SimConfig(seed=4, duration_s=60.0, ideal=True)))
    noisy = decode_all(
        simulate(SimConfig(seed=4, duration_s=60.0, ideal=True, gyro_noise=True, acc_noise=True))
    )
    g, a = noisy.gyr - base.gyr, noisy.acc - base.acc
    assert abs(g.std() - 0.005) < 0.0002 and abs(a.std() - 0.03) < 0.001
    assert abs(g.mean()) < 2e-4 and abs(a.mean()) < 1e-3
    # Fixed noise density: 400 Hz has twice the rms of 100 Hz.
    cfg = dict(seed=4, duration_s=20.0, imu_rate_hz=400.0, ideal=True)
    g400 = (
        decode_all(simulate(SimConfig(**cfg, gyro_noise=True))).gyr  # type: ignore[arg-type]
        - decode_all(simulate(SimConfig(**cfg))).gyr
    )  # type: ignore[arg-type]
    assert abs(g400.std() - 0.010) < 0.0004


def test_biases_and_truth_bias() -> None:
    sim = simulate(SimConfig(seed=4, duration_s=120.0, ideal=True, gyro_bias=True, acc_bias=True))
    base = simulate(SimConfig(seed=4, duration_s=120.0, ideal=True))
    s, b = decode_all(sim), decode_all(base)
    np.testing.assert_allclose(s.gyr - b.gyr, sim.truth.gyro_bias, atol=2e-7)
    bias0 = np.radians(sim.subject.gyro_bias_dps)
    np.testing.assert_allclose(sim.truth.gyro_bias[0], bias0, atol=1e-12)
    assert all(0.1 <= abs(x) <= 0.8 for x in sim.subject.gyro_bias_dps)
    walk = np.degrees(np.abs(sim.truth.gyro_bias[-1] - bias0))
    assert 0.0 < walk.max() < 0.1  # slow drift, ~0.002 °/s/√s
    np.testing.assert_allclose(
        s.acc - b.acc, np.broadcast_to(sim.subject.acc_bias_m_s2, s.acc.shape), atol=2e-6
    )
    assert all(0.05 <= abs(x) <= 0.15 for x in sim.subject.acc_bias_m_s2)


def test_heading_drift_of_plain_integration() -> None:
    """Integrating the biased gyro drifts in heading at the reported vertical bias rate."""
    sim = simulate(SimConfig(seed=2, duration_s=120.0, ideal=True, gyro_bias=True))
    assert abs(sim.heading_drift_dps) > 0.5  # a fast-drifting subject
    s = decode_all(sim)
    q = strapdown(sim.truth.q_imu[0], s.gyr, 0.01)
    err = quat.multiply(q, quat.conjugate(sim.truth.q_imu))  # world-frame error rotation
    yaw = np.degrees(np.unwrap(2 * np.arctan2(err[:, 3], err[:, 0])))
    slope = np.polyfit(sim.truth.t, yaw, 1)[0]
    assert abs(slope - sim.heading_drift_dps) < 0.1 * abs(sim.heading_drift_dps)


def test_some_subjects_drift_fast() -> None:
    drifts = [
        simulate(
            SimConfig(seed=s, duration_s=30.0, imu_rate_hz=20.0, robot_rate_hz=10.0)
        ).heading_drift_dps
        for s in range(1, 11)
    ]
    assert max(abs(d) for d in drifts) > 0.5
    assert min(abs(d) for d in drifts) < 0.2


def test_errors_are_independent_streams() -> None:
    """Switching one error off changes nothing else."""
    full = simulate(SimConfig(seed=11, duration_s=30.0))
    no_acc = simulate(SimConfig(seed=11, duration_s=30.0, acc_noise=False))
    a, b = decode_all(full), decode_all(no_acc)
    np.testing.assert_array_equal(a.gyr, b.gyr)
    np.testing.assert_array_equal(a.wrist, b.wrist)
    assert not np.array_equal(a.acc, b.acc)
    ideal = simulate(SimConfig(seed=11, duration_s=30.0, ideal=True))
    np.testing.assert_array_equal(ideal.truth.shoulder, full.truth.shoulder)  # same motion


def test_subject_json_round_trip() -> None:
    sim = simulate(SimConfig(seed=12, duration_s=20.0))
    assert Subject.from_json(sim.subject.to_json()) == sim.subject
    # A given subject is used as is.
    again = simulate(SimConfig(seed=99, duration_s=20.0, subject=sim.subject))
    assert again.subject == sim.subject
