"""Joint-angle trajectories for the wearable simulator (contract §8 angles, radians).

Every movement starts with ``rest_s`` at rest in the zero pose (contract §8 "Start") and is
smooth (piecewise minimum-jerk between key poses, C² at the joins) so that the numerical
differentiation of :mod:`simulator.wearable_arm` is exact to ~1e-6.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from simulator.wearable_arm import F64

ThetaFn = Callable[[F64], F64]
MOVES = ("flexion_sine", "shoulder_wheel", "reaching", "rom")


def _minjerk(s: F64) -> F64:
    s = np.clip(s, 0.0, 1.0)
    return np.asarray(s**3 * (10.0 - 15.0 * s + 6.0 * s * s), dtype=np.float64)


def keyframes(times: list[float], poses_deg: list[list[float]]) -> ThetaFn:
    """Minimum-jerk moves between key poses (deg) reached at ``times`` (s), held after."""
    tk = np.asarray(times, dtype=np.float64)
    pk = np.radians(np.asarray(poses_deg, dtype=np.float64))

    def fn(t: F64) -> F64:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.repeat(pk[:1], len(t), axis=0)
        for i in range(1, len(tk)):
            s = (t - tk[i - 1]) / (tk[i] - tk[i - 1])
            out = out + _minjerk(s)[:, None] * (pk[i] - pk[i - 1])
        return out

    return fn


def flexion_sine(
    amp_deg: float = 90.0, freq_hz: float = 1.0, rest_s: float = 0.0, centre_deg: float = 0.0
) -> ThetaFn:
    """Paper §3: ``θ0 = c + A·sin(2π f t)``, the other joints at zero. With ``rest_s`` > 0 the
    arm rests until then and the centre ``c`` and the amplitude ramp in smoothly over one
    period (no kink)."""

    def fn(t: F64) -> F64:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.zeros((len(t), 5))
        s = t - rest_s
        ramp = _minjerk(s * freq_hz) if rest_s > 0 else np.ones_like(t)
        wave = np.radians(centre_deg) + np.radians(amp_deg) * np.sin(2 * np.pi * freq_hz * s)
        out[:, 0] = ramp * wave
        return out

    return fn


@dataclass(frozen=True)
class Wheel:
    """The shoulder wheel of the paper's §4 (table 7), in S's sagittal plane.

    The handle turns at ``radius_m`` about a centre ``forward_m`` in front of and ``down_m``
    below the shoulder; the hand adds ``hand_m`` (table 7's s) to the forearm (l6), so the
    elbow-to-handle distance is ``s + l6``. Abduction and rotation are zero and the forearm is
    pronated 90° (eq. 22).
    """

    radius_m: float = 0.15  # r
    forward_m: float = 0.25  # w
    down_m: float = 0.05  # h
    hand_m: float = 0.04  # s
    upper_m: float = 0.22  # l3
    fore_m: float = 0.20  # l6

    def angles(self, phi: F64) -> tuple[F64, F64]:
        """Shoulder and elbow flexion (rad) for handle angles ``phi`` (eqs. 20, 21 in contract
        angles: two-link inverse kinematics with the elbow below the shoulder–handle line)."""
        x = self.forward_m + self.radius_m * np.cos(phi)
        z = -self.down_m + self.radius_m * np.sin(phi)
        l1, l2 = self.upper_m, self.hand_m + self.fore_m
        c4 = (x * x + z * z - l1 * l1 - l2 * l2) / (2 * l1 * l2)
        th4 = np.arccos(np.clip(c4, -1.0, 1.0))
        th0 = np.arctan2(x, -z) - np.arctan2(l2 * np.sin(th4), l1 + l2 * np.cos(th4))
        return np.asarray(th0, dtype=np.float64), np.asarray(th4, dtype=np.float64)


def shoulder_wheel(
    wheel: Wheel, period_s: float = 4.0, rest_s: float = 2.5, approach_s: float = 2.0
) -> ThetaFn:
    """At rest, a minimum-jerk approach to the handle, then the wheel turning at a steady
    ``period_s`` after a one-period speed ramp."""
    start = np.array([*wheel.angles(np.array([0.0]))])[:, 0]
    target = [float(np.degrees(start[0])), 0.0, 0.0, float(np.degrees(start[1])), 90.0]
    approach = keyframes([rest_s, rest_s + approach_s], [[0.0] * 5, list(target)])
    t_turn = rest_s + approach_s
    omega = 2 * np.pi / period_s

    def fn(t: F64) -> F64:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = approach(t)
        s = np.clip(t - t_turn, 0.0, None)
        # φ = ω (s − T/2 ·(1 − e^{…})) would do too; a smooth cubic ramp of speed over T:
        ramp = np.where(
            s < period_s, s**3 / period_s**2 - 0.5 * s**4 / period_s**3, s - 0.5 * period_s
        )
        phi = omega * ramp
        th0, th4 = wheel.angles(phi)
        turning = t > t_turn
        out[turning, 0] = th0[turning]
        out[turning, 3] = th4[turning]
        return out

    return fn


def reaching(duration_s: float, rest_s: float = 2.5, period_s: float = 3.0) -> ThetaFn:
    """Forward reaches to a table-top target and back, with some abduction and rotation."""
    home = [15.0, 10.0, 20.0, 90.0, 60.0]
    reach = [70.0, 20.0, -5.0, 15.0, 30.0]
    times = [rest_s, rest_s + 1.5]
    poses = [[0.0] * 5, home]
    t = times[-1]
    k = 0
    while t < duration_s:
        t += period_s / 2
        times.append(t)
        poses.append(reach if k % 2 == 0 else home)
        k += 1
    return keyframes(times, poses)


def rom(rest_s: float = 2.5, step_s: float = 2.0) -> ThetaFn:
    """Range-of-motion test movements, one joint at a time (deg): flexion to 150, abduction to
    80, rotation ±60 with the elbow at 90, elbow flexion to 140, pronation −70..80."""
    seq = [
        [0, 0, 0, 0, 0],
        [150, 0, 0, 0, 0],
        [0, 0, 0, 0, 0],
        [0, 80, 0, 0, 0],
        [0, 0, 0, 0, 0],
        [0, 0, 0, 90, 0],
        [0, 0, 60, 90, 0],
        [0, 0, -60, 90, 0],
        [0, 0, 0, 90, 0],
        [0, 0, 0, 140, 0],
        [0, 0, 0, 90, 0],
        [0, 0, 0, 90, 80],
        [0, 0, 0, 90, -70],
        [0, 0, 0, 90, 0],
        [0, 0, 0, 0, 0],
    ]
    times = [rest_s + step_s * i for i in range(len(seq))]
    return keyframes(times, [[float(v) for v in p] for p in seq])


def rom_duration(rest_s: float = 2.5, step_s: float = 2.0) -> float:
    return rest_s + step_s * 14 + 2.0
