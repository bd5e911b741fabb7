"""Butterworth filters as second-order sections, with explicit state, without ``scipy.signal``.

Why not ``scipy.signal``: issue 23 asks ``rehab analyze`` of an 8-minute session to take
≤ 1.1 s wall, start-up included, and ``import scipy.signal`` imports the whole package
(``scipy.stats``, ``interpolate``, ``windows`` ...): 1.0–1.3 s on the project's 2-core
machine, against 0.15 s for numpy and vqf and 0.2–0.35 s for numba, which the wearable
kernel already uses (``python -X importtime``; docs/benchmarks.md, issue 23). The core uses
four pieces of it, held here, computed as SciPy computes them so the numbers stay the same
(tests compare them with ``scipy.signal`` on real and random data):

- :func:`butter_sos`: the digital Butterworth design of ``scipy.signal.butter(...,
  output="sos")``: the analog prototype's poles ``-exp(iπm/2N)``, pre-warped cut-off
  ``4 tan(πWn/2)``, bilinear transform, sections paired and ordered as ``zpk2sos``'s
  "nearest" pairing (paper §3.2.1: 5th order, 0.5 Hz, on the fusion grid);
- :func:`sosfilt`: the cascade in direct form II transposed, numba-compiled, with state in
  and out (the one implementation: the live path's chunks and ``analyze``'s whole session
  give the same numbers);
- :func:`filtfilt`: forward-backward filtering with ``sosfiltfilt``'s odd extension and
  steady-state initial conditions (the movement quality's zero-lag low-pass);
- :func:`dc_group_delay_s`: the group delay near 0 Hz, by ``group_delay``'s formula.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.jit import aot

Array: TypeAlias = NDArray[np.float64]
CArray: TypeAlias = NDArray[np.complex128]


def _poly(roots: list[Any]) -> Array:
    """Monic polynomial with these roots (``np.poly``'s product of ``[1, -r]`` factors);
    conjugate pairs give real coefficients."""
    r = np.asarray(roots)
    a = np.ones(1, dtype=r.dtype)
    for x in r:
        a = np.convolve(a, np.stack((np.ones_like(x), -x)))
    return np.real(a).copy() if np.iscomplexobj(a) else a


def _section(z: list[Any], p: list[Any]) -> Array:
    """One section ``[b0, b1, b2, 1, a1, a2]`` from up to two zeros and two poles."""
    sos = np.zeros(6)
    b, a = _poly(z), _poly(p)
    sos[3 - len(b) : 3] = b
    sos[6 - len(a) : 6] = a
    return sos


def _pair(z: Array, p: CArray, k: float) -> Array:
    """Second-order sections from real zeros ``z``, poles ``p`` (conjugate pairs and real
    ones) and gain ``k``: ``scipy.signal.zpk2sos``'s default pairing for a digital filter.
    The pole nearest the unit circle goes last with its conjugate (or the next real pole) and
    the zeros nearest it; an odd count gets a pole and a zero at the origin."""
    if len(p) % 2:
        p = np.concatenate((p, [0.0]))
        z = np.concatenate((z, [0.0]))
    z = np.sort(z)
    # one of each conjugate pair (ascending real part), then the real poles
    p = p[np.lexsort((abs(p.imag), p.real))]
    real = abs(p.imag) <= 100 * np.finfo(np.float64).eps * abs(p)
    pc = p[~real]
    upper, lower = pc[pc.imag > 0], pc[pc.imag < 0]
    pool = np.concatenate(((upper + lower.conj()) / 2, p[real].real))
    sos = np.zeros((len(p) // 2, 6))
    for si in range(len(sos) - 1, -1, -1):
        i = int(np.argmin(np.abs(1 - np.abs(pool))))
        p1 = pool[i]
        pool = np.delete(pool, i)
        reals = np.flatnonzero(np.isreal(pool))
        if np.isreal(p1) and len(reals) == 0:  # the last real pole, with the origin
            j = int(np.argmin(np.abs(z - p1)))
            sos[si] = _section([z[j], 0], [p1, 0])
            z = np.delete(z, j)
            continue
        if np.isreal(p1):
            j = int(reals[np.argmin(np.abs(1 - np.abs(pool[reals])))])
            p2 = pool[j]
            pool = np.delete(pool, j)
        else:
            p2 = p1.conj()
        zs = []
        for _ in range(min(2, len(z))):
            j = int(np.argmin(np.abs(z - p1)))
            zs.append(z[j])
            z = np.delete(z, j)
        sos[si] = _section(zs, [p1, p2])
    sos[0][:3] *= k
    return sos


@lru_cache(maxsize=64)
def butter_sos(order: int, cutoff_hz: float, fs_hz: float, btype: str = "lowpass") -> Array:
    """Second-order sections (n_sections, 6) of a digital Butterworth low- or high-pass of
    ``order`` with its −3 dB point at ``cutoff_hz`` for sampling rate ``fs_hz`` (paper
    §3.2.1), as ``scipy.signal.butter(order, cutoff_hz, btype, fs=fs_hz, output="sos")``.
    Read-only: shared by every caller."""
    if btype not in ("lowpass", "highpass") or order < 1:
        raise ValueError(f"Butterworth {btype} of order {order}: not supported")
    wn = np.asarray(cutoff_hz, dtype=np.float64) / (float(fs_hz) / 2)
    if not 0 < wn < 1:
        raise ValueError(f"cut-off {cutoff_hz} Hz not in (0, {fs_hz / 2}) Hz")
    wo = float(4.0 * np.tan(np.pi * wn / 2.0))  # pre-warped for the bilinear transform
    m = np.arange(-order + 1, order, 2, dtype=np.float64)
    p: CArray = -np.exp(1j * np.pi * m / (2 * order))  # analog prototype, cut-off 1 rad/s
    if btype == "lowpass":
        p = wo * p
        k = 1.0 * wo**order
        z = np.empty(0)
        zd = -np.ones(order)  # the zeros at infinity go to Nyquist
    else:  # invert about the unit circle: the zeros at infinity go to the origin, then 0 Hz
        k = 1.0 * float(np.real(np.prod(-np.empty(0)) / np.prod(-p)))
        p = wo / p
        z = np.zeros(order)
        zd = (4.0 + z) / (4.0 - z)
    pd = (4.0 + p) / (4.0 - p)  # bilinear transform, fs = 2
    kd = k * np.real(np.prod(4.0 - z) / np.prod(4.0 - p))
    sos = _pair(zd, pd, float(kd))
    sos.setflags(write=False)
    return sos


@aot("void(f8[:, ::1], f8[:, ::1], f8[:, :, ::1])")
def _sosfilt(sos: Any, x: Any, zi: Any) -> None:  # pragma: no cover - compiled
    """In place: ``x`` (N, C) becomes the output and ``zi`` (sections, 2, C) the final
    state. Direct form II transposed, section after section, in ``scipy.signal.sosfilt``'s
    order of operations (channels are independent)."""
    for n in range(x.shape[0]):
        for c in range(x.shape[1]):
            x_cur = x[n, c]
            for s in range(sos.shape[0]):
                x_new = sos[s, 0] * x_cur + zi[s, 0, c]
                zi[s, 0, c] = sos[s, 1] * x_cur - sos[s, 4] * x_new + zi[s, 1, c]
                zi[s, 1, c] = sos[s, 2] * x_cur - sos[s, 5] * x_new
                x_cur = x_new
            x[n, c] = x_cur


def sosfilt(sos: Array, x: Array, zi: Array) -> tuple[Array, Array]:
    """Filter ``x`` (N, C) along axis 0 from state ``zi`` (sections, 2, C); returns new
    arrays ``(y (N, C), final state)``. Chunks filtered in turn, each from the previous
    one's state, give the whole series' output bit for bit."""
    y = np.array(x, dtype=np.float64, order="C")
    z = np.array(zi, dtype=np.float64, order="C")
    _sosfilt(np.ascontiguousarray(sos, dtype=np.float64), y, z)
    return y, z


def sosfilt_zi(sos: Array) -> Array:
    """Steady state (sections, 2) of the cascade for a unit step (``sosfilt_zi``): each
    section's ``zi = (I − A)⁻¹ (b[1:] − a[1:] b0)``, A its companion matrix, scaled by the
    DC gain of the sections before it. Read-only (cached)."""
    return _zi(np.ascontiguousarray(sos, dtype=np.float64).tobytes())


@lru_cache(maxsize=64)
def _zi(key: bytes) -> Array:
    sos = np.frombuffer(key, dtype=np.float64).reshape(-1, 6)
    zi = np.empty((len(sos), 2))
    scale = 1.0
    for s, (b, a) in enumerate(zip(sos[:, :3], sos[:, 3:], strict=True)):
        i_minus_a = np.eye(2) - np.array([[-a[1], -a[2]], [1.0, 0.0]]).T
        zi[s] = scale * np.linalg.solve(i_minus_a, b[1:] - a[1:] * b[0])
        scale *= np.sum(b) / np.sum(a)
    zi.setflags(write=False)
    return zi


def filtfilt(sos: Array, x: Array, padlen: int) -> Array:
    """Zero-lag filtering of ``x`` (N, C) along axis 0 (``scipy.signal.sosfiltfilt`` with
    its odd extension of ``padlen`` samples at each end, 0 < padlen < N): forward from the
    steady state of the first padded sample, backward from that of the last output."""
    ext = np.concatenate(
        (
            2 * x[:1] - x[padlen:0:-1],
            x,
            2 * x[-1:] - x[-2 : -(padlen + 2) : -1],
        )
    )
    zi = sosfilt_zi(sos)[:, :, None]
    y, _ = sosfilt(sos, ext, zi * ext[:1])
    y, _ = sosfilt(sos, y[::-1], zi * y[-1:])
    return y[::-1][padlen:-padlen]


@lru_cache(maxsize=64)
def dc_group_delay_s(order: int, cutoff_hz: float, fs_hz: float) -> float:
    """Group delay at 0 Hz (evaluated at 10⁻⁴ Hz), seconds: how far a causal low-pass lags
    slow signals. ``−d arg H/dω`` of the cascade's transfer function ``B/A`` by
    ``scipy.signal.group_delay``'s formula (with ``C = B · rev(A)``,
    ``τ = Re(Σ k c_k z⁻ᵏ / Σ c_k z⁻ᵏ) − deg A``)."""
    sos = butter_sos(order, cutoff_hz, fs_hz)
    b, a = np.ones(1), np.ones(1)
    for row in sos:
        b = np.convolve(b, np.trim_zeros(row[:3], "f"))
        a = np.convolve(a, np.trim_zeros(row[3:], "f"))
    w = 2 * np.pi * np.atleast_1d(1e-4) / fs_hz
    c = np.convolve(b, a[::-1])
    z = np.exp(-1j * w)
    num = np.polyval((c * np.arange(c.size))[::-1], z)
    den = np.polyval(c[::-1], z)
    gd = np.real(num / den) - a.size + 1
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
        zi = sosfilt_zi(self.sos)
        return zi[:, :, None] * x0[None, None, :]

    def __call__(self, x: Array, zi: Array) -> tuple[Array, Array]:
        """Filter ``x`` (N, C) from state ``zi``; chunking gives identical output."""
        if len(x) == 0:
            return x.copy(), zi
        return sosfilt(self.sos, x, zi)
