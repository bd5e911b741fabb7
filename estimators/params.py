"""Pipeline parameters: the contract's (§4) plus every constant of the method.

Defaults are the paper's values unless the improved method needs its own; the paper's
method is ``PipelineParams(method="paper")``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

from estimators.heading import HeadingParams

CONTRACT_KEYS = (
    "upper_arm_length_m",
    "imu_to_elbow_m",
    "cuff_to_elbow_m",
    "tolerance_m",
    "max_outside_fraction",
    "displacement_norm",
    "nominal_shoulder_m",
)


class ParamsError(ValueError):
    """Parameters that cannot be used (unknown key, wrong type, out of range)."""


@dataclass(frozen=True, slots=True)
class PipelineParams:
    # contract §4
    upper_arm_length_m: float = 0.30
    imu_to_elbow_m: float = 0.15
    cuff_to_elbow_m: float = 0.06
    tolerance_m: float = 0.10
    max_outside_fraction: float = 0.20
    displacement_norm: Literal["horizontal", "3d"] = "horizontal"
    nominal_shoulder_m: tuple[float, float, float] | None = None
    # method
    method: Literal["paper", "improved"] = "improved"
    heading: HeadingParams | None = None  # None: the method's own defaults
    fusion_rate_hz: float = 25.0  # common time base of the two accelerations (§3.2.1)
    lowpass_order: int = 5  # 5th-order Butterworth ...
    lowpass_cutoff_hz: float = 0.5  # ... at 0.5 Hz on both accelerations
    highpass_hz: float | None = None  # common high-pass on both accelerations; None: 0.1 Hz
    # for the improved method, off for the paper's
    antialias: bool | None = None  # centred anti-alias kernel before the grid; None: improved only
    gyro_lowpass_hz: float = 2.5  # paper: ω̇ from a 2.5 Hz low-passed gyro (paper method only)
    mounting_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  # A in sensor frame
    vqf_tau_acc_s: float = 3.0  # 6D filter's accelerometer time constant (VQF's tauAcc)
    # elbow angle: "paired" (both at the robot's instant), "fresh" (IMU now, robot forearm as
    # is) or "extrapolate" (forearm axis carried forward by the estimated latency); None:
    # "fresh" for the improved method, "paired" (the paper's eq. 11 at one instant) for the paper
    elbow_angle_timing: Literal["paired", "fresh", "extrapolate"] | None = None
    # streams
    robot_time_offset_s: float = 0.0  # robot stamps are this late (latency)
    imu_max_bridge_s: float = 0.1  # IMU gaps up to this are interpolated; longer ones reset
    robot_max_bridge_s: float = 0.3  # robot gaps up to this are interpolated for the fusion
    imu_wait_s: float = 0.5  # a robot sample waits this long (robot time) for the IMU
    # An IMU message ending more than this far (s) ahead of the robot's newest stamp (offset
    # corrected; before any robot data: of the stream's first IMU stamp) is rejected, counted
    # as "imu_without_robot": without robot data nothing lets the pipeline forget IMU samples,
    # so this bounds what a device sending IMU only holds (30 s at 1000 Hz: ~7 MB).
    imu_lead_max_s: float = 30.0
    # A robot sample the IMU has not reached yet, but is at most this far behind (s), is
    # computed at once with the upper arm predicted from the newest IMU sample by its gyro:
    # the row does not wait for the next IMU message (up to one message period, 40 ms for
    # 4 samples at 100 Hz). 0: every row waits for the IMU. None: 0.05 s for the improved
    # method, 0 for the paper's.
    imu_predict_s: float | None = None
    rate_probe_samples: int = 5
    # nominal shoulder and arm length
    auto_nominal_s: float = 2.0  # automatic nominal: mean estimate over this long after convergence
    # "fixed": upper_arm_length_m as given (the paper); "calibrate": measured at the rope
    # reference (improved). None: the method's own.
    arm_length: Literal["fixed", "calibrate"] | None = None
    arm_reference_s: float = 0.5  # elbow averaged this long after a shoulder_reference
    arm_length_bounds_m: tuple[float, float] = (0.22, 0.40)
    # compensation rule
    warning_after_s: float | None = None  # None: max_outside_fraction × last cycle duration
    cycle_mode: Literal["auto", "path", "events", "reach"] = "auto"
    extra: dict[str, Any] = field(default_factory=dict)  # reserved

    @property
    def highpass(self) -> float:
        if self.highpass_hz is not None:
            return self.highpass_hz
        return 0.0 if self.method == "paper" else 0.1

    @property
    def use_antialias(self) -> bool:
        return self.antialias if self.antialias is not None else self.method != "paper"

    @property
    def arm_length_mode(self) -> Literal["fixed", "calibrate"]:
        if self.arm_length is not None:
            return self.arm_length
        return "fixed" if self.method == "paper" else "calibrate"

    @property
    def angle_timing(self) -> Literal["paired", "fresh", "extrapolate"]:
        if self.elbow_angle_timing is not None:
            return self.elbow_angle_timing
        return "paired" if self.method == "paper" else "fresh"

    @property
    def predict_s(self) -> float:
        if self.imu_predict_s is not None:
            return self.imu_predict_s
        return 0.0 if self.method == "paper" else 0.05

    @property
    def heading_params(self) -> HeadingParams:
        if self.heading is not None:
            return self.heading
        return HeadingParams.paper() if self.method == "paper" else HeadingParams()

    @classmethod
    def from_json(cls, obj: dict[str, Any]) -> PipelineParams:
        """Build from a contract parameters object; unknown keys are an error."""
        if not isinstance(obj, dict):
            raise ParamsError("parameters must be a JSON object")
        names = {f.name for f in dataclasses.fields(cls)} - {"heading"}
        unknown = sorted(set(obj) - names - {"heading"})
        if unknown:
            raise ParamsError(f"unknown parameter(s): {', '.join(unknown)}")
        kw: dict[str, Any] = {}
        for k, v in obj.items():
            if v is None:
                continue
            if k == "heading":
                if not isinstance(v, dict):
                    raise ParamsError("heading must be an object")
                base = HeadingParams.paper() if obj.get("method") == "paper" else HeadingParams()
                try:
                    kw[k] = dataclasses.replace(base, **v)
                except TypeError as exc:
                    raise ParamsError(f"heading: {exc}") from None
            elif k in ("nominal_shoulder_m", "mounting_quat", "arm_length_bounds_m"):
                n = {"nominal_shoulder_m": 3, "mounting_quat": 4, "arm_length_bounds_m": 2}[k]
                if not isinstance(v, list) or len(v) != n or not all(_num(x) for x in v):
                    raise ParamsError(f"{k} must be a list of {n} numbers")
                kw[k] = tuple(float(x) for x in v)
            elif k in (
                "displacement_norm",
                "method",
                "arm_length",
                "cycle_mode",
                "elbow_angle_timing",
            ):
                kw[k] = v
            elif k == "extra":
                kw[k] = dict(v)
            elif k == "antialias":
                if not isinstance(v, bool):
                    raise ParamsError("antialias must be true or false")
                kw[k] = v
            elif k == "lowpass_order" or k == "rate_probe_samples":
                if not isinstance(v, int) or isinstance(v, bool):
                    raise ParamsError(f"{k} must be an integer")
                kw[k] = v
            else:
                if not _num(v):
                    raise ParamsError(f"{k} must be a number")
                kw[k] = float(v)
        p = cls(**kw)
        p.validate()
        return p

    def validate(self) -> None:
        checks = [
            (0.05 <= self.upper_arm_length_m <= 1.0, "upper_arm_length_m in [0.05, 1]"),
            (0.0 <= self.imu_to_elbow_m <= 1.0, "imu_to_elbow_m in [0, 1]"),
            (0.0 <= self.cuff_to_elbow_m <= 1.0, "cuff_to_elbow_m in [0, 1]"),
            (self.tolerance_m > 0, "tolerance_m > 0"),
            (0.0 <= self.max_outside_fraction <= 1.0, "max_outside_fraction in [0, 1]"),
            (self.displacement_norm in ("horizontal", "3d"), "displacement_norm horizontal|3d"),
            (self.method in ("paper", "improved"), "method paper|improved"),
            (self.arm_length in (None, "fixed", "calibrate"), "arm_length fixed|calibrate"),
            (
                self.elbow_angle_timing in (None, "paired", "fresh", "extrapolate"),
                "elbow_angle_timing paired|fresh|extrapolate",
            ),
            (self.cycle_mode in ("auto", "path", "events", "reach"), "cycle_mode"),
            (1.0 <= self.fusion_rate_hz <= 200.0, "fusion_rate_hz in [1, 200]"),
            (0 < self.lowpass_cutoff_hz < self.fusion_rate_hz / 2, "lowpass below Nyquist"),
            (self.rate_probe_samples >= 2, "rate_probe_samples >= 2"),
            (0.0 <= self.predict_s <= 0.2, "imu_predict_s in [0, 0.2]"),
            (self.imu_lead_max_s >= 1.0, "imu_lead_max_s >= 1"),
        ]
        bad = [msg for ok, msg in checks if not ok]
        if bad:
            raise ParamsError("; ".join(bad))

    def to_json(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out.pop("extra")
        out["heading"] = dataclasses.asdict(self.heading_params)
        # what the method resolved its unset options to (the report says what ran)
        out["arm_length"] = self.arm_length_mode
        out["elbow_angle_timing"] = self.angle_timing
        out["imu_predict_s"] = self.predict_s
        return out


def _num(x: Any) -> bool:
    return (
        isinstance(x, (int, float))
        and not isinstance(x, bool)
        and x == x
        and abs(x) != float("inf")
    )
