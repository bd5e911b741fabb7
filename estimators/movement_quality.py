"""Movement quality of a reach from the end effector's path (the robot's wrist cuff).

Per movement (a cycle of a repetitive task), from positions ``p`` (N, 3) in metres at times
``t`` (N,) in seconds:

- movement time (s) and hand-path length (m, the sum of the sample-to-sample distances);
- straightness ratio: hand-path length over the straight-line distance (Bhat & Galloway 2006,
  as used in the special issue's reach kinematics). A cycle of a repetitive task returns to its
  start, so :func:`measure` splits it at the point farthest from its start into an outbound and
  a return movement and divides the whole path by the two straight lines (1 for a straight
  back-and-forth reach; π/2 for a circle);
- mean speed (path length / movement time) and peak speed (m/s);
- number of movement units: peaks of the speed profile whose prominence is at least
  ``unit_prominence`` of the cycle's peak speed and ``unit_min_prominence_m_s`` (the project's
  parameters: von Hofsten 1991's movement units, with a noise floor);
- SPARC, the spectral arc length (Balasubramanian, Melendez-Calderon, Roby-Brami & Burdet
  2015, J NeuroEng Rehabil 12:112, eq. 3–4), with the published parameters: cut-off
  ``ω_c^max`` = 10 Hz, amplitude threshold ``V̄`` = 0.05, zero padding to 2^(⌈log2 N⌉ + 4)
  points; the spectrum is normalised by its value at 0 Hz and the frequency axis by the
  adaptive cut-off band;
- LDLJ, the log dimensionless jerk of the speed profile (same paper, eq. 2; Hogan & Sternad
  2009): ``−ln((t2 − t1)^3 / v_peak^2 · ∫ (d²v/dt²)^2 dt)``.

Both smoothness measures are dimensionless: unchanged by the movement's amplitude and
duration, lower (more negative) for less smooth movements. Samples need not be uniform in
time: the path is resampled linearly onto a uniform grid (``resample_hz``, default the median
rate rounded to 0.01 Hz) before the speed is taken; a zero-lag Butterworth low-pass on the
positions (``lowpass_hz``; None for the raw path) keeps sensor noise out of the derivatives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators import filters, peaks

Array: TypeAlias = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class QualityParams:
    """Parameters (Hz, m/s, fractions). SPARC's three are Balasubramanian et al. 2015's."""

    sparc_fc_hz: float = 10.0
    sparc_amp_threshold: float = 0.05
    sparc_pad_level: int = 4
    lowpass_hz: float | None = 6.0
    lowpass_order: int = 2
    resample_hz: float | None = None
    unit_prominence: float = 0.1
    unit_min_prominence_m_s: float = 0.01
    min_samples: int = 8


DEFAULT_PARAMS = QualityParams()

QUALITY_FIELDS = (
    "movement_time_s",
    "path_length_m",
    "straightness_ratio",
    "mean_speed_m_s",
    "peak_speed_m_s",
    "movement_units",
    "sparc",
    "ldlj",
)


def sparc(
    speed: Array, fs: float, fc: float = 10.0, amp_th: float = 0.05, pad_level: int = 4
) -> float:
    """Spectral arc length of a speed profile (Balasubramanian et al. 2015, eq. 3–4).

    ``speed`` (N,) uniformly sampled at ``fs`` Hz. The magnitude spectrum, zero-padded to
    ``2^(⌈log2 N⌉ + pad_level)`` points and normalised by its maximum (its 0 Hz value for a
    non-negative profile), is cut at the last frequency below ``fc`` where it is still at
    least ``amp_th``; SPARC is minus the arc length of that curve over the frequency band
    normalised to [0, 1]. NaN for a profile without motion.
    """
    v = np.asarray(speed, dtype=np.float64)
    if len(v) < 2 or not np.all(np.isfinite(v)) or not np.any(v > 0):
        return math.nan
    nfft = int(2 ** (math.ceil(math.log2(len(v))) + pad_level))
    f = np.arange(nfft) * (fs / nfft)
    mag = np.abs(np.fft.fft(v, nfft))
    mag = mag / mag.max()
    sel = f <= fc
    f_sel, m_sel = f[sel], mag[sel]
    above = np.flatnonzero(m_sel >= amp_th)
    f_sel = f_sel[above[0] : above[-1] + 1]
    m_sel = m_sel[above[0] : above[-1] + 1]
    if len(f_sel) < 2:
        return math.nan
    df = np.diff(f_sel) / (f_sel[-1] - f_sel[0])
    return -float(np.sum(np.sqrt(df**2 + np.diff(m_sel) ** 2)))


def ldlj(speed: Array, fs: float) -> float:
    """Log dimensionless jerk of a speed profile (Balasubramanian et al. 2015, eq. 2).

    ``−ln(T^3 / v_peak^2 · ∫ (d²v/dt²)^2 dt)``, ``T`` the duration of the N samples at ``fs`` Hz,
    the integral by the rectangle rule over second differences. NaN without motion.
    """
    v = np.asarray(speed, dtype=np.float64)
    if len(v) < 3 or not np.all(np.isfinite(v)):
        return math.nan
    peak = float(np.max(np.abs(v)))
    if peak <= 0:
        return math.nan
    dt = 1.0 / fs
    duration = len(v) * dt
    jerk = np.diff(v, 2) / dt**2
    integral = float(np.sum(jerk**2)) * dt
    if integral <= 0:
        return math.nan
    return -math.log(duration**3 / peak**2 * integral)


def path_length(p: Array) -> float:
    """Hand-path length (m): the sum of the distances between successive positions (N, 3)."""
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(p) > 1 else 0.0


def straightness_ratio(p: Array) -> float:
    """Hand-path length over the straight line from first to last position (≥ 1; NaN if they
    coincide)."""
    d = float(np.linalg.norm(p[-1] - p[0])) if len(p) else 0.0
    return path_length(p) / d if d > 0 else math.nan


def cycle_straightness(p: Array) -> float:
    """A cycle's straightness: the path over the two straight lines start → farthest point →
    end (an outbound and a return movement). NaN if the cycle does not move."""
    if len(p) < 2:
        return math.nan
    k = int(np.argmax(np.linalg.norm(p - p[0], axis=1)))
    straight = float(np.linalg.norm(p[k] - p[0]) + np.linalg.norm(p[-1] - p[k]))
    return path_length(p) / straight if straight > 0 else math.nan


def movement_units(speed: Array, prominence: float = 0.1, min_prominence: float = 0.01) -> int:
    """Speed peaks (movement units) with prominence ≥ ``max(prominence · v_peak,
    min_prominence)`` (m/s). A profile that rises to its peak at either end counts the end."""
    v = np.asarray(speed, dtype=np.float64)
    if len(v) < 3 or not np.any(v > 0):
        return 0
    floor = max(prominence * float(np.max(v)), min_prominence)
    # zero-padded at both ends so a movement cut mid-peak by the cycle's boundary counts
    return len(peaks.find_peaks(np.concatenate(([0.0], v, [0.0])), floor))


def filtfilt(x: Array, order: int, cutoff_hz: float, fs: float) -> Array:
    """Zero-lag Butterworth low-pass of ``x`` (N, k) along axis 0: scipy's ``sosfiltfilt``
    with its default odd extension, the pad shortened for a cycle shorter than it
    (:func:`.filters.filtfilt`)."""
    sos = filters.butter_sos(order, cutoff_hz, fs)
    pad = min(3 * (2 * len(sos) + 1), len(x) - 1)
    if pad <= 0:
        return x
    return filters.filtfilt(sos, x, pad)


def uniform_path(
    t: Array, p: Array, params: QualityParams = QualityParams()
) -> tuple[Array, float]:
    """``p`` (N, 3) at times ``t`` (N,) resampled linearly onto a uniform grid and low-passed
    (zero lag); returns ``(positions (M, 3), fs Hz)``."""
    t = np.asarray(t, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    # the median rate to 0.01 Hz: the grid (and its filter design) repeats from cycle to cycle
    fs = params.resample_hz or round(1.0 / float(np.median(np.diff(t))), 2)
    n = max(int(math.floor((t[-1] - t[0]) * fs + 1e-9)) + 1, 2)
    tu = t[0] + np.arange(n) / fs
    pu = np.stack([np.interp(tu, t, p[:, j]) for j in range(p.shape[1])], axis=1)
    if params.lowpass_hz is not None and params.lowpass_hz < fs / 2:
        pu = filtfilt(pu, params.lowpass_order, params.lowpass_hz, fs)
    return pu, fs


def measure(t: Array, p: Array, params: QualityParams = QualityParams()) -> dict[str, float]:
    """The movement-quality measures (:data:`QUALITY_FIELDS`) of one cycle's path.

    ``t`` (N,) s strictly increasing, ``p`` (N, 3) m. Rows with a non-finite position are
    dropped; with fewer than ``params.min_samples`` left every measure is NaN (``movement_units``
    too, as a float)."""
    t = np.asarray(t, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64).reshape(len(t), -1)
    ok = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    t, p = t[ok], p[ok]
    out = dict.fromkeys(QUALITY_FIELDS, math.nan)
    if len(t) < params.min_samples or t[-1] <= t[0]:
        return out
    duration = float(t[-1] - t[0])
    length = path_length(p)
    pu, fs = uniform_path(t, p, params)
    speed = np.linalg.norm(np.gradient(pu, 1.0 / fs, axis=0), axis=1)
    out["movement_time_s"] = duration
    out["path_length_m"] = length
    out["straightness_ratio"] = cycle_straightness(p)
    out["mean_speed_m_s"] = length / duration
    out["peak_speed_m_s"] = float(np.max(speed))
    out["movement_units"] = float(
        movement_units(speed, params.unit_prominence, params.unit_min_prominence_m_s)
    )
    out["sparc"] = sparc(
        speed, fs, params.sparc_fc_hz, params.sparc_amp_threshold, params.sparc_pad_level
    )
    out["ldlj"] = ldlj(speed, fs)
    return out
