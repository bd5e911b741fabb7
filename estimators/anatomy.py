"""Shoulder angles in anatomical terms (ISB, Wu et al. 2005, J Biomech 38:981, §3.5) and
range-of-motion statistics.

**Frames.** The ISB thorax frame T: ``X_t`` anterior, ``Y_t`` superior, ``Z_t`` to the right.
The ISB humerus frame H: ``Y_h`` from the elbow to the glenohumeral centre, ``X_h`` anterior
and ``Z_h`` lateral in the zero pose (arm hanging, palm toward the trunk, thumb forward).
Without a trunk sensor the robot frame stands in for the thorax (contract §3: robot ``y``
forward, ``z`` up, so ``x`` points to the patient's right when the patient faces ``+y``):
``T = (y_R, z_R, x_R)``. The upper-arm IMU frame A has ``x`` along the upper arm toward the
elbow; its ``y`` is taken as forward and its ``z`` as lateral in the zero pose (the contract
§8 default mounting), so ``H = (y_A, −x_A, z_A)``. A left arm is mirrored through the
sagittal plane, so the same positive angles mean the same anatomical motions.

**Angles** (ISB's Y–X–Y Euler sequence, ``R_TH = Ry(α) · Rx(β) · Ry(γ)``):

- plane of elevation ``α``: 0° = abduction (in the frontal plane), 90° = forward flexion;
- elevation ``−β`` (ISB's β is negative for elevation; reported positive): 0° hanging, 90°
  horizontal, 180° overhead;
- axial rotation ``γ``: positive = internal rotation.

Near the hanging position (elevation below ``min_elevation_deg``) the sequence is in gimbal
lock: ``α`` and ``γ`` are undefined there and both are NaN. ISB's ``γ`` depends on the plane:
pure forward flexion from the zero pose is ``(90°, 90°, −90°)``. ``axial="plane_corrected"``
reports ``α + γ`` instead (0 for pure flexion and pure abduction, defined also with the arm at
the side, where it is the rotation a therapist measures); the default is ISB's ``γ``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal, TypeAlias

import numpy as np
from numpy.typing import NDArray

Array: TypeAlias = NDArray[np.float64]
Side: TypeAlias = Literal["right", "left"]

ISB_ANGLES = (
    "shoulder_plane_of_elevation_deg",
    "shoulder_elevation_deg",
    "shoulder_axial_rotation_deg",
)

# columns: the ISB axes (X_t, Y_t, Z_t) in robot coordinates, right arm
_T_IN_R = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]).T
# columns: the ISB humerus axes (X_h, Y_h, Z_h) in IMU coordinates
_H_IN_A = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T
_MIRROR = np.diag([1.0, 1.0, -1.0])  # a left arm: through the thorax's sagittal (X-Y) plane


@dataclass(frozen=True, slots=True)
class AnatomyParams:
    """``side``: the tracked arm; ``min_elevation_deg``: below it the plane of elevation (and
    ISB's axial rotation) is NaN (gimbal lock of the Y–X–Y sequence); ``axial``: ISB's ``γ``
    or ``α + γ`` (module docstring)."""

    side: Side = "right"
    min_elevation_deg: float = 15.0
    axial: Literal["isb", "plane_corrected"] = "isb"


def quat_to_matrix(q: Array) -> Array:
    """Rotation matrices (N, 3, 3) of unit quaternions ``[w, x, y, z]`` (N, 4)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    m = np.empty((len(q), 3, 3))
    m[:, 0, 0] = 1 - 2 * (y * y + z * z)
    m[:, 0, 1] = 2 * (x * y - w * z)
    m[:, 0, 2] = 2 * (x * z + w * y)
    m[:, 1, 0] = 2 * (x * y + w * z)
    m[:, 1, 1] = 1 - 2 * (x * x + z * z)
    m[:, 1, 2] = 2 * (y * z - w * x)
    m[:, 2, 0] = 2 * (x * z - w * y)
    m[:, 2, 1] = 2 * (y * z + w * x)
    m[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def humerus_in_thorax(q_ra: Array, side: Side = "right") -> Array:
    """``R_TH`` (N, 3, 3) from the upper-arm orientation ``q_RA`` (N, 4; A → R), the robot
    frame standing in for the thorax."""
    r_ra = quat_to_matrix(q_ra)
    r = _T_IN_R.T @ r_ra @ _H_IN_A
    if side == "left":
        r = _MIRROR @ r @ _MIRROR
    out: Array = r
    return out


def isb_angles(r_th: Array, params: AnatomyParams = AnatomyParams()) -> dict[str, Array]:
    """Plane of elevation, elevation and axial rotation (°, each (N,)) of ``R_TH`` (N, 3, 3),
    ISB's Y–X–Y sequence (module docstring). Non-finite input gives NaN."""
    r = np.asarray(r_th, dtype=np.float64)
    # −β, β ∈ [−180°, 0°]: atan2 of the long axis' horizontal and vertical parts (arccos
    # of R11 alone loses half the digits near the hanging pose)
    sb = -np.hypot(r[:, 0, 1], r[:, 2, 1])  # sin β ≤ 0
    elevation = np.degrees(np.arctan2(-sb, r[:, 1, 1]))
    with np.errstate(invalid="ignore", divide="ignore"):
        plane = np.degrees(np.arctan2(r[:, 0, 1] / sb, r[:, 2, 1] / sb))
        axial = np.degrees(np.arctan2(r[:, 1, 0] / sb, -r[:, 1, 2] / sb))
    low = ~(elevation >= params.min_elevation_deg)  # NaN elevation counts as low
    plane = np.where(low, np.nan, plane)
    if params.axial == "isb":
        axial = np.where(low, np.nan, axial)
    else:  # α + γ, wrapped; at β ≈ 0 it is the rotation about the vertical
        total = np.degrees(np.arctan2(r[:, 0, 2], r[:, 0, 0]))
        axial = np.where(low, total, (np.where(low, 0.0, plane) + axial + 180.0) % 360.0 - 180.0)
    bad = ~np.all(np.isfinite(r.reshape(len(r), 9)), axis=1)
    for a in (elevation, axial):
        a[bad] = np.nan
    return {
        ISB_ANGLES[0]: plane,
        ISB_ANGLES[1]: elevation,
        ISB_ANGLES[2]: axial,
    }


def shoulder_angles(q_ra: Array, params: AnatomyParams = AnatomyParams()) -> dict[str, Array]:
    """ISB shoulder angles (°, (N,) each) from the upper arm's orientation in the robot
    frame ``q_RA`` (N, 4). Rows with a non-finite quaternion give NaN."""
    q = np.asarray(q_ra, dtype=np.float64).reshape(-1, 4)
    return isb_angles(humerus_in_thorax(q, params.side), params)


ROM_FIELDS = ("min", "max", "p5", "p95", "range")


def rom_stats(values: Array) -> dict[str, float | None]:
    """min, max, 5th and 95th percentiles (linear interpolation, numpy's default) and the
    active range (p95 − p5) of one angle's finite values (°); None for each when there is
    none."""
    a = np.asarray(values, dtype=np.float64)
    a = np.sort(a[np.isfinite(a)])  # one sort for all four (np.percentile's overhead dominated)
    if not len(a):
        return dict.fromkeys(ROM_FIELDS, None)
    p5, p95 = _sorted_percentile(a, 0.05), _sorted_percentile(a, 0.95)
    return {
        "min": float(a[0]),
        "max": float(a[-1]),
        "p5": p5,
        "p95": p95,
        "range": p95 - p5,
    }


def _sorted_percentile(a: Array, q: float) -> float:
    """``np.percentile(a, 100 q)`` of a sorted non-empty array (linear interpolation)."""
    x = q * (len(a) - 1)
    i = min(int(x), len(a) - 1)
    j = min(i + 1, len(a) - 1)
    lo, hi, t = float(a[i]), float(a[j]), x - i
    # numpy's lerp, to the last bit: from the nearer end
    return hi - (hi - lo) * (1.0 - t) if t >= 0.5 else lo + (hi - lo) * t


def rom_table(
    angles: Mapping[str, Array], mask: NDArray[np.bool_] | None = None
) -> dict[str, dict[str, float | None]]:
    """:func:`rom_stats` of every named angle column (robot-mode ISB angles, the wearable
    mode's joint angles, or any other), over the rows where ``mask`` holds."""
    return {
        name: rom_stats(np.asarray(a)[mask] if mask is not None else np.asarray(a))
        for name, a in angles.items()
    }


# columns: the ISB thorax / humerus axes (X anterior, Y superior, Z right) in contract §8's
# shoulder frame S (x forward, y left, z up) and, in the zero pose, in the upper-arm frame U
_ISB_IN_S = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]).T


