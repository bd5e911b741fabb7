"""Vectorised unit-quaternion helpers, ``[w, x, y, z]`` along the last axis.

Convention (paper §3.1): ``q_RA`` rotates coordinates from A to R, ``v_R = q ⊗ v_A ⊗ q*``.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

Array: TypeAlias = NDArray[np.float64]


def mul(a: Array, b: Array) -> Array:
    """Hamilton product ``a ⊗ b``; shapes (..., 4) broadcast."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        axis=-1,
    )


def conj(q: Array) -> Array:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def rotate(q: Array, v: Array) -> Array:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4): ``q ⊗ v ⊗ q*``."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)  # type: ignore[no-any-return]


def about_z(delta: Array | float) -> Array:
    """Heading rotation ``Rz(δ)`` as a quaternion (paper eq. 9); ``delta`` in rad."""
    d = np.asarray(delta, dtype=np.float64) / 2.0
    z = np.zeros_like(d)
    return np.stack((np.cos(d), z, z, np.sin(d)), axis=-1)


def rotate_z(delta: Array | float, v: Array) -> Array:
    """``Rz(δ) v`` for vectors (..., 3), cheaper than a quaternion product."""
    c, s = np.cos(delta), np.sin(delta)
    x, y = v[..., 0], v[..., 1]
    return np.stack((c * x - s * y, s * x + c * y, v[..., 2]), axis=-1)


def normalize(q: Array) -> Array:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)  # type: ignore[no-any-return]


def nlerp(q0: Array, q1: Array, s: Array) -> Array:
    """Normalised linear interpolation (shortest arc), ``s`` (...,) in [0, 1].

    Between samples 10 ms apart nlerp differs from slerp by far less than sensor noise.
    """
    sign = np.where(np.sum(q0 * q1, axis=-1, keepdims=True) < 0.0, -1.0, 1.0)
    return normalize(q0 + s[..., None] * (sign * q1 - q0))


def angle(q: Array) -> Array:
    """Rotation angle of each quaternion, rad in [0, π]."""
    return 2.0 * np.arccos(np.clip(np.abs(q[..., 0]), 0.0, 1.0))  # type: ignore[no-any-return]
