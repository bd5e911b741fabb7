"""Wearable-mode sessions: two IMUs (upper arm, forearm) and an optional camera (contract §8).

Honest by construction: the truth comes from :mod:`simulator.wearable_arm` (scipy rotations and
numerical differentiation, nothing shared with the filter), and every error source below is
applied to the data while the filter gets only the nominal parameters:

- IMU: white noise (table 5 of Alizadegan & Behzadipour 2016 by default), constant gyro and
  accelerometer biases, scale-factor errors, a mounting misalignment the filter does not know,
  soft-tissue motion (the IMU turns about the segment's long axis by a fraction of the
  segment's axial rotation);
- subject: segment lengths differ from the parameters given to the filter;
- camera: noise, a constant offset per joint (markerless joint-centre bias), lag, and dropouts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from protocol import recording, wire
from simulator import wearable_moves as moves
from simulator.wearable_arm import F64, Mount, imu_readings, joint_positions

DEFAULT_QUAT = (0.5, 0.5, 0.5, -0.5)  # contract §8: IMU x distal, y forward, z lateral
COLUMNS = (
    "shoulder_flexion_deg",
    "shoulder_abduction_deg",
    "shoulder_rotation_deg",
    "elbow_flexion_deg",
    "forearm_pronation_deg",
)


@dataclass(frozen=True)
class ImuErrors:
    """Sensor errors; :meth:`paper` is table 5's white noise alone."""

    gyro_noise_dps: float = float(np.sqrt(0.1))
    acc_noise_ms2: float = 0.1
    gyro_bias_dps: float = 0.5  # σ of each constant bias component
    acc_bias_ms2: float = 0.05
    scale: float = 0.01  # σ of each axis' scale-factor error
    misalignment_deg: float = 3.0  # σ of the mounting rotation the filter does not know
    sta_upper: float = 0.10  # soft tissue: IMU turn per unit of θ2 (upper arm)
    sta_fore: float = 0.15  # ... per unit of θ5 (forearm)

    @classmethod
    def paper(cls) -> ImuErrors:
        return cls(
            gyro_bias_dps=0.0,
            acc_bias_ms2=0.0,
            scale=0.0,
            misalignment_deg=0.0,
            sta_upper=0.0,
            sta_fore=0.0,
        )


@dataclass(frozen=True)
class CameraErrors:
    noise_m: float = 0.01
    offset_m: float = 0.01  # σ of a constant offset per joint
    lag_s: float = 0.05
    rate_hz: float = 30.0
    dropouts_per_min: float = 3.0
    dropout_s: tuple[float, float] = (0.5, 2.0)

    @classmethod
    def paper(cls) -> CameraErrors:
        """The paper's camera: white noise of σp = 1 cm (table 5), nothing else."""
        return cls(offset_m=0.0, lag_s=0.0, dropouts_per_min=0.0)


@dataclass(frozen=True)
class WearableSimConfig:
    move: str = "reaching"  # simulator.wearable_moves.MOVES
    duration_s: float = 60.0
    seed: int = 0
    imu_hz: float = 100.0
    imu_batch: int = 10
    camera: bool = True
    side: str = "right"
    device: str = "wear01"
    imu: ImuErrors = field(default_factory=ImuErrors)
    cam: CameraErrors = field(default_factory=CameraErrors)
    upper_arm_m: float = 0.30  # nominal, given to the filter
    forearm_m: float = 0.25
    length_error_m: float = 0.01  # σ of the subject's true lengths about the nominal ones
    upper_imu_m: tuple[float, float, float] = (0.0, -0.04, -0.24)
    fore_imu_m: tuple[float, float, float] = (0.0, -0.03, -0.20)
    sine_amp_deg: float = 90.0
    sine_hz: float = 1.0
    wheel: moves.Wheel = field(default_factory=moves.Wheel)


@dataclass(frozen=True)
class WearableSimulation:
    config: WearableSimConfig
    t: F64  # (N,) IMU times, s
    theta_deg: F64  # (N, 5) true angles (contract §8 names in COLUMNS)
    elbow: F64  # (N, 3) true positions in S, m
    wrist: F64
    upper: tuple[F64, F64]  # measured gyro (rad/s), specific force (m/s²), (N,3) each
    fore: tuple[F64, F64]
    camera: tuple[F64, F64, F64]  # t (M,), elbow, wrist (M,3) as received (after dropouts)
    params: dict[str, Any]  # contract §8 parameters for the filter (nominal values)
    truth: dict[str, Any]  # the subject's true values
    messages: list[tuple[str, dict[str, Any]]] = field(repr=False)

    def summary(self) -> str:
        c = self.config
        return (
            f"{c.move}, seed {c.seed}: {c.duration_s:g} s at {c.imu_hz:g} Hz, "
            f"{len(self.t)} samples per IMU, {len(self.camera[0])} camera samples, "
            f"{len(self.messages)} messages"
        )