def _rot(axis: int, a: Array) -> Array:
    """Right-handed rotations (N, 3, 3) about x (0), y (1) or z (2) by ``a`` (N,) rad."""
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.zeros((len(a), 3, 3))
    m[:, axis, axis] = 1.0
    m[:, i, i] = c
    m[:, j, j] = c
    m[:, i, j] = -s
    m[:, j, i] = s
    return m


def wearable_isb_angles(
    flexion_deg: Array,
    abduction_deg: Array,
    rotation_deg: Array,
    params: AnatomyParams = AnatomyParams(),
) -> dict[str, Array]:
    """ISB shoulder angles (°, (N,) each) from the wearable mode's joint angles (contract §8,
    °, (N,) each): ``R_SU = Ry(−θ0) · Rx(−θ1) · Rz(θ2)`` with S standing in for the thorax
    and U for the humerus (both parallel in the zero pose, so ``R_TH = C^T R_SU C`` with
    ``C`` the ISB axes in S). The §8 angles of a left arm are already those of the mirrored
    (virtual right) arm, so ``params.side`` is not applied again. NaN in → NaN out."""
    t0 = np.radians(np.asarray(flexion_deg, dtype=np.float64).reshape(-1))
    t1 = np.radians(np.asarray(abduction_deg, dtype=np.float64).reshape(-1))
    t2 = np.radians(np.asarray(rotation_deg, dtype=np.float64).reshape(-1))
    r_su = _rot(1, -t0) @ _rot(0, -t1) @ _rot(2, t2)
    return isb_angles(_ISB_IN_S.T @ r_su @ _ISB_IN_S, params)
