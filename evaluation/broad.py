"""BROAD trials as contract recordings, with ground truth and the paper's error metrics.

Data: the Berlin Robust Orientation Estimation Assessment Dataset (BROAD) by D. Laidig,
M. Caruso, A. Cereatti, T. Seel, "BROAD—A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7):72, 2021, https://doi.org/10.3390/data6070072, licensed CC-BY-4.0.
Keep this attribution wherever the data or results derived from it go.

A trial holds one IMU (gyro, accelerometer) at 285.714 Hz and the optical pose of its
marker body. :func:`convert` turns it into a contract recording (list of ``(key, payload)``
in arrival order) in which a *virtual elbow*, rigidly attached 15 cm along the IMU's x axis
and computed from the optical pose, plays the robot at 25 Hz. The optical world frame
(z up), turned about z by a known yaw, is the robot frame R; the IMU frame is the
upper-arm frame A (mounting = identity), so the ground truth ``q_ref`` is directly
comparable with a pipeline's ``q_RA``.

Two corrections make the streams physically consistent (see :func:`estimate_lag` and
:func:`fit_acc_offset`): the IMU lags the optical stream by ~3.8 ms (3.7–4.0 ms per
trial), and the accelerometer sits ~0.9 cm from the optical body origin, mostly along the
sensor's z axis. The virtual elbow is placed 15 cm from the *accelerometer*, the point
whose lever arm the method models; at the method's 0.5 Hz this shifts the acceleration-
matched heading by up to ~2° on the slow-rotation trial, and by < 0.5° elsewhere.

Scoring follows the BROAD paper: ``q_err = q_est ⊗ q_ref⁻¹``, heading ``2·atan(|z/w|)``,
inclination ``2·acos(√(w²+z²))``, total ``2·acos(|w|)``. Quaternions are (w, x, y, z)
throughout, and ``q`` maps sensor coordinates to world coordinates.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar
from scipy.signal import butter, sosfiltfilt

from protocol import wire

FloatArray: TypeAlias = NDArray[np.float64]
BoolArray: TypeAlias = NDArray[np.bool_]
Recording: TypeAlias = list[tuple[str, dict[str, Any]]]

GRAVITY_M_S2 = 9.81
ENV_DIR = "REHAB_BROAD_DIR"
# Accelerometer position in the sensor frame relative to the optical body origin, metres.
# Mean of fit_acc_offset over the eight trials (per-trial fits within ±4 mm of it).
ACC_OFFSET_M: tuple[float, float, float] = (-0.0012, 0.0, 0.0088)


# --------------------------------------------------------------------------- data access


def data_dir() -> Path:
    """The BROAD directory: ``$REHAB_BROAD_DIR``, else ``<repo>/../shared/data/broad``."""
    env = os.environ.get(ENV_DIR)
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[1]
    return repo.parent / "shared" / "data" / "broad"


def trial_paths(directory: str | Path | None = None) -> list[Path]:
    """All ``*.npz`` trials in ``directory`` (default :func:`data_dir`), sorted by name."""
    d = Path(directory) if directory is not None else data_dir()
    return sorted(d.glob("*.npz")) if d.is_dir() else []


@dataclass(frozen=True)
class Trial:
    """One BROAD trial, sample-aligned arrays of length N as stored in the archive.

    ``gyr`` (N,3) rad/s and ``acc`` (N,3) m/s² in the sensor frame; ``opt_quat`` (N,4)
    sensor→world and ``opt_pos`` (N,3) m of the optical body origin, NaN rows where
    tracking was lost; ``movement`` (N,) the samples BROAD scores; ``rate_hz`` (≈285.714).
    """

    name: str
    rate_hz: float
    gyr: FloatArray
    acc: FloatArray
    opt_quat: FloatArray
    opt_pos: FloatArray
    movement: BoolArray

    @property
    def n(self) -> int:
        return int(self.gyr.shape[0])

    @property
    def optical_valid(self) -> BoolArray:
        """(N,) True where both optical quaternion and position are finite."""
        ok = np.isfinite(self.opt_quat).all(axis=1) & np.isfinite(self.opt_pos).all(axis=1)
        return np.asarray(ok, dtype=bool)


def load_trial(path: str | Path) -> Trial:
    """Read one BROAD ``.npz`` (float32 IMU data is widened to float64)."""
    p = Path(path)
    with np.load(p) as z:
        return Trial(
            name=p.stem,
            rate_hz=float(z["sampling_rate"]),
            gyr=np.asarray(z["imu_gyr"], dtype=np.float64),
            acc=np.asarray(z["imu_acc"], dtype=np.float64),
            opt_quat=np.asarray(z["opt_quat"], dtype=np.float64),
            opt_pos=np.asarray(z["opt_pos"], dtype=np.float64),
            movement=np.asarray(z["movement"], dtype=bool),
        )


# --------------------------------------------------------------------------- quaternions


def quat_mul(a: FloatArray, b: FloatArray) -> FloatArray:
    """Hamilton product ``a ⊗ b`` of (...,4) wxyz arrays (broadcasting)."""
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quat_conj(q: FloatArray) -> FloatArray:
    """Conjugate (= inverse for unit quaternions), (...,4) wxyz."""
    out: FloatArray = q * np.array([1.0, -1.0, -1.0, -1.0])
    return out


def quat_rotate(q: FloatArray, v: FloatArray) -> FloatArray:
    """Rotate vectors ``v`` (...,3) by unit quaternions ``q`` (...,4): ``q ⊗ v ⊗ q*``."""
    w = q[..., :1]
    u = q[..., 1:]
    uv = np.cross(u, v)
    out: FloatArray = v + 2.0 * (w * uv + np.cross(u, uv))
    return out


def quat_z(angle_rad: float | FloatArray) -> FloatArray:
    """Rotation about the vertical as (...,4) wxyz: ``[cos δ/2, 0, 0, sin δ/2]``."""
    a = np.asarray(angle_rad, dtype=np.float64) / 2.0
    z = np.zeros_like(a)
    return np.stack([np.cos(a), z, z, np.sin(a)], axis=-1)


def interp_quat(t_src: FloatArray, q_src: FloatArray, t: FloatArray) -> FloatArray:
    """Normalised linear interpolation of (N,4) ``q_src`` at times ``t`` (M,) → (M,4).

    ``t_src`` must increase. NaN outside ``t_src`` and wherever a neighbour is NaN
    (lost tracking is never bridged).
    """
    t = np.asarray(t, dtype=np.float64)
    out = np.full((t.shape[0], 4), np.nan)
    if t_src.shape[0] < 2:
        return out
    k = np.clip(np.searchsorted(t_src, t, side="right") - 1, 0, t_src.shape[0] - 2)
    inside = (t >= t_src[0]) & (t <= t_src[-1])
    a = (t - t_src[k]) / (t_src[k + 1] - t_src[k])
    out[inside] = _nlerp(q_src[k], q_src[k + 1], a)[inside]
    return out


def _nlerp(q0: FloatArray, q1: FloatArray, a: FloatArray) -> FloatArray:
    # Neighbours 3.5 ms apart: nlerp equals slerp far below the optical noise.
    sign = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    q = (1.0 - a)[:, None] * q0 + a[:, None] * sign * q1
    out: FloatArray = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return out


# --------------------------------------------------------------------------- clock and lever


def _optical_at(trial: Trial, s: FloatArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Optical (pos (M,3), quat (M,4), valid (M,)) at fractional optical indices ``s``.

    Invalid (NaN rows) where ``s`` is out of range or either neighbour is lost.
    """
    n = trial.n
    k0 = np.floor(s).astype(np.int64)
    inside = (k0 >= 0) & (k0 + 1 <= n - 1)
    k0c = np.clip(k0, 0, n - 2)
    ok = trial.optical_valid
    valid = inside & ok[k0c] & ok[k0c + 1]
    a = s - k0c
    pos = np.full((s.shape[0], 3), np.nan)
    quat = np.full((s.shape[0], 4), np.nan)
    q0, q1 = trial.opt_quat[k0c[valid]], trial.opt_quat[k0c[valid] + 1]
    quat[valid] = _nlerp(q0, q1, a[valid])
    p0, p1 = trial.opt_pos[k0c[valid]], trial.opt_pos[k0c[valid] + 1]
    pos[valid] = p0 + a[valid, None] * (p1 - p0)
    return pos, quat, valid


