"""ISB shoulder angles for known poses, and range-of-motion statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimators import anatomy

X, Y, Z = np.eye(3)  # robot frame: x to the patient's right, y forward, z up


def q_of(x_a: np.ndarray, y_a: np.ndarray) -> np.ndarray:
    """``q_RA`` [w, x, y, z] (1, 4) of an IMU whose x and y axes point along ``x_a``, ``y_a``
    (robot coordinates)."""
    m = np.stack([x_a, y_a, np.cross(x_a, y_a)], axis=1)
    return Rotation.from_matrix(m).as_quat(scalar_first=True)[None, :]


def angles(q: np.ndarray, side: str = "right", axial: str = "isb") -> tuple[float, float, float]:
    params = anatomy.AnatomyParams(side=side, axial=axial)  # type: ignore[arg-type]
    a = anatomy.shoulder_angles(q, params)
    return tuple(float(a[k][0]) for k in anatomy.ISB_ANGLES)  # type: ignore[return-value]


def test_arm_hanging_is_zero_elevation_and_plane_undefined() -> None:
    plane, elev, rot = angles(q_of(-Z, Y))
    assert math.isnan(plane) and math.isnan(rot)  # ISB's sequence is in gimbal lock
    assert elev == pytest.approx(0.0, abs=1e-6)
    plane, elev, rot = angles(q_of(-Z, Y), axial="plane_corrected")
    assert math.isnan(plane)
    assert rot == pytest.approx(0.0, abs=1e-6)


def test_forward_flexion_and_abduction() -> None:
    plane, elev, rot = angles(q_of(Y, Z))  # arm forward, thumb up: pure flexion
    assert (plane, elev, rot) == pytest.approx((90.0, 90.0, -90.0), abs=1e-6)  # ISB's γ
    assert angles(q_of(Y, Z), axial="plane_corrected")[2] == pytest.approx(0.0, abs=1e-6)
    plane, elev, rot = angles(q_of(X, Y))  # arm out to the right side, thumb forward
    assert (plane, elev, rot) == pytest.approx((0.0, 90.0, 0.0), abs=1e-6)
    plane, elev, rot = angles(q_of(Z, -X))  # overhead by flexion
    assert elev == pytest.approx(180.0, abs=1e-3)


def test_rotation_with_the_arm_at_the_side() -> None:
    """The forearm (IMU y, forward) swung 30° toward the belly is 30° internal rotation."""
    inward = np.array([-math.sin(math.radians(30)), math.cos(math.radians(30)), 0.0])
    _, elev, rot = angles(q_of(-Z, inward), axial="plane_corrected")
    assert elev == pytest.approx(0.0, abs=1e-6)
    assert rot == pytest.approx(30.0, abs=1e-6)
    outward = np.array([math.sin(math.radians(45)), math.cos(math.radians(45)), 0.0])
    assert angles(q_of(-Z, outward), axial="plane_corrected")[2] == pytest.approx(-45.0, abs=1e-6)
    # and the same rotation with the arm abducted 90° (forearm forward → toward the floor)
    a = math.radians(30)
    assert angles(q_of(X, np.array([0.0, math.cos(a), -math.sin(a)])))[2] == pytest.approx(30.0)


@pytest.mark.parametrize(
    ("plane", "elev", "rot"), [(30.0, 60.0, 20.0), (120.0, 35.0, -40.0), (-20.0, 150.0, 70.0)]
)
def test_isb_sequence_round_trip(plane: float, elev: float, rot: float) -> None:
    """R_TH = Ry(α)·Rx(−elevation)·Ry(γ) built in the thorax frame, expressed as the IMU's
    orientation in the robot frame, gives the same three angles back."""
    r_th = Rotation.from_euler("YXY", [plane, -elev, rot], degrees=True).as_matrix()
    t_in_r = np.stack([Y, Z, X], axis=1)  # thorax axes (anterior, up, right) in R
    h_in_a = np.stack([Y, -X, Z], axis=1)  # humerus axes in A
    r_ra = t_in_r @ r_th @ h_in_a.T
    q = Rotation.from_matrix(r_ra).as_quat(scalar_first=True)[None, :]
    assert angles(q) == pytest.approx((plane, elev, rot), abs=1e-6)
    corrected = (plane + rot + 180.0) % 360.0 - 180.0
    assert angles(q, axial="plane_corrected")[2] == pytest.approx(corrected, abs=1e-6)
    # the left arm's mirror image gives the same anatomical angles
    m = np.diag([-1.0, 1.0, 1.0])  # robot x (right) mirrored
    r_left = m @ r_ra @ np.diag([1.0, 1.0, -1.0])  # the IMU stays right-handed: z flips
    q_left = Rotation.from_matrix(r_left).as_quat(scalar_first=True)[None, :]
    assert angles(q_left, "left") == pytest.approx((plane, elev, rot), abs=1e-6)


def test_non_finite_rows_and_rom_statistics() -> None:
    q = np.vstack([q_of(Y, Z), np.full((1, 4), np.nan)])
    a = anatomy.shoulder_angles(q)
    assert all(np.isnan(a[k][1]) for k in anatomy.ISB_ANGLES)
    values = np.concatenate([np.linspace(10.0, 110.0, 101), [np.nan]])
    s = anatomy.rom_stats(values)
    assert s == pytest.approx({"min": 10.0, "max": 110.0, "p5": 15.0, "p95": 105.0, "range": 90.0})
    assert anatomy.rom_stats(np.array([np.nan])) == dict.fromkeys(anatomy.ROM_FIELDS, None)
    table = anatomy.rom_table(
        {"elbow_flexion_deg": values, "any": -values}, mask=np.arange(102) < 51
    )
    assert table["elbow_flexion_deg"]["max"] == 60.0
    assert table["any"]["min"] == -60.0
