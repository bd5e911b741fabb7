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
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def conj(q: Array) -> Array:
    out: Array = q * np.array([1.0, -1.0, -1.0, -1.0])
    return out


def rotate(q: Array, v: Array) -> Array:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4): ``q ⊗ v ⊗ q*``.

    Written out by component: ``np.cross`` costs more in overhead than the arithmetic.
    """
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    # t = 2 (u × v)
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    # v + w t + u × t
    return np.stack(
        (
            vx + w * tx + (y * tz - z * ty),
            vy + w * ty + (z * tx - x * tz),
            vz + w * tz + (x * ty - y * tx),
        ),
        axis=-1,
    )


def matrix_columns(q: Array) -> Array:
    """The rotation matrix of ``q`` (..., 4) as its three columns side by side (..., 9):
    the images of the x, y and z axes."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        (
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
            2.0 * (x * y - w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ),
        axis=-1,
    )


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
