"""Vectorised rotation helpers. Quaternions are (w, x, y, z), Hamilton, active rotations.

``q`` with shape (..., 4) rotates a vector from the body frame into the reference frame:
``v_ref = q ⊗ v_body ⊗ q*``. Rotation matrices have the body axes as columns.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

F64: TypeAlias = NDArray[np.float64]


def multiply(q: F64, p: F64) -> F64:
    """Hamilton product ``q ⊗ p``; shapes broadcast, (..., 4)."""
    w1, x1, y1, z1 = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    w2, x2, y2, z2 = np.moveaxis(np.asarray(p, dtype=np.float64), -1, 0)
    return np.stack(
        (
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ),
        axis=-1,
    )


def conjugate(q: F64) -> F64:
    """Inverse of a unit quaternion, (..., 4)."""
    return np.asarray(np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0]))


def rotate(q: F64, v: F64) -> F64:
    """Rotate body vectors ``v`` (..., 3) into the reference frame of ``q`` (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return np.asarray(v + w * t + np.cross(u, t), dtype=np.float64)


def from_axis_angle(axis: F64, angle: F64 | float) -> F64:
    """Quaternion of a rotation by ``angle`` (rad) about unit ``axis`` (..., 3)."""
    axis = np.asarray(axis, dtype=np.float64)
    half = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    return np.concatenate((np.cos(half), np.sin(half) * axis), axis=-1)


def from_rotvec(r: F64) -> F64:
    """Quaternion of rotation vectors ``r`` (..., 3), rad."""
    r = np.asarray(r, dtype=np.float64)
    angle = np.linalg.norm(r, axis=-1)
    half = 0.5 * angle
    # sin(a/2)/a → 1/2 for a → 0; the series keeps tiny rotations exact.
    small = angle < 1e-8
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate((np.cos(half)[..., None], k[..., None] * r), axis=-1)


def to_matrix(q: F64) -> F64:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), -1),
            np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), -1),
            np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1),
        ),
        axis=-2,
    )


def from_matrix(m: F64) -> F64:
    """Unit quaternions (..., 4) with w ≥ 0 from rotation matrices (..., 3, 3) (Shepperd)."""
    m = np.asarray(m, dtype=np.float64)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cand = np.stack(
        (
            np.stack(
                (
                    1 + tr,
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                ),
                -1,
            ),
            np.stack(
                (
                    m[..., 2, 1] - m[..., 1, 2],
                    1 + 2 * m[..., 0, 0] - tr,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                ),
                -1,
            ),
            np.stack(
                (
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 0, 1] + m[..., 1, 0],
                    1 + 2 * m[..., 1, 1] - tr,
                    m[..., 1, 2] + m[..., 2, 1],
                ),
                -1,
            ),
            np.stack(
                (
                    m[..., 1, 0] - m[..., 0, 1],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 + 2 * m[..., 2, 2] - tr,
                ),
                -1,
            ),
        ),
        axis=-2,
    )
    # Pick the best-conditioned of the four formulas (largest diagonal term) per matrix.
    diag = np.stack((tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]), -1)
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(cand, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.asarray(np.where(q[..., :1] < 0, -q, q), dtype=np.float64)


def continuous(q: F64) -> F64:
    """Flip signs along axis 0 of (N, 4) so consecutive quaternions lie in one hemisphere."""
    q = np.array(q, dtype=np.float64)
    if len(q) < 2:
        return q
    flips = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0
    sign = np.concatenate(([1.0], np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)))
    return q * sign[:, None]


def angle_between(q: F64, p: F64) -> F64:
    """Rotation angle (rad) of ``q* ⊗ p``, (...)."""
    d = np.abs(np.einsum("...i,...i->...", q, p))
    return np.asarray(2.0 * np.arccos(np.clip(d, 0.0, 1.0)), dtype=np.float64)