def estimate_lag(trial: Trial, max_lag_s: float = 0.035) -> float:
    """Delay of the IMU behind the optical stream, seconds (positive = IMU late).

    Minimises the mean squared ``gyr(i) − ω_opt(i − L) − b`` over the sub-sample lag L
    (|L| ≤ ``max_lag_s``), with ``ω_opt`` the body rate from consecutive optical
    quaternions and b the mean gyro bias. The gyro is used because both systems observe
    rotation directly (no double differentiation of noisy positions).
    """
    q = trial.opt_quat
    ok = trial.optical_valid
    # Body-frame rate between optical samples k and k+1 (q_{k+1} = q_k ⊗ Δ), at index k + 0.5.
    dq = quat_mul(quat_conj(q[:-1]), q[1:])
    dq = np.where(dq[:, :1] < 0.0, -dq, dq)
    vec = dq[:, 1:]
    s = np.linalg.norm(vec, axis=1)
    ang = 2.0 * np.arctan2(s, dq[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        w_opt = np.where(s[:, None] > 1e-12, vec * (ang / s)[:, None], 2.0 * vec) * trial.rate_hz
    w_ok = ok[:-1] & ok[1:]
    n_w = trial.n - 1
    idx = np.arange(trial.n, dtype=np.float64)

    def cost(lag: float) -> float:
        x = idx - lag - 0.5  # position in w_opt's index space
        j = np.clip(np.floor(x).astype(np.int64), 0, n_w - 2)
        use = (x >= 0) & (x <= n_w - 1) & w_ok[j] & w_ok[j + 1]
        a = (x - j)[use, None]
        w = (1.0 - a) * w_opt[j[use]] + a * w_opt[j[use] + 1]
        r = trial.gyr[use] - w
        r -= r.mean(axis=0)
        return float(np.mean(np.sum(r * r, axis=1)))

    max_lag = max_lag_s * trial.rate_hz
    grid = np.arange(-np.floor(max_lag), np.floor(max_lag) + 1.0)
    best = float(grid[int(np.argmin([cost(float(g)) for g in grid]))])
    res = minimize_scalar(
        cost, bounds=(best - 1.0, best + 1.0), method="bounded", options={"xatol": 1e-3}
    )
    return float(res.x) / trial.rate_hz


def fit_acc_offset(
    trial: Trial, lag_s: float, cutoff_hz: float = 8.0
) -> tuple[FloatArray, FloatArray]:
    """Accelerometer position relative to the optical body origin, sensor frame.

    Least squares on ``f − Rᵀ(p̈ + g) = ω̇ × r + ω × (ω × r) + b`` after a zero-phase
    low-pass (``cutoff_hz``) of positions, gyro and accelerometer; samples within 1 s of
    lost tracking are excluded. Returns ``(r (3,) m, b (3,) m/s² accelerometer bias)``.
    """
    fs = trial.rate_hz
    s = np.arange(trial.n, dtype=np.float64) - lag_s * fs
    pos, quat, valid = _optical_at(trial, s)
    good = np.flatnonzero(valid)
    # Bridge gaps for the filters only; bridged samples and their surroundings are dropped.
    filled = np.stack([np.interp(s, s[good], pos[good, k]) for k in range(3)], axis=1)
    qf = np.stack([np.interp(s, s[good], quat[good, k]) for k in range(4)], axis=1)
    qf /= np.linalg.norm(qf, axis=1, keepdims=True)
    sos = butter(4, cutoff_hz / (fs / 2.0), output="sos")
    p = sosfiltfilt(sos, filled, axis=0)
    pdd = np.gradient(np.gradient(p, 1.0 / fs, axis=0), 1.0 / fs, axis=0)
    f = sosfiltfilt(sos, trial.acc, axis=0)
    w = sosfiltfilt(sos, trial.gyr, axis=0)
    wd = np.gradient(w, 1.0 / fs, axis=0)
    f_pred = quat_rotate(quat_conj(qf), pdd + np.array([0.0, 0.0, GRAVITY_M_S2]))
    margin = round(fs)
    near_gap = np.convolve(~valid, np.ones(2 * margin + 1), mode="same") > 0
    use = ~near_gap
    use[:margin] = False
    use[-margin:] = False
    m = _skew(wd[use]) + _skew(w[use]) @ _skew(w[use])  # (M,3,3): r ↦ ω̇×r + ω×(ω×r)
    a = np.concatenate([m, np.broadcast_to(np.eye(3), m.shape)], axis=2).reshape(-1, 6)
    y = (f[use] - f_pred[use]).reshape(-1)
    sol, *_ = np.linalg.lstsq(a, y, rcond=None)
    return sol[:3], sol[3:]


def _skew(v: FloatArray) -> FloatArray:
    z = np.zeros(v.shape[0])
    return np.stack(
        [
            np.stack([z, -v[:, 2], v[:, 1]], axis=1),
            np.stack([v[:, 2], z, -v[:, 0]], axis=1),
            np.stack([-v[:, 1], v[:, 0], z], axis=1),
        ],
        axis=1,
    )


# --------------------------------------------------------------------------- conversion


@dataclass(frozen=True)
class Truth:
    """Ground truth on the IMU clock (t = i / rate, seconds).

    ``t`` (N,), ``q_ref`` (N,4) wxyz IMU→robot frame with NaN rows where optical
    tracking is lost, ``movement`` (N,) bool; ``robot_t`` (M,) s and ``elbow`` (M,3) m the
    virtual elbow actually sent (robot frame); ``lag_s`` the optical→IMU shift applied;
    ``acc_offset_m`` (3,) the accelerometer offset used for the lever; ``robot_yaw_deg``
    the turn from the optical world frame to the robot frame.
    """

    t: FloatArray
    q_ref: FloatArray
    movement: BoolArray
    robot_t: FloatArray
    elbow: FloatArray
    lag_s: float
    acc_offset_m: FloatArray
    robot_yaw_deg: float


@dataclass(frozen=True)
class Converted:
    """A contract recording (``(key, payload)`` in arrival order) and its ground truth."""

    messages: Recording
    truth: Truth


def convert(
    trial: Trial,
    *,
    device: str = "broad",
    robot_rate_hz: float = 25.0,
    imu_batch: int = 8,
    imu_to_elbow_m: float = 0.15,
    cuff_to_elbow_m: float = 0.06,
    wrist_to_elbow_m: float = 0.25,
    forearm_dir: ArrayLike = (0.0, 1.0, 0.0),
    lag_s: float | None = None,
    acc_offset_m: ArrayLike = ACC_OFFSET_M,
    robot_yaw_deg: float = 120.0,
) -> Converted:
    """Turn a trial into a recording where a virtual elbow plays the robot.

    - IMU ``rehab/<device>/imu/upperarm``: every sample at the native rate, ``imu_batch``
      samples per message, ``t = i / rate``, ``seq`` 0, 1, ….
    - Robot ``rehab/<device>/robot``: one sample per message at ``robot_rate_hz`` on the
      same clock; the optical pose is read ``lag_s`` earlier (default: :func:`estimate_lag`)
      so both streams show the same instant. ``elbow = p + R(q)·(acc_offset_m + [d, 0, 0])``
      (d = ``imu_to_elbow_m``, so the elbow is d from the *accelerometer* along x);
      ``proximal = elbow + cuff_to_elbow_m·u``, ``wrist = elbow + wrist_to_elbow_m·u`` with
      u the fixed unit ``forearm_dir``, so eq. 13 of the seed paper returns the elbow.
      Where optical tracking is lost no robot message is sent (a gap, as from a robot).
    - The robot frame is the optical world frame turned by ``robot_yaw_deg`` about z
      (positions and ``q_ref`` alike). BROAD trials start with the IMU roughly aligned to
      the optical frame, so without this turn a filter's initial heading would already be
      nearly right and a heading estimator could look converged without doing anything.

    Messages are ordered by the time of their last sample (arrival order).
    """
    if wrist_to_elbow_m <= cuff_to_elbow_m:
        raise ValueError("the wrist cuff must be farther from the elbow than the proximal cuff")
    fs = trial.rate_hz
    lag = estimate_lag(trial) if lag_s is None else float(lag_s)
    offset = np.asarray(acc_offset_m, dtype=np.float64).reshape(3)
    u = np.asarray(forearm_dir, dtype=np.float64).reshape(3)
    u = u / np.linalg.norm(u)

    yaw = quat_z(np.radians(robot_yaw_deg))
    t_imu = np.arange(trial.n) / fs
    _, q_ref, _ = _optical_at(trial, np.arange(trial.n, dtype=np.float64) - lag * fs)
    q_ref = quat_mul(yaw, q_ref)

    t_rob = np.arange(0.0, t_imu[-1] + 1e-9, 1.0 / robot_rate_hz)
    pos, quat, valid = _optical_at(trial, t_rob * fs - lag * fs)
    t_rob, pos, quat = t_rob[valid], pos[valid], quat[valid]
    lever = np.broadcast_to(offset + np.array([imu_to_elbow_m, 0.0, 0.0]), pos.shape)
    elbow = quat_rotate(np.broadcast_to(yaw, quat.shape), pos + quat_rotate(quat, lever))
    proximal = elbow + cuff_to_elbow_m * u
    wrist = elbow + wrist_to_elbow_m * u

    timed: list[tuple[float, int, tuple[str, dict[str, Any]]]] = []
    for seq, i0 in enumerate(range(0, trial.n, imu_batch)):
        sl = slice(i0, min(i0 + imu_batch, trial.n))
        msg = wire.ImuMessage(device, "upperarm", t_imu[sl], trial.gyr[sl], trial.acc[sl], seq=seq)
        timed.append((float(t_imu[sl][-1]), 0, wire.encode(msg)))
    for seq in range(t_rob.shape[0]):
        sl = slice(seq, seq + 1)
        rmsg = wire.RobotMessage(device, t_rob[sl], wrist[sl], proximal[sl], elbow[sl], seq=seq)
        timed.append((float(t_rob[seq]), 1, wire.encode(rmsg)))
    timed.sort(key=lambda e: (e[0], e[1]))  # stable: IMU before robot at equal times

    truth = Truth(
        t=t_imu,
        q_ref=q_ref,
        movement=trial.movement.copy(),
        robot_t=t_rob,
        elbow=elbow,
        lag_s=lag,
        acc_offset_m=offset,
        robot_yaw_deg=float(robot_yaw_deg),
    )
    return Converted([m for _, _, m in timed], truth)


# --------------------------------------------------------------------------- scoring


def orientation_errors(
    q_est: FloatArray, q_ref: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per-sample (total, heading, inclination) errors in degrees, BROAD definitions.

    ``q_est``, ``q_ref``: (N,4) wxyz sensor→world. ``q_err = q_est ⊗ q_ref⁻¹`` (world
    frame, so a heading offset is a rotation about world z): total ``2·acos(|w|)``,
    heading ``2·atan(|z/w|)``, inclination ``2·acos(√(w²+z²))``. Rows where either input
    has a NaN give NaN in all three outputs.
    """
    qe = quat_mul(_unit(q_est), quat_conj(_unit(q_ref)))
    w, z = np.abs(qe[:, 0]), np.abs(qe[:, 3])
    total = np.degrees(2.0 * np.arccos(np.clip(w, 0.0, 1.0)))
    heading = np.degrees(2.0 * np.arctan2(z, w))  # atan2 keeps w = 0 finite (180°)
    incl = np.degrees(2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0)))
    return total, heading, incl


def _unit(q: FloatArray) -> FloatArray:
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    out: FloatArray = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out


def align_heading(
    q_est: FloatArray, q_ref: FloatArray, mask: BoolArray | None = None
) -> tuple[FloatArray, float]:
    """Best constant heading alignment: ``(Rz(−δ) ⊗ q_est, δ rad)``.

    δ maximises Σ w'² of the aligned error quaternions over ``mask`` (and finite rows),
    i.e. the chordal least-squares heading offset, in closed form.
    """
    qe = quat_mul(_unit(q_est), quat_conj(_unit(q_ref)))
    use = np.isfinite(qe).all(axis=1)
    if mask is not None:
        use &= mask
    if not use.any():
        return q_est.copy(), float("nan")
    w, z = qe[use, 0], qe[use, 3]
    # w' = c·w + s·z with (c, s) = (cos δ/2, sin δ/2): principal axis of the 2×2 moment.
    half = 0.5 * np.arctan2(2.0 * np.sum(w * z), np.sum(w * w) - np.sum(z * z))
    delta = float(2.0 * half)
    return quat_mul(quat_z(-delta), q_est), delta


def _stats(x: FloatArray) -> tuple[float | None, float | None]:
    if x.size == 0:
        return None, None
    return float(np.median(x)), float(np.percentile(x, 95))


def score_trial(
    t_est: FloatArray,
    q_est: FloatArray,
    converged: BoolArray,
    truth: Truth,
    confidence: FloatArray | None = None,
) -> dict[str, Any]:
    """Score an estimate stream (e.g. one row per robot sample) against the ground truth.

    ``t_est`` (M,) s on the recording clock, ``q_est`` (M,4) wxyz A→R (NaN allowed),
    ``converged`` (M,) bool, optional ``confidence`` (M,). The reference is interpolated
    at ``t_est``; ``movement`` is taken from the nearest IMU sample. Statistics use the
    samples with ``t ≥`` the first converged time, movement, and finite estimate and
    reference. Returns degrees / seconds; ``None`` where undefined (never converged).
    """
    t_est = np.asarray(t_est, dtype=np.float64)
    converged = np.asarray(converged, dtype=bool)
    q_ref = interp_quat(truth.t, truth.q_ref, t_est)
    k = np.clip(np.searchsorted(truth.t, t_est), 0, truth.t.shape[0] - 1)
    k_prev = np.clip(k - 1, 0, truth.t.shape[0] - 1)
    nearest = np.where(np.abs(truth.t[k_prev] - t_est) < np.abs(truth.t[k] - t_est), k_prev, k)
    moving = truth.movement[nearest]
    total, heading, incl = orientation_errors(q_est, q_ref)
    first = np.flatnonzero(converged)
    t_conv = float(t_est[first[0]]) if first.size else None
    use = moving & np.isfinite(total)
    use &= t_est >= (t_conv if t_conv is not None else np.inf)
    out: dict[str, Any] = {
        "t_converged_s": t_conv,
        "n_scored": int(use.sum()),
        "n_after_converged_nan": int(
            (np.isnan(q_est).any(axis=1) & (t_est >= (t_conv or np.inf))).sum()
        ),
    }
    for name, err in (("total", total), ("heading", heading), ("inclination", incl)):
        med, p95 = _stats(err[use])
        out[f"{name}_median_deg"] = med
        out[f"{name}_p95_deg"] = p95
    if confidence is not None:
        c = np.asarray(confidence, dtype=np.float64)
        c_use = c[use & np.isfinite(c)]
        out["confidence_median"] = float(np.median(c_use)) if c_use.size else None
        out["confidence_final"] = float(c[-1]) if c.size and np.isfinite(c[-1]) else None
    return out


# --------------------------------------------------------------------------- 6D baseline


@dataclass(frozen=True)
class Baseline:
    """VQF 6D (gyro + acc, no magnetometer) on the raw IMU stream.

    ``q6d`` (N,4) wxyz sensor→filter frame (arbitrary heading); statistics in degrees over
    ``movement`` samples after ``skip_s``; ``heading_offset_deg`` the constant alignment δ
    used for the ``total_aligned_*`` figures (an oracle, for reference only).
    """

    q6d: FloatArray
    inclination_median_deg: float
    inclination_p95_deg: float
    total_aligned_median_deg: float
    total_aligned_p95_deg: float
    heading_offset_deg: float


def vqf_6d(gyr: FloatArray, acc: FloatArray, rate_hz: float) -> FloatArray:
    """Causal VQF 6D orientation, (N,4) wxyz, from (N,3) rad/s and (N,3) m/s² at ``rate_hz``."""
    from vqf import VQF  # local: the scoring helpers must not need the compiled filter

    f = VQF(1.0 / rate_hz)
    out = f.updateBatch(
        np.ascontiguousarray(gyr, np.float64), np.ascontiguousarray(acc, np.float64)
    )
    q: FloatArray = np.asarray(out["quat6D"], dtype=np.float64)
    return q


def vqf_baseline(trial: Trial, truth: Truth, skip_s: float = 5.0) -> Baseline:
    """The "6D filter alone" figures: VQF inclination error and, after the best constant
    heading, its total error, median and 95th percentile over movement samples after
    ``skip_s`` (the filter's initial convergence)."""
    q = vqf_6d(trial.gyr, trial.acc, trial.rate_hz)
    mask = truth.movement & (truth.t >= skip_s)
    _, _, incl = orientation_errors(q, truth.q_ref)
    aligned, delta = align_heading(q, truth.q_ref, mask)
    total, _, _ = orientation_errors(aligned, truth.q_ref)
    use = mask & np.isfinite(incl)
    return Baseline(
        q6d=q,
        inclination_median_deg=float(np.median(incl[use])),
        inclination_p95_deg=float(np.percentile(incl[use], 95)),
        total_aligned_median_deg=float(np.median(total[use])),
        total_aligned_p95_deg=float(np.percentile(total[use], 95)),
        heading_offset_deg=float(np.degrees(delta)),
    )
