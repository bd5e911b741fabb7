"""Per-subject parameters: body, task placement, sensor mounting and device errors.

Everything a subject or a session setup fixes for a whole run lives in :class:`Subject`;
everything that changes cycle by cycle is drawn in :mod:`simulator.arm` from the seed.
Lengths are metres, angles degrees, rates hertz, times seconds.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

Vec3 = tuple[float, float, float]

# Reach of the 50th-percentile arm the task template is sized for (upper arm + forearm), m.
REFERENCE_REACH_M = 0.57


@dataclass(frozen=True)
class Subject:
    """One seated subject with the right arm in the robot (robot frame R: x right, y forward, z up).

    Segment frame A (upper arm): ``x`` shoulder → elbow, ``z = normalize(x × forearm)``
    (the elbow's flexion axis, pointing laterally for a right arm), ``y = z × x``
    (anterior). A is fixed to the humerus because the elbow is a hinge and never straight.
    """

    # body
    upper_arm_m: float
    forearm_m: float  # elbow to wrist joint centre
    nominal_shoulder_m: Vec3  # shoulder during the initial rest, in R
    # task, relative to the nominal shoulder
    rect_center_m: Vec3  # centre of the wrist's rectangle (x, y) and wrist height (z)
    rect_size_m: tuple[float, float]  # side lengths along x and y
    cycle_s: float  # mean proper cycle duration
    swivel_deg: float  # nominal elbow swivel: 0 = elbow as low as possible, + = lifted laterally
    proper_lean_m: float  # reach-correlated shoulder displacement at the far edge, proper
    compensatory_lean_m: float  # the same during compensation (horizontal peak)
    sway_m: float  # bound of the random shoulder sway per horizontal axis
    # IMU placement (geometry, not an error of the sensor; ``radial_offset`` switch)
    imu_to_elbow_m: float  # along the humerus, from the elbow
    imu_radial_m: float  # distance from the humerus axis
    imu_radial_angle_deg: float  # offset direction about x_A: from +z_A (lateral) toward +y_A
    mount_axis: Vec3  # misalignment axis in A (unit)
    mount_angle_deg: float  # misalignment angle
    # IMU errors
    gyro_bias_dps: Vec3  # sensor frame, at t = 0
    acc_bias_m_s2: Vec3  # sensor frame
    wobble_hz: float  # soft-tissue natural frequency
    wobble_damping: float  # damping ratio
    wobble_mm_per_m_s2: float  # quasi-static translation per unit bone acceleration
    wobble_deg_per_m_s2: float  # quasi-static rotation per unit tangential acceleration
    wobble_axis: Vec3  # rotation axis of the tissue in A (unit, mostly along the humerus)
    # robot and session errors
    latency_s: float  # robot sample stamped t shows the pose at t - latency
    rope_hz: float  # rope oscillation frequency
    rope_decay_s: float  # its exponential time constant
    rope_amp_m: float  # mean first-peak amplitude at the wrist cuff (per corner ×0.6–1.4)
    reference_error_m: Vec3  # therapist's placement error of the rope end on the shoulder

    def to_json(self) -> str:
        """JSON object of all fields (tuples as arrays)."""
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Subject:
        """Inverse of :meth:`to_json`; unknown keys are rejected."""
        obj: dict[str, Any] = json.loads(text)
        names = {f.name for f in fields(cls)}
        unknown = set(obj) - names
        if unknown:
            raise ValueError(f"unknown subject fields: {sorted(unknown)}")
        kwargs: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in obj.items()}
        return cls(**kwargs)


def _unit(v: np.ndarray) -> Vec3:
    u = v / np.linalg.norm(v)
    return (float(u[0]), float(u[1]), float(u[2]))


def _signed(rng: np.random.Generator, lo: float, hi: float, n: int) -> Vec3:
    mag = rng.uniform(lo, hi, n) * rng.choice((-1.0, 1.0), n)
    return (float(mag[0]), float(mag[1]), float(mag[2]))


def task_placement(upper_arm_m: float, forearm_m: float) -> tuple[Vec3, tuple[float, float]]:
    """Rectangle centre (relative to the shoulder) and size that keep the elbow at ~30°–120°.

    The therapist sizes the task to the arm: a 0.30 m × 0.20 m rectangle for a 0.57 m reach,
    scaled with the reach, its centre in front of the shoulder and the wrist below it.
    """
    s = (upper_arm_m + forearm_m) / REFERENCE_REACH_M
    center = (0.0, 0.415 * s, -0.15 * s)
    size = (0.30 * s, 0.20 * s)
    return center, size


def draw_subject(rng: np.random.Generator) -> Subject:
    """Draw a subject. Uses a fixed number of draws so the stream stays aligned across versions."""
    upper = float(rng.uniform(0.26, 0.34))
    fore = float(rng.uniform(0.24, 0.30))
    center, size = task_placement(upper, fore)
    shoulder = np.array([0.15, -0.25, 0.40]) + rng.uniform(-0.02, 0.02, 3)
    mount_axis = _unit(rng.normal(size=3))
    wobble_axis = _unit(np.array([1.0, 0.0, 0.0]) + rng.uniform(-0.3, 0.3, 3))
    ref_dir = rng.normal(size=3)
    ref = ref_dir / np.linalg.norm(ref_dir) * rng.uniform(0.005, 0.010)
    return Subject(
        upper_arm_m=upper,
        forearm_m=fore,
        nominal_shoulder_m=(float(shoulder[0]), float(shoulder[1]), float(shoulder[2])),
        rect_center_m=center,
        rect_size_m=size,
        cycle_s=float(rng.uniform(4.6, 5.2)),
        swivel_deg=float(rng.uniform(15.0, 35.0)),
        proper_lean_m=float(rng.uniform(0.025, 0.04)),
        compensatory_lean_m=float(rng.uniform(0.135, 0.15)),
        sway_m=float(rng.uniform(0.015, 0.025)),
        imu_to_elbow_m=float(0.15 + rng.uniform(-0.04, 0.04)),
        imu_radial_m=float(rng.uniform(0.03, 0.05)),
        imu_radial_angle_deg=float(rng.uniform(-15.0, 15.0)),
        mount_axis=mount_axis,
        mount_angle_deg=float(rng.uniform(1.0, 3.0)),
        gyro_bias_dps=_signed(rng, 0.1, 0.8, 3),
        acc_bias_m_s2=_signed(rng, 0.05, 0.15, 3),
        wobble_hz=float(rng.uniform(4.0, 10.0)),
        wobble_damping=float(rng.uniform(0.15, 0.35)),
        wobble_mm_per_m_s2=float(rng.uniform(3.0, 6.0)),
        wobble_deg_per_m_s2=float(rng.uniform(1.0, 2.0)),
        wobble_axis=wobble_axis,
        latency_s=float(rng.uniform(0.02, 0.06)),
        rope_hz=float(rng.uniform(3.0, 6.0)),
        rope_decay_s=float(rng.uniform(0.08, 0.14)),
        rope_amp_m=float(rng.uniform(0.008, 0.011)),
        reference_error_m=(float(ref[0]), float(ref[1]), float(ref[2])),
    )


def without(subject: Subject, **switches: bool) -> Subject:
    """Copy of ``subject`` with the errors whose switch is False set to zero.

    Switch names: ``radial_offset``, ``misalignment``, ``gyro_bias``, ``acc_bias``, ``wobble``,
    ``latency``, ``rope``, ``reference_noise``.
    """
    zero3 = (0.0, 0.0, 0.0)
    off: dict[str, Any] = {}
    if not switches.get("radial_offset", True):
        off["imu_radial_m"] = 0.0
    if not switches.get("misalignment", True):
        off["mount_angle_deg"] = 0.0
    if not switches.get("gyro_bias", True):
        off["gyro_bias_dps"] = zero3
    if not switches.get("acc_bias", True):
        off["acc_bias_m_s2"] = zero3
    if not switches.get("wobble", True):
        off["wobble_mm_per_m_s2"] = 0.0
        off["wobble_deg_per_m_s2"] = 0.0
    if not switches.get("latency", True):
        off["latency_s"] = 0.0
    if not switches.get("rope", True):
        off["rope_amp_m"] = 0.0
    if not switches.get("reference_noise", True):
        off["reference_error_m"] = zero3
    return replace(subject, **off)
