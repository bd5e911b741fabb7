"""Wearable simulator: contract messages, determinism, geometry of the shoulder wheel, errors."""

from __future__ import annotations

import numpy as np

from estimators.wearable.params import WearableParams
from protocol import keys, recording, wire
from simulator import wearable as w
from simulator import wearable_moves as moves
from simulator.wearable_arm import joint_positions

SHORT = {"duration_s": 6.0}


def test_messages_are_contract_payloads_and_deterministic(tmp_path):
    sim = w.simulate(w.WearableSimConfig(move="reaching", seed=3, **SHORT))
    again = w.simulate(w.WearableSimConfig(move="reaching", seed=3, **SHORT))
    assert sim.messages == again.messages
    other = w.simulate(w.WearableSimConfig(move="reaching", seed=4, **SHORT))
    assert other.messages != sim.messages
    kinds = set()
    for key, payload in sim.messages:
        parsed = keys.parse(key)
        kinds.add(parsed.kind if parsed.segment is None else parsed.segment)
        msg = wire.decode(key, wire.dumps(payload))
        assert msg.device == "wear01"
    assert {"upperarm", "forearm", "camera"} <= kinds
    paths = w.write(sim, tmp_path)
    back = list(recording.read(paths["recording"]))
    assert len(back) == len(sim.messages)
    WearableParams.from_json(sim.params)  # the filter accepts the parameters it is given
    truth = np.loadtxt(paths["truth"], delimiter=",", skiprows=1)
    assert truth.shape == (len(sim.t), 12)


def test_at_rest_the_imus_read_gravity_along_their_x():
    cfg = w.WearableSimConfig(move="reaching", imu=w.ImuErrors.paper(), **SHORT)
    sim = w.simulate(cfg)
    rest = sim.t < 2.0
    for gyr, acc in (sim.upper, sim.fore):
        np.testing.assert_allclose(acc[rest].mean(axis=0), [-9.81, 0, 0], atol=0.02)
        assert np.abs(gyr[rest].mean(axis=0)).max() < np.radians(0.1)


def test_errors_are_applied_and_unknown_to_the_filter():
    sim = w.simulate(w.WearableSimConfig(move="reaching", seed=1, **SHORT))
    rest = sim.t < 2.0
    bias = np.degrees(sim.upper[0][rest].mean(axis=0))
    assert np.abs(bias).max() > 0.05  # a constant gyro bias of ~0.5 °/s per axis
    assert sim.truth["upper_arm_length_m"] != sim.params["upper_arm_length_m"]
    r_true = np.asarray(sim.truth["upperarm_imu_R"])
    assert np.degrees(np.arccos((np.trace(r_true @ w_default().T) - 1) / 2)) > 0.3


def w_default():
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat([0.5, 0.5, -0.5, 0.5]).as_matrix()


def test_flexion_sine_rests_then_swings_about_its_centre():
    fn = moves.flexion_sine(90.0, 1.0, rest_s=2.0, centre_deg=90.0)
    t = np.array([0.0, 1.9, 3.0, 3.25, 3.5, 3.75])
    th = np.degrees(fn(t))
    np.testing.assert_allclose(th[:2, 0], 0.0, atol=1e-12)  # at rest in the zero pose
    np.testing.assert_allclose(th[2:, 0], [90.0, 180.0, 90.0, 0.0], atol=1e-9)  # 90° ± 90°
    assert np.all(th[:, 1:] == 0.0)


def test_shoulder_wheel_inverse_kinematics_puts_the_hand_on_the_wheel():
    wheel = moves.Wheel()
    phi = np.linspace(0, 2 * np.pi, 37)
    th0, th4 = wheel.angles(phi)
    th = np.zeros((len(phi), 5))
    th[:, 0], th[:, 3] = th0, th4
    elbow, _ = joint_positions(th, wheel.upper_m, wheel.fore_m)
    _, hand = joint_positions(th, wheel.upper_m, wheel.fore_m + wheel.hand_m)
    centre = np.array([wheel.forward_m, 0.0, -wheel.down_m])
    np.testing.assert_allclose(np.linalg.norm(hand - centre, axis=1), wheel.radius_m, atol=1e-9)
    ang = np.arctan2(hand[:, 2] - centre[2], hand[:, 0] - centre[0])
    np.testing.assert_allclose(np.cos(ang), np.cos(phi), atol=1e-9)
    assert (th4 > 0).all() and (elbow[:, 2] < 0).all()  # a flexed elbow below the shoulder


def test_camera_lag_noise_and_dropouts():
    cfg = w.WearableSimConfig(
        move="reaching",
        duration_s=40.0,
        cam=w.CameraErrors(noise_m=0.0, offset_m=0.0, dropouts_per_min=6.0),
        length_error_m=0.0,
    )
    sim = w.simulate(cfg)
    tc, ce, _ = sim.camera
    assert len(tc) < 0.97 * 40.0 * 30.0  # dropouts
    assert np.diff(tc).max() > 0.4
    fn = w.theta_function(cfg)
    lagged, _ = joint_positions(fn(tc - 0.05), 0.30, 0.25)
    np.testing.assert_allclose(ce, lagged, atol=1e-9)
    none = w.simulate(w.WearableSimConfig(move="rom", camera=False, **SHORT))
    assert not any(k.endswith("/camera") for k, _ in none.messages)
