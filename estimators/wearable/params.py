"""Wearable mode parameters (contract §8 keys plus the method's constants).

Noise defaults are the paper's table 5: σ_θ̈² = 1 (°/s²)² per 1 ms step, σ_ω² = 0.1 (°/s)²,
σ_a² = 0.01 (m/s²)², σ_p² = 1e-4 m². The paper's model is ``model="A"`` with
``gyro_bias=False, acc_bias=False, mounting_states=False, camera_offset_sigma_m=0``; the
product's default adds
gyro-bias states (see :mod:`.model`), accelerometer-bias states (model A),
mounting-misalignment states turning the readings exactly, the upper arm's soft tissue and the
camera's joint-centre offsets (:mod:`.mounting`); :data:`FIRST_ORDER` selects the product as it
was before the last three (the first-order turn).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from estimators.wearable.dh import F64, Geometry, quat_to_matrix

CONTRACT_KEYS = (
    "mode",
    "side",
    "upper_arm_length_m",
    "forearm_length_m",
    "upperarm_imu",
    "forearm_imu",
    "filter",
    "model",
)
# §4 keys of the robot mode: accepted in a wearable file, not used by this mode
_ROBOT_KEYS = (
    "imu_to_elbow_m",
    "cuff_to_elbow_m",
    "tolerance_m",
    "max_outside_fraction",
    "displacement_norm",
    "nominal_shoulder_m",
)
DEFAULT_QUAT = (0.5, 0.5, 0.5, -0.5)
MIRROR = np.diag([1.0, -1.0, 1.0])  # S's x–z plane: a left arm is the right one mirrored


# The product's settings until 2026-12-05, selectable (docs/benchmarks.md, "Per-angle
# confidence"): the mounting states' first-order turn, which lengthens a reading and lets an
# accelerometer's scale error tilt the arm (shown sure while 10° off on whole simulated
# trials), no accelerometer biases, no σ from the mounting states, and the drift bound's
# larger start that turn needed; nor the soft-tissue and camera-offset states nor the elbow's
# σ until its split is seen (added 2026-12-05 too).
FIRST_ORDER: dict[str, Any] = {
    "mounting_turn": "first_order",
    "acc_bias": False,
    "sigma_mounting_gain": 0.0,
    "sigma_mounting_change_gain": 0.0,
    "sigma_upper_change_gain": 0.0,
    "vertical_init_deg": 12.0,
    "soft_tissue_sigma": 0.0,
    "camera_offset_sigma_m": 0.0,
    "sigma_elbow_split_deg": 0.0,
    "sigma_dropout_share": 0.0,
    "sigma_camera_disagree_gain": 0.0,
}


class WearableParamsError(ValueError):
    """Parameters that cannot be used (unknown key, wrong type, out of range)."""


@dataclass(frozen=True, slots=True)
class Mounting:
    """An IMU's pose in its segment (U or F): ``position_m`` (m) and ``quat`` [w, x, y, z]
    rotating IMU coordinates into the segment's frame."""

    position_m: tuple[float, float, float]
    quat: tuple[float, float, float, float] = DEFAULT_QUAT