def theta_function(cfg: WearableSimConfig) -> moves.ThetaFn:
    if cfg.move == "flexion_sine":
        return moves.flexion_sine(cfg.sine_amp_deg, cfg.sine_hz)
    if cfg.move == "shoulder_wheel":
        return moves.shoulder_wheel(cfg.wheel)
    if cfg.move == "reaching":
        return moves.reaching(cfg.duration_s)
    if cfg.move == "rom":
        return moves.rom()
    raise ValueError(f"unknown movement {cfg.move!r}; one of {', '.join(moves.MOVES)}")


def _small_rotation(rng: np.random.Generator, sigma_deg: float) -> F64:
    return np.asarray(
        Rotation.from_rotvec(rng.normal(0.0, np.radians(sigma_deg), 3)).as_matrix(),
        dtype=np.float64,
    )


def _corrupt(rng: np.random.Generator, gyr: F64, acc: F64, e: ImuErrors) -> tuple[F64, F64]:
    sg = 1.0 + rng.normal(0.0, e.scale, 3)
    sa = 1.0 + rng.normal(0.0, e.scale, 3)
    bg = rng.normal(0.0, np.radians(e.gyro_bias_dps), 3)
    ba = rng.normal(0.0, e.acc_bias_ms2, 3)
    g = gyr * sg + bg + rng.normal(0.0, np.radians(e.gyro_noise_dps), gyr.shape)
    a = acc * sa + ba + rng.normal(0.0, e.acc_noise_ms2, acc.shape)
    return g, a


def simulate(cfg: WearableSimConfig) -> WearableSimulation:
    """Simulate one session; deterministic in ``cfg.seed``."""
    rng = np.random.default_rng(cfg.seed)
    fn = theta_function(cfg)
    upper_true = cfg.upper_arm_m + rng.normal(0.0, cfg.length_error_m)
    fore_true = cfg.forearm_m + rng.normal(0.0, cfg.length_error_m)
    if cfg.move == "shoulder_wheel":  # table 7's subject (the wheel's inverse kinematics)
        upper_true, fore_true = cfg.wheel.upper_m, cfg.wheel.fore_m
    r_nom = Rotation.from_quat([*DEFAULT_QUAT[1:], DEFAULT_QUAT[0]]).as_matrix()
    mu = Mount(
        np.array(cfg.upper_imu_m),
        _small_rotation(rng, cfg.imu.misalignment_deg) @ r_nom,
        cfg.imu.sta_upper,
    )
    mf = Mount(
        np.array(cfg.fore_imu_m),
        _small_rotation(rng, cfg.imu.misalignment_deg) @ r_nom,
        cfg.imu.sta_fore,
    )
    t = np.round(np.arange(0.0, cfg.duration_s, 1.0 / cfg.imu_hz), 6)
    th = fn(t)
    gu, au = imu_readings(fn, t, 0, mu, upper_true)
    gf, af = imu_readings(fn, t, 1, mf, upper_true)
    gu, au = _corrupt(rng, gu, au, cfg.imu)
    gf, af = _corrupt(rng, gf, af, cfg.imu)
    elbow, wrist = joint_positions(th, upper_true, fore_true)
    # camera: lagged truth + per-joint offset + noise, minus dropouts
    c = cfg.cam
    tc = np.round(np.arange(0.0, cfg.duration_s, 1.0 / c.rate_hz), 6)
    ce, cw = joint_positions(fn(tc - c.lag_s), upper_true, fore_true)
    ce = ce + rng.normal(0.0, c.offset_m, 3) + rng.normal(0.0, c.noise_m, ce.shape)
    cw = cw + rng.normal(0.0, c.offset_m, 3) + rng.normal(0.0, c.noise_m, cw.shape)
    keep = np.ones(len(tc), dtype=bool)
    n_drop = rng.poisson(c.dropouts_per_min * cfg.duration_s / 60.0)
    for start in rng.uniform(0.0, cfg.duration_s, n_drop):
        keep &= ~((tc >= start) & (tc < start + rng.uniform(*c.dropout_s)))
    if not cfg.camera:
        keep[:] = False
    tc, ce, cw = tc[keep], ce[keep], cw[keep]
    if cfg.side == "left":  # the mirror image through S's x–z plane (contract §8)
        flip_v, flip_w = np.array([1.0, -1.0, 1.0]), np.array([-1.0, 1.0, -1.0])
        gu, au, gf, af = gu * flip_w, au * flip_v, gf * flip_w, af * flip_v
        ce, cw, elbow, wrist = ce * flip_v, cw * flip_v, elbow * flip_v, wrist * flip_v
    params = _params(cfg)
    truth = {
        "upper_arm_length_m": upper_true,
        "forearm_length_m": fore_true,
        "upperarm_imu_R": mu.rotation.tolist(),
        "forearm_imu_R": mf.rotation.tolist(),
    }
    msgs = _messages(cfg, t, gu, au, gf, af, tc, ce, cw)
    return WearableSimulation(
        cfg, t, np.degrees(th), elbow, wrist, (gu, au), (gf, af), (tc, ce, cw), params, truth, msgs
    )


