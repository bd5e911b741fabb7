"""Arm trajectories: wrist path, task phase, shoulder motion, swivel and inverse kinematics.

All functions take session time ``tau`` (s, 0 = session start; any shape (N,)) and are
smooth (C2 or better) everywhere, so derivatives can be taken by finite differences of the
exact functions (see :mod:`simulator.imu`). The subject is perfectly still before the end of
the initial rest: every motion term is multiplied by an activity envelope that is 0 there.

Task: the wrist traces a rounded rectangle on the table counter-clockwise seen from above,
starting each cycle at the front-right corner (far from the subject, lateral). The cycle
phase Φ(τ) grows by 1 per cycle; cycle ``j`` is Φ ∈ [j, j+1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import BSpline, make_interp_spline

from simulator.config import COMPENSATORY, TRANSITION
from simulator.subject import Subject

F64: TypeAlias = NDArray[np.float64]

ACTIVITY_RAMP_S = 2.0  # motion envelope rise after the rest
RATE_KNOT_S = 0.5  # knot spacing of the phase-rate spline
SWAY_KNOT_S = 1.0  # knot spacing of the random shoulder sway
SWIVEL_KNOT_S = 1.5  # knot spacing of the random swivel
EDGE_EASE = 0.8  # 0: constant speed along an edge; 1: stops at corners
CORNER_SMOOTH = 0.02  # Gaussian σ of the corner rounding, in cycle phase
LEAN_NEAR = 0.2  # lean at the near edge as a fraction of the far-edge lean
LEAN_TURN_DEG = 30.0  # lean direction turns with the wrist's lateral position
LEAN_DROP = 0.3  # the shoulder drops this much per metre of forward lean
COMPENSATORY_SLOWDOWN = 0.12  # compensatory cycles are this much longer
CYCLE_JITTER = 0.15  # per-cycle duration varies ±15 %


@dataclass(frozen=True)
class Pose:
    """Joint centres (N,3) in R, metres, and the upper-arm frame A as matrices (N,3,3)."""

    shoulder: F64
    elbow: F64
    wrist: F64
    rot: F64  # columns: x_A, y_A, z_A in R


def smoothstep(x: F64) -> F64:
    """Quintic 0→1 ramp on [0, 1], C2 at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return np.asarray(x**3 * (10.0 + x * (-15.0 + 6.0 * x)), dtype=np.float64)


def _uniform_bspline(start: float, step: float, coefs: F64) -> BSpline:
    """Cubic B-spline whose first basis function starts at ``start``; knots every ``step``."""
    n = coefs.shape[0]
    knots = start + step * np.arange(n + 4, dtype=np.float64)
    return BSpline(knots, coefs, 3, extrapolate=False)


def _unit(v: F64) -> F64:
    return np.asarray(v / np.linalg.norm(v, axis=-1, keepdims=True), dtype=np.float64)


class RectanglePath:
    """Rounded rectangle as a periodic C4 function of phase φ (cycles), relative to its centre.

    Corners CCW from above: front-right, front-left, back-left, back-right (front = +y, far
    from the subject). Along each edge the wrist eases (slower near corners); the corners are
    rounded by a Gaussian in phase, applied exactly in the Fourier domain.
    """

    N = 4096

    def __init__(self, size: tuple[float, float]) -> None:
        a, b = 0.5 * size[0], 0.5 * size[1]
        self.half = (a, b)
        corners = np.array([[a, b], [-a, b], [-a, -b], [a, -b]])
        lengths = np.array([2 * a, 2 * b, 2 * a, 2 * b])
        self.corner_phase = np.concatenate(([0.0], np.cumsum(lengths)[:-1])) / lengths.sum()
        ends = np.concatenate((self.corner_phase[1:], [1.0]))
        # Direction of travel arriving at each corner (the edge before it), unit (x, y).
        self.arrival_dir = np.roll(np.diff(np.vstack((corners, corners[:1])), axis=0), 1, axis=0)
        self.arrival_dir /= np.linalg.norm(self.arrival_dir, axis=1, keepdims=True)

        phi = np.arange(self.N) / self.N
        raw = np.empty((self.N, 2))
        for k in range(4):
            sel = (phi >= self.corner_phase[k]) & (phi < ends[k])
            u = (phi[sel] - self.corner_phase[k]) / (ends[k] - self.corner_phase[k])
            g = u - EDGE_EASE * np.sin(2 * np.pi * u) / (2 * np.pi)
            raw[sel] = corners[k] + (corners[(k + 1) % 4] - corners[k]) * g[:, None]
        freq = np.fft.rfftfreq(self.N, d=1.0 / self.N)
        kernel = np.exp(-2.0 * (np.pi * CORNER_SMOOTH * freq) ** 2)
        smooth = np.fft.irfft(np.fft.rfft(raw, axis=0) * kernel[:, None], n=self.N, axis=0)
        grid = np.append(phi, 1.0)
        values = np.vstack((smooth, smooth[:1]))
        self._spline = make_interp_spline(grid, values, k=5, bc_type="periodic")

    def __call__(self, phi: F64) -> F64:
        """(x, y) offsets (N,2), metres, at phases ``phi`` (any real; periodic)."""
        return np.asarray(self._spline(np.mod(phi, 1.0)), dtype=np.float64)


