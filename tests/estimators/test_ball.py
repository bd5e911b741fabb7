"""Smallest enclosing ball (the paper's motion test, §3.2.2), against geometry."""

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from estimators.ball import enclosing_radius, fits_in_ball


def test_simple_sets():
    assert enclosing_radius(np.zeros((1, 3))) == 0.0
    assert enclosing_radius(np.array([[0, 0, 0], [0.3, 0.4, 0]], float)) == pytest.approx(0.25)
    # equilateral triangle of side s: circumradius s/√3
    s = 0.1
    tri = np.array([[0, 0, 0], [s, 0, 0], [s / 2, s * math.sqrt(3) / 2, 0]])
    assert enclosing_radius(tri) == pytest.approx(s / math.sqrt(3))
    # regular tetrahedron of edge e: circumradius e √(3/8)
    tet = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    assert enclosing_radius(tet) == pytest.approx(2 * math.sqrt(2) * math.sqrt(3 / 8))
    # an obtuse triangle's ball is the one on its longest side
    obtuse = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.1, 0]])
    assert enclosing_radius(obtuse) == pytest.approx(0.5)
    assert math.isnan(enclosing_radius(np.empty((0, 3))))


@pytest.mark.parametrize("seed", range(5))
def test_points_on_a_sphere_with_interior_points(seed):
    rng = np.random.default_rng(seed)
    c, r = rng.normal(size=3), rng.uniform(0.01, 1.0)
    u = rng.normal(size=(8, 3))
    surface = c + r * u / np.linalg.norm(u, axis=1, keepdims=True)
    # points spread over the whole sphere pin it; interior points change nothing
    surface = np.vstack([surface, c + r * np.eye(3), c - r * np.eye(3)])
    inner = c + 0.5 * r * rng.uniform(-1, 1, (50, 3)) / math.sqrt(3)
    pts = rng.permutation(np.vstack([surface, inner]))
    assert enclosing_radius(pts) == pytest.approx(r, rel=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_matches_a_numerical_minimax(seed):
    # min over c of max |p − c|, solved by a general constrained optimiser
    rng = np.random.default_rng(100 + seed)
    pts = rng.normal(size=(60, 3)) * rng.uniform(0.01, 0.2, 3)
    x0 = np.append(pts.mean(axis=0), 1.0)
    res = minimize(
        lambda x: x[3],  # minimise r² subject to |p − c|² ≤ r² (a convex program)
        x0,
        method="SLSQP",
        constraints=[{"type": "ineq", "fun": lambda x: x[3] - np.sum((pts - x[:3]) ** 2, axis=1)}],
        options={"ftol": 1e-13, "maxiter": 500},
    )
    assert res.success
    res.fun = math.sqrt(res.fun)
    r = enclosing_radius(pts)
    assert r <= res.fun * (1 + 1e-9)  # never larger than any enclosing ball
    assert r == pytest.approx(res.fun, rel=1e-5)
    assert np.max(np.linalg.norm(pts - pts.mean(axis=0), axis=1)) >= r


def test_fits_in_ball_is_the_sphere_test_not_the_centroid_distance():
    # an elbow path with most samples at one end: the centroid sits near that end, so the
    # farthest sample is 8 cm from it, yet the whole path fits a 10 cm ball (6 cm long)
    x = np.concatenate([np.zeros(90), np.linspace(0.0, 0.06, 10)])
    p = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    p[:, 1] = 0.03 * np.sin(np.linspace(0, 1, len(x)))
    centroid_dist = np.max(np.linalg.norm(p - p.mean(axis=0), axis=1))
    assert centroid_dist > 0.05
    assert enclosing_radius(p) < 0.05
    assert fits_in_ball(p, 0.10)
    # and a path just longer than the diameter does not fit
    q = np.column_stack([np.linspace(0, 0.1001, 50), np.zeros(50), np.zeros(50)])
    assert not fits_in_ball(q, 0.10)
    assert fits_in_ball(q[:-1], 0.10)