def _params(cfg: WearableSimConfig) -> dict[str, Any]:
    flip = -1.0 if cfg.side == "left" else 1.0
    up = [cfg.upper_imu_m[0], flip * cfg.upper_imu_m[1], cfg.upper_imu_m[2]]
    fo = [cfg.fore_imu_m[0], flip * cfg.fore_imu_m[1], cfg.fore_imu_m[2]]
    out: dict[str, Any] = {
        "mode": "wearable",
        "side": cfg.side,
        "upper_arm_length_m": cfg.upper_arm_m if cfg.move != "shoulder_wheel" else 0.22,
        "forearm_length_m": cfg.forearm_m if cfg.move != "shoulder_wheel" else 0.20,
        "filter": "ekf",
        "model": "A",
    }
    if cfg.side == "right":
        out["upperarm_imu"] = {"position_m": up, "quat": list(DEFAULT_QUAT)}
        out["forearm_imu"] = {"position_m": fo, "quat": list(DEFAULT_QUAT)}
    return out  # a left arm's mountings: the mirrored defaults of the parameters


def _messages(
    cfg: WearableSimConfig, t: F64, gu: F64, au: F64, gf: F64, af: F64, tc: F64, ce: F64, cw: F64
) -> list[tuple[str, dict[str, Any]]]:
    """Contract messages in arrival order (by the time of each message's last sample; the
    camera's come ``lag`` later)."""
    queue: list[tuple[float, int, int, tuple[str, dict[str, Any]]]] = []
    b = cfg.imu_batch
    for seq, i in enumerate(range(0, len(t), b)):
        sl = slice(i, i + b)
        for k, (seg, g, a) in enumerate((("upperarm", gu, au), ("forearm", gf, af))):
            m = wire.ImuMessage(cfg.device, seg, t[sl], g[sl], a[sl], seq)
            queue.append((float(t[sl][-1]), k, seq, wire.encode(m)))
    cb = max(1, int(round(cfg.cam.rate_hz * b / cfg.imu_hz)))
    for seq, i in enumerate(range(0, len(tc), cb)):
        sl = slice(i, i + cb)
        cm = wire.CameraMessage(cfg.device, tc[sl], ce[sl], cw[sl], None, seq)
        queue.append((float(tc[sl][-1]) + cfg.cam.lag_s, 2, seq, wire.encode(cm)))
    queue.sort(key=lambda q: (q[0], q[1], q[2]))
    return [q[3] for q in queue]


def write(sim: WearableSimulation, out: Path) -> dict[str, Path]:
    """Write DIR/recording.jsonl.gz, DIR/params.json, DIR/truth.csv; return the paths."""
    import json

    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "recording": out / "recording.jsonl.gz",
        "params": out / "params.json",
        "truth": out / "truth.csv",
    }
    recording.write(paths["recording"], sim.messages)
    paths["params"].write_text(json.dumps(sim.params, indent=2) + "\n")
    header = ",".join(
        ("t", *COLUMNS, "elbow_x", "elbow_y", "elbow_z", "wrist_x", "wrist_y", "wrist_z")
    )
    data = np.column_stack((sim.t, sim.theta_deg, sim.elbow, sim.wrist))
    np.savetxt(paths["truth"], data, delimiter=",", header=header, comments="", fmt="%.6f")
    return paths


def tracker_inputs(
    messages: list[tuple[str, dict[str, Any]]],
) -> list[tuple[str, F64, F64, F64]]:
    """Contract messages as the wearable tracker's ``(kind, t, u, v)`` inputs, in order."""
    out: list[tuple[str, F64, F64, F64]] = []
    for key, p in messages:
        kind = key.rsplit("/", 1)[-1]
        t = np.asarray(p["t"], dtype=np.float64)
        if kind in ("upperarm", "forearm"):
            out.append(
                (
                    kind,
                    t,
                    np.asarray(p["gyr"], dtype=np.float64),
                    np.asarray(p["acc"], dtype=np.float64),
                )
            )
        elif kind == "camera":
            out.append(
                (
                    kind,
                    t,
                    np.asarray(p["elbow"], dtype=np.float64),
                    np.asarray(p["wrist"], dtype=np.float64),
                )
            )
    return out