class ArmModel:
    """Deterministic trajectories of one session, built from a subject and a random stream."""

    def __init__(
        self,
        subject: Subject,
        spans: list[tuple[int, float, float]],
        duration_s: float,
        rng: np.random.Generator,
    ) -> None:
        self.subject = subject
        self.spans = spans
        self.duration_s = duration_s
        self.rest_end = spans[0][2]
        self.nominal_shoulder = np.array(subject.nominal_shoulder_m, dtype=np.float64)
        self.center = self.nominal_shoulder + np.array(subject.rect_center_m)
        self.path = RectanglePath(subject.rect_size_m)
        horizon = duration_s + 10.0

        # Phase rate: piecewise-constant 1/T_j per nominal cycle, smoothed by a cubic B-spline
        # whose coefficients are zero before the rest ends (so Φ is exactly 0 during the rest).
        t = self.rest_end
        starts, periods = [], []
        while t < horizon:
            level = float(self.comp_level(np.array([t]))[0])
            period = subject.cycle_s * (1 + COMPENSATORY_SLOWDOWN * level)
            period *= rng.uniform(1 - CYCLE_JITTER, 1 + CYCLE_JITTER)
            starts.append(t)
            periods.append(period)
            t += period
        n_lead = int(np.ceil(10.0 / RATE_KNOT_S))  # covers τ ≥ −10 s
        knot0 = self.rest_end - n_lead * RATE_KNOT_S
        n_coef = n_lead + int(np.ceil((horizon - self.rest_end) / RATE_KNOT_S)) + 4
        centers = knot0 + RATE_KNOT_S * (np.arange(n_coef) + 2.0)
        block = np.clip(np.searchsorted(np.array(starts), centers, side="right") - 1, 0, None)
        coefs = np.where(np.arange(n_coef) >= n_lead, 1.0 / np.array(periods)[block], 0.0)
        self._rate = _uniform_bspline(knot0, RATE_KNOT_S, coefs)
        self._phase = self._rate.antiderivative()
        self._tau_min = knot0 + 3 * RATE_KNOT_S
        self._tau_max = knot0 + n_coef * RATE_KNOT_S

        # Per-cycle lean amplitudes, smooth in Φ (one coefficient per cycle). With the drawn
        # ranges a proper shoulder stays within 1.4 × 0.04 + √2 × 0.025 < 0.092 m of nominal,
        # so proper cycles never leave the 0.10 m tolerance.
        n_cyc = len(starts) + 8
        self._proper_lean = _uniform_bspline(
            -4.0, 1.0, subject.proper_lean_m * rng.uniform(0.6, 1.4, n_cyc + 4)
        )
        self._comp_lean = _uniform_bspline(
            -4.0, 1.0, subject.compensatory_lean_m * rng.uniform(0.95, 1.05, n_cyc + 4)
        )

        # Random sway of the shoulder and of the swivel; B-spline values stay inside the
        # coefficients' range, so the bounds below are hard bounds.
        n_sway = int(np.ceil((horizon + 10.0) / SWAY_KNOT_S)) + 4
        sway = rng.uniform(-1.0, 1.0, (n_sway, 3)) * subject.sway_m * np.array([1.0, 1.0, 0.4])
        self._sway = _uniform_bspline(-10.0 - 3 * SWAY_KNOT_S, SWAY_KNOT_S, sway)
        n_sw = int(np.ceil((horizon + 10.0) / SWIVEL_KNOT_S)) + 4
        self._swivel_noise = _uniform_bspline(
            -10.0 - 3 * SWIVEL_KNOT_S, SWIVEL_KNOT_S, rng.uniform(-4.0, 4.0, n_sw)
        )

    # ------------------------------------------------------------------ time envelopes

    def _clip(self, tau: F64) -> F64:
        # Everything is constant before the motion starts, so clipping there is exact.
        tau = np.asarray(tau, dtype=np.float64)
        if np.any(tau > self._tau_max):
            raise ValueError("time beyond the simulated horizon")
        return np.maximum(tau, self._tau_min)

    def activity(self, tau: F64) -> F64:
        """Motion envelope: 0 during the rest, rising to 1 over ``ACTIVITY_RAMP_S``."""
        return smoothstep((np.asarray(tau) - self.rest_end) / ACTIVITY_RAMP_S)

    def comp_level(self, tau: F64) -> F64:
        """Compensation level 0 (proper) … 1 (compensatory); ramps smoothly in transitions."""
        tau = np.asarray(tau, dtype=np.float64)
        level = np.zeros_like(tau)
        base = [1.0 if p == COMPENSATORY else 0.0 for p, _, _ in self.spans]
        for i, (p, start, end) in enumerate(self.spans):
            sel = (tau >= start) & (tau < end)
            if i == len(self.spans) - 1:
                sel |= tau >= end
            if p == TRANSITION:
                before = base[i - 1] if i > 0 else 0.0
                after = base[i + 1] if i + 1 < len(self.spans) else before
                ramp = smoothstep((tau[sel] - start) / (end - start))
                level[sel] = before + (after - before) * ramp
            else:
                level[sel] = base[i]
        return level

    def phase(self, tau: F64) -> F64:
        """Cycle phase Φ (cycles), 0 until the rest ends."""
        return np.asarray(self._phase(self._clip(tau)), dtype=np.float64)

    def phase_rate(self, tau: F64) -> F64:
        """dΦ/dτ, cycles per second."""
        return np.asarray(self._rate(self._clip(tau)), dtype=np.float64)

    def times_at_phase(self, targets: F64) -> F64:
        """Session times where Φ reaches each target (> 0), by interpolation and Newton steps."""
        targets = np.asarray(targets, dtype=np.float64)
        grid = np.arange(self.rest_end, self._tau_max, 0.01)
        phi = self.phase(grid)
        keep = np.concatenate(([True], np.diff(phi) > 0))
        tau = np.interp(targets, phi[keep], grid[keep])
        for _ in range(4):
            tau = tau - (self.phase(tau) - targets) / np.maximum(self.phase_rate(tau), 1e-9)
        return np.asarray(tau, dtype=np.float64)

    # ------------------------------------------------------------------ trajectories

    def wrist(self, tau: F64, xy: F64 | None = None) -> F64:
        """Wrist joint centre (N,3) in R: on the table's rectangle, constant height.

        ``xy`` (N,2) is ``self.path(self.phase(tau))`` if the caller has it already.
        """
        if xy is None:
            xy = self.path(self.phase(tau))
        out = np.empty((xy.shape[0], 3))
        out[:, :2] = self.center[:2] + xy
        out[:, 2] = self.center[2]
        return out

    def _reach(self, xy: F64) -> tuple[F64, F64]:
        """Depth u ∈ [0,1] (0 near edge, 1 far edge) and lateral s ∈ [−1,1] of the wrist."""
        a, b = self.path.half
        return (xy[:, 1] + b) / (2 * b), xy[:, 0] / a

    def shoulder(self, tau: F64, phi: F64 | None = None, xy: F64 | None = None) -> F64:
        """Shoulder joint centre (N,3) in R.

        Lean toward the wrist grows with its reach (partially correlated sway); its far-edge
        amplitude blends from the proper to the compensatory value with the compensation
        level. A bounded random sway is added on top.
        """
        tau = self._clip(tau)
        if phi is None:
            phi = self.phase(tau)
        if xy is None:
            xy = self.path(phi)
        depth, lateral = self._reach(xy)
        c = self.comp_level(tau)
        amp = (1 - c) * self._proper_lean(phi) + c * self._comp_lean(phi)
        lean = amp * (LEAN_NEAR + (1 - LEAN_NEAR) * depth)
        beta = np.radians(LEAN_TURN_DEG) * lateral
        vec = np.stack((lean * np.sin(beta), lean * np.cos(beta), -LEAN_DROP * lean), axis=-1)
        sway = np.asarray(self._sway(tau), dtype=np.float64)
        return self.nominal_shoulder + self.activity(tau)[:, None] * (vec + sway)

    def swivel(self, tau: F64, xy: F64 | None = None) -> F64:
        """Swivel angle (rad) of the elbow about the shoulder–wrist line."""
        tau = self._clip(tau)
        if xy is None:
            xy = self.path(self.phase(tau))
        depth, lateral = self._reach(xy)
        c = self.comp_level(tau)
        deg = -8.0 * lateral + 6.0 * depth + 8.0 * c * depth + self._swivel_noise(tau)
        return np.asarray(np.radians(self.subject.swivel_deg + self.activity(tau) * deg))

    def pose(self, tau: F64) -> Pose:
        """Joint centres and the upper-arm frame at session times ``tau`` (N,)."""
        tau = self._clip(tau)
        phi = self.phase(tau)
        xy = self.path(phi)
        s = self.shoulder(tau, phi, xy)
        w = self.wrist(tau, xy)
        e = elbow_ik(s, w, self.swivel(tau, xy), self.subject.upper_arm_m, self.subject.forearm_m)
        return Pose(s, e, w, segment_frame(s, e, w))


