"""Smallest enclosing ball of a point set (for the paper's motion test, §3.2.2).

Welzl's algorithm (1991) in its incremental form: the ball of the first ``k`` points is grown
whenever a later point lies outside it, by solving the same problem for the earlier points with
that point on the boundary. The ball is unique, so the result does not depend on the order;
the expected work is linear in the number of points (here ~100 per 4 s sub-window).
"""

from __future__ import annotations

import math
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

Array: TypeAlias = NDArray[np.float64]

_REL = 1e-12  # relative slack of "inside" (rounding of the ball's own construction)


def enclosing_radius(points: Array) -> float:
    """Radius (m) of the smallest ball containing every row of ``points`` (n, 3); 0 for one
    point, NaN for none or for NaN coordinates."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0 or not bool(np.isfinite(p).all()):
        return math.nan
    _, r2 = _welzl(p, len(p), [])
    return math.sqrt(r2)


def fits_in_ball(points: Array, diameter: float) -> bool:
    """Whether the rows of ``points`` (n, 3) fit in a ball of ``diameter`` (m).

    Two cheap bounds decide most windows without the exact ball: the largest distance from the
    centroid bounds the smallest radius from above, the longest extent along an axis (half of
    it) from below.
    """
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    if n < 2:
        return True
    r = 0.5 * diameter
    # the ufuncs' own reductions: what p.mean(axis=0), np.max and np.ptp compute (the same
    # sum divided by the same count, max − min), without their wrappers, which cost more
    # than the arithmetic on a sub-window's ~100 points (the heading's motion test: ~500 a
    # session)
    d = p - np.add.reduce(p, axis=0) / n
    if np.einsum("ij,ij->i", d, d).max() <= r * r:
        return True
    if (np.maximum.reduce(p, axis=0) - np.minimum.reduce(p, axis=0)).max() > diameter:
        return False
    return not enclosing_radius(p) > r  # NaN: no evidence of motion


def _welzl(p: Array, n: int, boundary: list[Array]) -> tuple[Array, float]:
    """Smallest ball of ``p[:n]`` with the points of ``boundary`` (≤ 4) on its surface:
    (centre, squared radius)."""
    if len(boundary) == 4 or (n == 0 and boundary):
        return _circumball(boundary)
    if boundary:
        c, r2 = _circumball(boundary)
        start = 0
    else:
        c, r2 = p[0], 0.0
        start = 1
    i = start
    while i < n:
        d = p[i:n] - c
        out = np.flatnonzero(np.einsum("ij,ij->i", d, d) > r2 * (1.0 + _REL) + 1e-18)
        if len(out) == 0:
            break
        k = i + int(out[0])
        c, r2 = _welzl(p, k, [*boundary, p[k]])
        i = k + 1
    return c, r2


def _circumball(pts: list[Array]) -> tuple[Array, float]:
    """Smallest ball with 1–4 given points on its surface: (centre, squared radius)."""
    a = pts[0]
    if len(pts) == 1:
        return a, 0.0
    if len(pts) == 2:
        c = 0.5 * (a + pts[1])
        return c, float(np.sum((pts[1] - c) ** 2))
    # the centre is a + x with 2 (p_i − a)·x = |p_i − a|² for each other point, and, for three
    # points, x in their plane (x = s u + t v): the minimum-norm solution does both
    m = np.array([q - a for q in pts[1:]])
    rhs = 0.5 * np.einsum("ij,ij->i", m, m)
    x = np.linalg.lstsq(m, rhs, rcond=None)[0]
    return a + x, float(x @ x)
