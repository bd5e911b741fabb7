"""End-effector robot: two cuffs on the forearm axis, with rope oscillation, noise and latency.

The proximal cuff sits ``cuff_to_elbow_m`` from the elbow toward the wrist and the wrist cuff
``wrist_cuff_m`` proximal of the wrist, so the contract's eq. 13 recovers the elbow exactly
from error-free cuffs. A sample stamped ``t`` shows the pose at ``t − latency``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

from simulator.arm import ArmModel
from simulator.subject import Subject

F64: TypeAlias = NDArray[np.float64]

ROPE_CUTOFF = 6.0  # an oscillation is dropped after this many decay time constants
PROXIMAL_ROPE = (0.4, 0.8)  # proximal cuff's amplitude relative to the wrist cuff's


@dataclass(frozen=True)
class RobotSamples:
    """Robot stream in session time: stamps (K,), cuffs (K,3) in R, metres."""

    tau: F64  # stamps
    wrist: F64  # measured wrist cuff
    proximal: F64  # measured proximal cuff
    true_elbow: F64  # elbow at the pose time (stamp − latency), for tests


def _rope(tau: F64, onsets: F64, dirs: F64, amps: F64, subject: Subject) -> F64:
    """Sum of damped sinusoids (K,3) started at ``onsets`` (E,), unit ``dirs`` (E,3), ``amps`` (E,).

    ``amps`` are the first peaks. Corners are ~1 s apart and an oscillation lasts < 1 s, so
    the last two onsets suffice.
    """
    out = np.zeros((tau.shape[0], 3))
    if onsets.size == 0 or subject.rope_amp_m == 0.0:
        return out
    w, decay = 2 * np.pi * subject.rope_hz, subject.rope_decay_s
    first_peak = np.arctan(w * decay) / w
    gain = 1.0 / (np.exp(-first_peak / decay) * np.sin(w * first_peak))
    last = np.searchsorted(onsets, tau, side="right") - 1
    for back in (0, 1):
        idx = last - back
        valid = idx >= 0
        dt = tau[valid] - onsets[idx[valid]]
        live = dt < ROPE_CUTOFF * subject.rope_decay_s
        env = np.where(live, np.exp(-dt / subject.rope_decay_s), 0.0)
        wave = gain * env * np.sin(w * dt) * amps[idx[valid]]
        out[valid] += wave[:, None] * dirs[idx[valid]]
    return out


def robot_samples(
    arm: ArmModel,
    subject: Subject,
    rng: np.random.Generator,
    *,
    rate_hz: float,
    time_offset_s: float,
    duration_s: float,
    cuff_to_elbow_m: float,
    wrist_cuff_m: float,
    noise_m: float,
    corner_tau: F64,
    corner_dir: F64,
) -> RobotSamples:
    """Measured cuffs at stamps ``offset + k / rate`` within the session.

    ``corner_tau`` (E,) are the times the wrist passes a rectangle corner and ``corner_dir``
    (E,3) the horizontal direction it came from: a slack rope overshoots along it.
    """
    n = int(np.floor((duration_s - time_offset_s) * rate_hz + 1e-9)) + 1
    tau = time_offset_s + np.arange(n) / rate_hz
    pose = arm.pose(tau - subject.latency_s)
    axis = pose.wrist - pose.elbow
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    proximal = pose.elbow + cuff_to_elbow_m * axis
    wrist = pose.wrist - wrist_cuff_m * axis

    # Random numbers are drawn whatever the switches, so the streams stay aligned.
    e = corner_tau.shape[0]
    amp = subject.rope_amp_m * np.asarray(rng.uniform(0.6, 1.4, e))
    prox_amp = amp * np.asarray(rng.uniform(*PROXIMAL_ROPE, e))
    wrist_dir = corner_dir + 0.4 * rng.standard_normal((e, 3))
    prox_dir = corner_dir + 0.4 * rng.standard_normal((e, 3))
    wrist_dir /= np.linalg.norm(wrist_dir, axis=1, keepdims=True)
    prox_dir /= np.linalg.norm(prox_dir, axis=1, keepdims=True)
    white = rng.standard_normal((2, n, 3)) * noise_m

    pose_tau = tau - subject.latency_s
    wrist = wrist + _rope(pose_tau, corner_tau, wrist_dir, amp, subject) + white[0]
    proximal = proximal + _rope(pose_tau, corner_tau, prox_dir, prox_amp, subject) + white[1]
    return RobotSamples(tau, wrist, proximal, pose.elbow)
