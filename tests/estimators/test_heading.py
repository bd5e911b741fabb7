"""Heading estimation (paper §3.2): cost identity, grid search, drift fit, schedule."""

import math

import numpy as np
import pytest

from estimators import heading as hd
from estimators import quaternion as quat


def _pair(delta: float, n: int = 500, noise: float = 0.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, 3))
    b = quat.rotate_z(delta, a) + noise * rng.normal(size=(n, 3))
    return a, b


def test_sinusoid_identity_matches_direct_cost():
    a, b = _pair(0.7, noise=0.3)
    grid = np.radians(np.arange(0, 360, 5.0))
    sc, ss = hd.sums(a, b)
    direct = hd.cost(grid, a, b)
    c0 = float(np.sum(a * a) + np.sum(b * b) - 2 * np.sum(a[:, 2] * b[:, 2]))
    np.testing.assert_allclose(direct, c0 - 2 * (sc * np.cos(grid) + ss * np.sin(grid)), rtol=1e-10)
    assert hd.optdelta(grid, sc, ss) == grid[np.argmin(direct)]


@pytest.mark.parametrize("deg", [-170.0, -33.3, 0.0, 12.5, 179.0])
def test_closed_form_recovers_heading(deg):
    a, b = _pair(math.radians(deg), noise=0.05)
    sc, ss = hd.sums(a, b)
    assert math.degrees(hd.wrap(math.atan2(ss, sc) - math.radians(deg))) == pytest.approx(
        0, abs=0.5
    )


def test_drift_fit_recovers_offset_and_rate():
    rng = np.random.default_rng(3)
    n = 500
    tau = np.linspace(-20.0, 0.0, n)
    a = rng.normal(size=(n, 3))
    d0, rate = math.radians(40.0), math.radians(0.5)
    b = quat.rotate_z(d0 + rate * tau, a) + 0.05 * rng.normal(size=(n, 3))
    p = hd.HeadingParams(drift_prior_std_dps=2.0)
    d, r, sd, _ = hd.fit_drift(a, b, tau, 0.0, p)
    assert math.degrees(hd.wrap(d - d0)) == pytest.approx(0.0, abs=0.3)
    assert math.degrees(r) == pytest.approx(0.5, abs=0.05)
    assert 0 < math.degrees(sd) < 1.0


def _window(delta: float, motion: bool, t_end: float = 20.0, rate: float = 25.0):
    t = np.arange(t_end - 20.0 + 1 / rate, t_end + 1e-9, 1 / rate)
    amp = 0.2 if motion else 0.01
    p = np.stack([amp * np.cos(t), amp * np.sin(1.3 * t), 0 * t], axis=1)
    b = -np.stack([amp * np.cos(t), 1.69 * amp * np.sin(1.3 * t), 0 * t], axis=1)
    a = quat.rotate_z(-delta, b)
    return hd.Window(t, a, b, p, np.ones(len(t), bool))


def test_motion_test_counts_subwindows():
    p = hd.HeadingParams.paper()
    assert hd.motion_subwindows(_window(0.3, True), p, 20.0) == 5
    assert hd.motion_subwindows(_window(0.3, False), p, 20.0) == 0


def test_paper_schedule_converges_after_five_plus_five_windows():
    p = hd.HeadingParams.paper()
    s = hd.HeadingState()
    truth = math.radians(123.4)
    for k in range(1, 12):
        assert hd.update_paper(s, _window(truth, True, 20.0 * k), p, 20.0 * k)
        assert s.converged == (k >= 6)
    # quantised to the paper's 1° grid
    assert math.degrees(s.delta) == pytest.approx(123.0, abs=0.01)


def test_no_update_without_motion():
    for p in (hd.HeadingParams.paper(), hd.HeadingParams()):
        s = hd.HeadingState()
        update = hd.update_paper if p.method == "paper" else hd.update_improved
        args = (s, _window(1.0, False), p, 20.0) + (() if p.method == "paper" else (1.0,))
        assert update(*args) is False
        assert s.delta is None and not s.converged


def test_improved_is_sub_degree_and_reports_uncertainty():
    p = hd.HeadingParams()
    s = hd.HeadingState()
    truth = math.radians(-57.25)
    for k in range(1, 5):
        hd.update_improved(s, _window(truth, True, 20.0 + k), p, 20.0 + k, 0.0)
    assert s.converged
    assert math.degrees(hd.wrap(s.delta - truth)) == pytest.approx(0.0, abs=0.05)
    assert math.isfinite(s.std) and s.std < math.radians(1)