def elbow_ik(shoulder: F64, wrist: F64, swivel: F64, upper: float, fore: float) -> F64:
    """Elbow (N,3) from shoulder, wrist, swivel (rad) and segment lengths (m).

    The elbow lies on a circle about the shoulder→wrist line n; swivel 0 puts it lowest
    (toward −z), positive swivel turns it toward ``down × n`` (lateral for a right arm
    reaching forward).
    """
    v = wrist - shoulder
    dist = np.linalg.norm(v, axis=-1)
    if np.any(dist >= upper + fore) or np.any(dist <= abs(upper - fore)):
        raise ValueError("wrist out of reach: the task does not fit this arm")
    n = v / dist[:, None]
    along = (upper**2 - fore**2 + dist**2) / (2 * dist)
    radius = np.sqrt(upper**2 - along**2)
    down = np.array([0.0, 0.0, -1.0])
    u = _unit(down - (n @ down)[:, None] * n)
    lat = np.cross(u, n)
    return np.asarray(
        shoulder
        + along[:, None] * n
        + radius[:, None] * (np.cos(swivel)[:, None] * u + np.sin(swivel)[:, None] * lat),
        dtype=np.float64,
    )


def segment_frame(shoulder: F64, elbow: F64, wrist: F64) -> F64:
    """Upper-arm frame A as matrices (N,3,3): x shoulder→elbow, z = x × forearm, y = z × x."""
    x = _unit(elbow - shoulder)
    z = _unit(np.cross(x, wrist - elbow))
    y = np.cross(z, x)
    return np.stack((x, y, z), axis=-1)


def elbow_angle_deg(shoulder: F64, elbow: F64, wrist: F64) -> F64:
    """Angle between shoulder→elbow and elbow→wrist, degrees (0 = extended)."""
    a = _unit(elbow - shoulder)
    b = _unit(wrist - elbow)
    cos = np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)
    return np.asarray(np.degrees(np.arccos(cos)))


__all__ = [
    "ArmModel",
    "Pose",
    "RectanglePath",
    "elbow_angle_deg",
    "elbow_ik",
    "segment_frame",
    "smoothstep",
]
