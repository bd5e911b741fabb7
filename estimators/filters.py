"""Causal Butterworth low-pass filters with explicit state (scipy ``sosfilt`` ``zi``)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray
from scipy import signal

Array: TypeAlias = NDArray[np.float64]


@lru_cache(maxsize=64)
def butter_sos(order: int, cutoff_hz: float, fs_hz: float, btype: str = "lowpass") -> Array:
    """Second-order sections of a digital Butterworth filter (paper §3.2.1)."""
    sos = signal.butter(order, cutoff_hz, btype=btype, fs=fs_hz, output="sos")
    return np.asarray(sos, dtype=np.float64)


@lru_cache(maxsize=64)
def _zi_unit(order: int, cutoff_hz: float, fs_hz: float, btype: str = "lowpass") -> Array:
    return np.asarray(
        signal.sosfilt_zi(butter_sos(order, cutoff_hz, fs_hz, btype)), dtype=np.float64
    )


@lru_cache(maxsize=64)
def dc_group_delay_s(order: int, cutoff_hz: float, fs_hz: float) -> float:
    """Group delay at 0 Hz, seconds: how far a causal low-pass lags slow signals."""
    b, a = signal.sos2tf(butter_sos(order, cutoff_hz, fs_hz))
    _, gd = signal.group_delay((b, a), w=[1e-4], fs=fs_hz)
    return float(gd[0]) / fs_hz


@dataclass(frozen=True, slots=True)
class LowPass:
    """A Butterworth filter (low-pass unless ``btype``) along axis 0 of (N, C) data.

    State is (n_sections, 2, C)."""

    order: int
    cutoff_hz: float
    fs_hz: float
    btype: str = "lowpass"

    @property
    def sos(self) -> Array:
        return butter_sos(self.order, self.cutoff_hz, self.fs_hz, self.btype)

    def initial_state(self, x0: Array) -> Array:
        """Steady state for a constant input ``x0`` (C,), so a restart has no step transient."""
        zi = _zi_unit(self.order, self.cutoff_hz, self.fs_hz, self.btype)
        return zi[:, :, None] * x0[None, None, :]

    def __call__(self, x: Array, zi: Array) -> tuple[Array, Array]:
        """Filter ``x`` (N, C) from state ``zi``; chunking gives identical output."""
        if len(x) == 0:
            return x.copy(), zi
        y, zf = signal.sosfilt(self.sos, x, axis=0, zi=zi)
        return np.asarray(y, dtype=np.float64), np.asarray(zf, dtype=np.float64)
