"""Kinematics (paper eqs. 1, 2, 11–13) and quaternion helpers."""

import numpy as np
import pytest

from estimators import kinematics as kin
from estimators import quaternion as quat


def _rand_quat(n, seed=0):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return quat.normalize(q)


def test_rotate_matches_hamilton_product():
    q = _rand_quat(50)
    v = np.random.default_rng(1).normal(size=(50, 3))
    pure = np.concatenate((np.zeros((50, 1)), v), axis=1)
    full = quat.mul(quat.mul(q, pure), quat.conj(q))
    np.testing.assert_allclose(quat.rotate(q, v), full[:, 1:], atol=1e-12)
    np.testing.assert_allclose(quat.rotate(quat.about_z(0.3), v), quat.rotate_z(0.3, v), atol=1e-12)


def test_elbow_from_cuffs_eq13():
    wrist = np.array([[0.3, 0.4, 0.0]])
    prox = np.array([[0.3, 0.2, 0.0]])
    p_e, x_c = kin.elbow_from_cuffs(wrist, prox, 0.06)
    np.testing.assert_allclose(p_e, [[0.3, 0.14, 0.0]])
    np.testing.assert_allclose(x_c, [[0.0, 1.0, 0.0]])


def test_elbow_angle_and_shoulder():
    x_a = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    x_c = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(kin.elbow_angle_deg(x_a, x_c), [0.0, 90.0])
    p_s = kin.shoulder_position(np.array([[0.0, 0.3, 0.0]] * 2), x_a, 0.3)
    np.testing.assert_allclose(p_s, [[0.0, 0.3, 0.3]] * 2)


def test_joint_specific_force_is_rigid_body_acceleration():
    # a point r on a body spinning at ω about z: centripetal −ω² r
    r = np.array([0.15, 0.0, 0.0])
    f = np.zeros((1, 3))
    w = np.array([[0.0, 0.0, 2.0]])
    out = kin.joint_specific_force(f, w, np.zeros((1, 3)), r)
    np.testing.assert_allclose(out, [[-4.0 * 0.15, 0.0, 0.0]])
    # tangential: ω̇ × r
    out = kin.joint_specific_force(f, np.zeros((1, 3)), np.array([[0.0, 0.0, 3.0]]), r)
    np.testing.assert_allclose(out, [[0.0, 0.45, 0.0]])


def test_conventional_baseline_uses_fixed_shoulder():
    x_a, ang = kin.conventional(
        np.array([[0.0, 0.3, 0.0]]), np.array([[0.0, 1.0, 0.0]]), np.zeros(3)
    )
    np.testing.assert_allclose(x_a, [[0.0, 1.0, 0.0]])
    assert ang[0] == pytest.approx(0.0)


def test_nlerp_endpoints_and_shortest_arc():
    q0, q1 = _rand_quat(10, 2), _rand_quat(10, 3)
    np.testing.assert_allclose(quat.nlerp(q0, q1, np.zeros(10)), q0, atol=1e-12)
    end = quat.nlerp(q0, q1, np.ones(10))
    np.testing.assert_allclose(np.abs(np.sum(end * q1, axis=1)), 1.0, atol=1e-12)