def _mirror_mounting(m: Mounting) -> Mounting:
    """The mirror image through S's x–z plane: position (x, −y, z), rotation M·R·M."""
    from estimators.wearable.dh import matrix_to_quat

    r = MIRROR @ quat_to_matrix(m.quat) @ MIRROR
    p = MIRROR @ np.asarray(m.position_m)
    q = matrix_to_quat(r)
    return Mounting(
        (float(p[0]), float(p[1]), float(p[2])),
        (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
    )


UPPER_DEFAULT = Mounting((0.0, -0.04, -0.24))
FORE_DEFAULT = Mounting((0.0, -0.03, -0.20))


@dataclass(frozen=True, slots=True)
class WearableParams:
    """Everything the wearable estimator needs. Angles in the contract's sense (§8).

    For ``side="left"`` the mountings are given in the left arm's own frames (which are the
    mirror image of the right's, contract §8); the estimator mirrors data and mountings onto
    a virtual right arm and the positions back. Missing left mountings default to the mirror
    image of the right defaults (the same anatomical place).
    """

    side: Literal["right", "left"] = "right"
    upper_arm_length_m: float = 0.30
    forearm_length_m: float = 0.25
    upperarm_imu: Mounting = UPPER_DEFAULT
    forearm_imu: Mounting = FORE_DEFAULT
    filter: Literal["ekf", "ukf"] = "ekf"
    # A: DH model (paper); B: inclinometer/gyro + GM-1 body-acceleration states; C: inclinometer
    # /gyro, no compensation; "I": inclinometer only (the zero-order model of §3.1).
    model: Literal["A", "B", "C", "I"] = "A"
    joints: tuple[int, ...] = (0, 1, 2, 3, 4)  # estimated joints (θ0, θ1, θ2, θ4, θ5); others 0
    forearm: bool = True  # use the forearm IMU (off: upper-arm joints only)
    # process noise: σ of the top derivative's increment per ``q_ref_dt_s`` step (paper eq. 4),
    # scaled with the step (discrete variance ∝ ts) so that 100 Hz and 1 kHz mean the same.
    sigma_ddtheta_dps2: float = 1.0  # model A (order 2): θ̈ increment, °/s²
    sigma_dtheta_dps: float = 1.0  # order 1 (B, C): θ̇ increment, °/s
    sigma_theta_deg: float = 1.0  # order 0 (I): θ increment, °
    q_ref_dt_s: float = 1e-3
    sigma_gyr_dps: float = math.sqrt(0.1)
    sigma_acc_ms2: float = 0.1
    sigma_pos_m: float = 0.01
    camera: bool = True  # use camera positions when there are some (σp² = ∞ otherwise)
    # model B's GM-1 body acceleration (paper ref. 17): correlation time and steady σ
    body_acc_tau_s: float = 0.2
    body_acc_sigma_ms2: float = 5.0
    # prior σ of each body-acceleration state, m/s² (None: a tenth of the steady σ). A random
    # walk (τ → ∞, the form eq. 3 gives the paper's own GM-1) has no steady σ to take it from.
    body_acc_init_sigma_ms2: float | None = None
    # product: gyro-bias random constants per IMU (off = the paper's model)
    gyro_bias: bool = True
    gyro_bias_sigma_dps: float = 0.5  # prior σ of each bias component
    gyro_bias_walk_dps_per_sqrt_s: float = 0.002
    # product: each IMU's mounting misalignment as three small-angle states (off = the paper's
    # model, which takes the mounting as exact; see :mod:`.mounting`)
    mounting_states: bool = True
    mounting_sigma_deg: float = 5.0  # prior σ of each component (a strap's few degrees)
    mounting_walk_deg_per_sqrt_s: float = 0.01  # slow change (skin and strap creep)
    # how a mounting state turns its IMU's readings (:mod:`.mounting`): exactly ("exact",
    # Exp(−δ)·v) or to first order ("first_order", v + v × δ: a reading |δ⊥v|²/2 longer, the
    # product's until 2026-12-05: docs/benchmarks.md)
    mounting_turn: Literal["first_order", "exact"] = "exact"
    # model A: accelerometer-bias random constants per IMU, added to its rows like the gyro's
    # (model B's body-acceleration states take those rows' slots; off = the paper's)
    acc_bias: bool = True
    acc_bias_sigma_ms2: float = 0.1  # prior σ of each component (a MEMS part's few 10 mg)
    acc_bias_walk_ms2_per_sqrt_s: float = 0.001
    # product: the upper-arm IMU's soft tissue as a gain ``c`` of the shoulder rotation (the
    # strap turns with (1 + c)·θ2: skin sliding over the humerus), a random constant of prior
    # σ ``soft_tissue_sigma`` (0: off = the paper's; needs ``mounting_states``). Only the
    # forearm IMU across a bent elbow tells θ2 from c·θ2, so ``c`` learns only while the
    # estimated elbow flexion is beyond ``soft_tissue_min_elbow_deg`` (before, a wrong θ2 at
    # a straight elbow drove it to −0.5 and the upper arm's gyro bias with it: :mod:`.mounting`)
    soft_tissue_sigma: float = 0.1
    soft_tissue_min_elbow_deg: float = 30.0
    # product: the camera's joint-centre offsets (elbow xyz, wrist xyz in S, m), random
    # constants added to its rows, prior σ ``camera_offset_sigma_m`` (0: off = the paper's
    # white camera noise). A markerless camera's joint centres are off by about a centimetre
    # per subject; read as positions, they bend a straight elbow by up to 17°. Half that
    # centimetre: at a full centimetre the states take the arm overhead (flexion 134°) 5–7 cm
    # off and abduction 11° with them (docs/benchmarks.md, "Per-angle confidence").
    camera_offset_sigma_m: float = 0.005
    # The EKF's own P is overconfident about the whole arm's turn about the vertical (it takes
    # information from linearising at a slightly tilted estimate): the reported confidence
    # adds a drift bound that grows at this rate (a residual gyro bias about the vertical) and
    # is reset by camera positions of a joint at least ``camera_fix_reach_m`` off the vertical.
    vertical_drift_dps: float = 0.2
    camera_fix_reach_m: float = 0.05
    # The bound starts at ``init_sigma_deg`` + this (P0 untouched): without a camera the whole
    # arm's turn about the vertical can go beyond 5° + 0.2 °/s from the first movement after
    # the start's rest. It follows neither the IMU's misalignment about the arm's axis nor the
    # pose (tried: ε (u − u₀), no better than a constant), so a constant: the least of 2, 3, 4,
    # 5, 6 that keeps abduction and rotation from being wrongly sure on more than 2 % of any
    # camera-less wheel or reaching trial of seeds 0–9, 200–219 and 400–419 (4 until
    # 2026-12-05, from the first two: the wheel's rotation on seeds 401 and 410 then 3.0 and
    # 6.9 %, with 5 seed 410 3.9 %; the first-order turn needed 12 on seeds 0–9:
    # docs/benchmarks.md). A camera's fix bounds it as before. 0: the bound of the paper's
    # method.
    vertical_init_deg: float = 6.0
    # The reported σ of each angle (θ0 θ1 θ2 θ4 θ5) adds what the filter's P cannot hold: the
    # errors that are biases, not eq. 19's white noise (scale factors, accelerometer bias,
    # segment lengths, soft tissue, the camera's offset and lag). Each angle's σ² gets
    # ``floor²`` plus ``(share·θ)²`` (θ from the zero pose): soft tissue and scale errors grow
    # with the angle; the forearm's skin turns most with pronation. Sized on simulated
    # sessions (benchmarks/wearable_paper.py --only coverage) for ~95 % of errors within 2σ;
    # zeros give the filter's own P (the paper's figure).
    # Pronation: soft tissue (the skin turns with the forearm) and the IMU's strap turned about
    # the forearm's axis read exactly as pronation, to gravity and camera alike: the error is
    # 15–25 % of the angle plus a constant of up to ~6° (seeds 0–2), hence its floor and share.
    sigma_floor_deg: tuple[float, float, float, float, float] = (2.0, 2.0, 2.0, 3.5, 4.0)
    sigma_share: tuple[float, float, float, float, float] = (0.03, 0.05, 0.05, 0.02, 0.20)
    # A large shoulder rotation (|θ2| beyond ``doubt_rotation_deg``; the arm turns about the
    # vertical, which gravity does not see) leaves offsets of 5–18° in the flexions and
    # pronation that persist for about a minute, at any later pose (the zero pose included),
    # while P stays at 0.1–0.5°; abduction is off by up to 16° during the rotation. With a
    # camera too (the doubt off while the camera held the vertical: the elbow shown sure but
    # off by > 7.5° on up to 15 % of a ROM trial). Each angle's σ² adds ``(doubt·g)²``, g the
    # rotation's excess in degrees, held at its peak and fading with ``doubt_tau_s`` (sample
    # time). Sized with the floors on seeds 0–2 so that an error beyond the dashboard's 7.5°
    # is not shown sure; zeros give the filter's own P.
    sigma_doubt: tuple[float, float, float, float, float] = (0.4, 0.3, 0.0, 0.4, 0.16)
    doubt_rotation_deg: float = 30.0
    doubt_tau_s: float = 60.0  # the offsets fade over about a minute (seeds 0–2)
    # Pronation is a turn about the forearm's axis: with the forearm vertical (the arm hanging)
    # it is a turn about the vertical, which gravity does not see. Its σ² adds
    # ``(sigma_pronation_vertical_deg·c²)²``, c the vertical component of the forearm's
    # direction (estimated elbow to wrist). Sized on seeds 0–2; zero gives the filter's P.
    sigma_pronation_vertical_deg: float = 4.0
    # What no sensor sees (:func:`.steps.unobserved`), sized on seeds 0–2; zeros give P.
    # With the elbow straight, shoulder rotation and pronation turn about the same axis: their
    # split is lost as the upper arm moves (errors of ±15° in opposite signs after the ROM
    # test's flexion and abduction, the camera on or off). Their σ² add a², a growing by
    # ``sigma_axial_share`` × the upper arm's motion (|Δθ0| + |Δθ1|) × cos² θ4, fading with
    # ``axial_tau_s`` × sin² θ4 once the elbow bends and the split is seen again.
    sigma_axial_share: float = 0.05
    axial_tau_s: float = 1.0
    # Pronation's copy of that bound fades slower: once the elbow bends, gravity corrects the
    # split's error in pronation over several seconds (−10° for ~8 s after the ROM moves'
    # abduction, seed 209), while shoulder rotation's was never shown sure and wrong; 3 s
    # (1 s as for rotation until 2026-12-05: docs/benchmarks.md, "Per-angle confidence").
    pronation_axial_tau_s: float = 3.0
    # With the forearm hanging, pronation drifts (a turn about the vertical; the gyro's bias
    # about the forearm's axis is not seen): its σ² adds b², b growing at this rate × (2c² − 1)
    # (c as above), back to 0 as the forearm comes up.
    pronation_drift_dps: float = 0.4
    # Without a camera an angle and its IMU's turn about the same axis are one quantity to
    # gravity and the gyros; only the size of the kinematic accelerations splits them (second
    # order, carrying soft tissue and scale errors), so the split slides (elbow 10–50° off in
    # the ROM moves). While no camera position has come for ``camera_hold_s``, each angle's σ
    # adds ``sigma_mounting_gain`` × the departure from nominal of the mounting states paired
    # with it (shoulder flexion: the upper-arm IMU's about its lateral axis; abduction: about
    # its forward axis; elbow flexion: both IMUs' about the lateral axis, the larger of their
    # signed difference, the elbow's error, and their quadrature sum); 0: off.
    sigma_mounting_gain: float = 1.0
    camera_hold_s: float = 5.0
    # A mounting state that has just moved is being learnt again: after the ROM moves' fast
    # overhead flexion the upper arm's states swing by 5–25° and back within seconds, abduction
    # 7–10° off meanwhile and shown sure (seeds 102, 203, 209), and the elbow's pair slides in
    # the elbow moves (seeds 300, 310; with a camera, 210, 505, 509). While there is no camera
    # (as above) each angle's σ adds ``sigma_mounting_change_gain`` × how far its paired
    # departure (as above) is from its average over ``mounting_change_tau_s``, the elbow's
    # with a camera too, and shoulder flexion's and abduction's ``sigma_upper_change_gain`` ×
    # the same for the upper-arm IMU's whole turn (all three states: the one about the arm's
    # long axis is paired with no angle, yet tilts their split once the arm is raised); 0:
    # off. (The shoulder's with a camera greyed the overhead flexion the camera holds, so the
    # ROM test's maximal flexion was not recorded.)
    sigma_mounting_change_gain: float = 1.0
    sigma_upper_change_gain: float = 0.5
    mounting_change_tau_s: float = 20.0
    # Without a camera the elbow's flexion and the forearm IMU's turn about the elbow's axis
    # are one quantity until the forearm turns about its own axis (pronation or supination
    # turns that axis away from the elbow's): the EKF's P of the elbow falls below 1° anyway
    # (the fast moves' kinematic accelerations split them, to second order, carrying scale
    # and length errors), and the ROM moves' straight elbow was shown sure 7.5–10° off in
    # their shoulder tests (seeds 700–839: 9 of 140 camera-less trials over 2 %). The elbow's
    # σ adds ``sigma_elbow_split_deg`` × (1 − s), s growing by Δt·sin²θ5 / ``elbow_split_tau_s``
    # to 1 (θ5 the estimated pronation; a camera sets it to 1; a restart to 0). 7°: the two
    # IMUs' prior turn about the elbow's axis (√2 × ``mounting_sigma_deg``); 6 left one of
    # those trials (13.5 %), 7 none (docs/benchmarks.md); 0: off.
    sigma_elbow_split_deg: float = 7.0
    elbow_split_tau_s: float = 2.0
    # A camera that drops out: the IMUs' mountings, which its positions were correcting, carry
    # the angles alone, and the EKF's σ of the elbow (0.35° with a camera) does not grow with
    # what they carry (ROM moves, seed 935: the elbow slid 2 → 9° off in a 2-s dropout, and the
    # camera, back, pulled it back only over seconds). Once a camera has been seen, θ0…θ3's σ
    # adds, while it is away, ``sigma_dropout_share`` × their motion since its last position
    # (deg per deg, up to ``sigma_dropout_cap_deg``), and with its positions
    # ``sigma_camera_disagree_gain`` × their disagreement with the estimate (the change of
    # θ0…θ3 that explains them, least squares, averaged over ``camera_disagree_tau_s``, against
    # the camera's offset states as averaged over ``camera_offset_tau_s``: the EKF explains
    # part of an angle's error by moving those constants); 0: off.
    sigma_dropout_share: float = 0.1
    sigma_dropout_cap_deg: float = 10.0
    sigma_camera_disagree_gain: float = 1.0
    camera_disagree_tau_s: float = 0.5
    camera_offset_tau_s: float = 20.0
    init_sigma_deg: float = 5.0  # prior σ of each angle at the zero pose (contract §8 "Start")
    # streams
    forearm_tolerance_s: float = 0.006  # a forearm sample this close pairs with the upper one
    forearm_missing_s: float = 0.1  # no forearm sample this long: steps go on without it
    camera_max_age_s: float = 0.2  # an older camera sample is rejected as stale
    max_gap_s: float = 0.25  # a longer upper-arm gap restarts the filter
    rest_s: float = 2.0  # the start at rest checked against the zero pose
    rest_gyro_dps: float = 20.0
    mounting_tolerance_deg: float = 20.0  # gravity at rest vs the zero pose's prediction
    max_gyro_rads: float = 35.0  # ~2000 °/s: a sample beyond it is a glitch, rejected
    max_acc_ms2: float = 160.0  # ~16 g
    nis_window: int = 100
    nis_limit: float = 5.0  # mean normalised innovation per row above this: flag
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if self.side not in ("right", "left"):
            raise WearableParamsError(f"side must be 'right' or 'left', not {self.side!r}")
        if self.filter not in ("ekf", "ukf"):
            raise WearableParamsError(f"filter must be 'ekf' or 'ukf', not {self.filter!r}")
        if self.mounting_turn not in ("first_order", "exact"):
            raise WearableParamsError(
                f"mounting_turn must be 'first_order' or 'exact', not {self.mounting_turn!r}"
            )
        if self.model not in ("A", "B", "C", "I"):
            raise WearableParamsError(f"model must be A, B or C, not {self.model!r}")
        for name in ("upper_arm_length_m", "forearm_length_m"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and 0.05 <= v <= 1.0):
                raise WearableParamsError(f"{name} must be a length in [0.05, 1] m, not {v!r}")
        for name in ("sigma_floor_deg", "sigma_share", "sigma_doubt"):
            v = getattr(self, name)
            if len(v) != 5 or not all(math.isfinite(c) and c >= 0 for c in v):
                raise WearableParamsError(f"{name} must be 5 finite numbers >= 0, not {v!r}")
        v = self.sigma_pronation_vertical_deg
        if not (math.isfinite(v) and v >= 0):
            raise WearableParamsError(f"sigma_pronation_vertical_deg must be >= 0, not {v!r}")
        for name in (
            "sigma_axial_share",
            "pronation_drift_dps",
            "vertical_init_deg",
            "soft_tissue_sigma",
            "camera_offset_sigma_m",
            "sigma_mounting_change_gain",
            "sigma_upper_change_gain",
            "sigma_elbow_split_deg",
            "sigma_dropout_share",
            "sigma_dropout_cap_deg",
            "sigma_camera_disagree_gain",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise WearableParamsError(f"{name} must be >= 0, not {v!r}")
        for name in (
            "doubt_rotation_deg",
            "doubt_tau_s",
            "axial_tau_s",
            "pronation_axial_tau_s",
            "mounting_change_tau_s",
            "elbow_split_tau_s",
            "camera_disagree_tau_s",
            "camera_offset_tau_s",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise WearableParamsError(f"{name} must be a finite number > 0, not {v!r}")
        v0 = self.body_acc_init_sigma_ms2
        if v0 is not None and not (math.isfinite(v0) and v0 > 0):
            raise WearableParamsError(f"body_acc_init_sigma_ms2 must be > 0 or None, not {v0!r}")
        if not self.joints or any(j not in range(5) for j in self.joints):
            raise WearableParamsError(f"joints must be indices 0..4, not {self.joints!r}")

    @property
    def estimated(self) -> tuple[int, ...]:
        """Estimated joints: the forearm's (3, 4) only with the forearm IMU."""
        return tuple(j for j in sorted(set(self.joints)) if self.forearm or j < 3)

    def geometry(self) -> Geometry:
        """The model's geometry on the (virtual) right arm."""
        up, fo = self.upperarm_imu, self.forearm_imu
        if self.side == "left":
            up, fo = _mirror_mounting(up), _mirror_mounting(fo)
        return Geometry(
            self.upper_arm_length_m,
            self.forearm_length_m,
            np.asarray(up.position_m, dtype=np.float64),
            quat_to_matrix(up.quat),
            np.asarray(fo.position_m, dtype=np.float64),
            quat_to_matrix(fo.quat),
        )

    @classmethod
    def from_json(cls, obj: dict[str, Any], **overrides: Any) -> WearableParams:
        """Parameters from a contract §8 object; unknown keys are refused."""
        if not isinstance(obj, dict):
            raise WearableParamsError("parameters must be a JSON object")
        mode = obj.get("mode", "wearable")
        if mode != "wearable":
            raise WearableParamsError(f"mode must be 'wearable' here, not {mode!r}")
        unknown = set(obj) - set(CONTRACT_KEYS) - set(_ROBOT_KEYS)
        if unknown:
            raise WearableParamsError(f"unknown parameter(s): {', '.join(sorted(unknown))}")
        kw: dict[str, Any] = {}
        side = obj.get("side", "right")
        kw["side"] = side
        for k in ("upper_arm_length_m", "forearm_length_m"):
            if k in obj:
                v = obj[k]
                if isinstance(v, bool) or not isinstance(v, int | float):
                    raise WearableParamsError(f"{k} must be a number")
                kw[k] = float(v)
        for k in ("filter", "model"):
            if k in obj:
                kw[k] = obj[k]
        for k, default in (("upperarm_imu", UPPER_DEFAULT), ("forearm_imu", FORE_DEFAULT)):
            if side == "left":
                default = _mirror_mounting(default)
            kw[k] = _mounting(k, obj.get(k), default)
        kw.update(overrides)
        return replace(cls(), **kw)


def _vector(name: str, v: Any, n: int) -> tuple[float, ...]:
    if (
        not isinstance(v, list | tuple)
        or len(v) != n
        or not all(isinstance(c, int | float) and not isinstance(c, bool) for c in v)
        or not all(math.isfinite(float(c)) for c in v)
    ):
        raise WearableParamsError(f"{name} must be {n} finite numbers")
    return tuple(float(c) for c in v)


def _mounting(name: str, obj: Any, default: Mounting) -> Mounting:
    if obj is None:
        return default
    if not isinstance(obj, dict) or set(obj) - {"position_m", "quat"}:
        raise WearableParamsError(f"{name} must be {{'position_m': [...], 'quat': [...]}}")
    pos = _vector(f"{name}.position_m", obj.get("position_m", default.position_m), 3)
    q = _vector(f"{name}.quat", obj.get("quat", default.quat), 4)
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > 1e-3:
        raise WearableParamsError(f"{name}.quat must be a unit quaternion (norm {norm:.4f})")
    if max(abs(c) for c in pos) > 1.0:
        raise WearableParamsError(f"{name}.position_m must be within 1 m of its joint")
    return Mounting((pos[0], pos[1], pos[2]), (q[0], q[1], q[2], q[3]))


def mirror_vectors(v: F64) -> F64:
    """Polar vectors (accelerations, positions) through S's x–z plane, (..., 3)."""
    return np.asarray(v * np.array([1.0, -1.0, 1.0]), dtype=np.float64)


def mirror_rates(v: F64) -> F64:
    """Angular rates (pseudovectors) through the mirror, in a mirrored sensor frame."""
    return np.asarray(v * np.array([-1.0, 1.0, -1.0]), dtype=np.float64)
