"""Heading estimation (paper §3.2): cost identity, grid search, drift fit, schedule."""

import itertools
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


def _window(
    delta: float,
    motion: bool,
    t_end: float = 20.0,
    rate: float = 25.0,
    noise: float = 0.0,
    rng: np.random.Generator | None = None,
):
    """A 20 s window of an elbow moving on a Lissajous path; the IMU's acceleration is the
    robot's turned by −δ, plus white noise of ``noise`` m/s² on both."""
    t = np.arange(t_end - 20.0 + 1 / rate, t_end + 1e-9, 1 / rate)
    amp = 0.2 if motion else 0.01
    p = np.stack([amp * np.cos(t), amp * np.sin(1.3 * t), 0 * t], axis=1)
    b = -np.stack([amp * np.cos(t), 1.69 * amp * np.sin(1.3 * t), 0 * t], axis=1)
    a = quat.rotate_z(-delta, b)
    if noise:
        rng = rng or np.random.default_rng(0)
        a = a + noise * rng.normal(size=a.shape)
        b = b + noise * rng.normal(size=b.shape)
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


def _paper_run(truths_deg, noise=0.0, seed=0):
    """update_paper over one window per heading in ``truths_deg``; (estimates in degrees,
    the counted window at which it converged or None)."""
    p = hd.HeadingParams.paper()
    s = hd.HeadingState()
    rng = np.random.default_rng(seed)
    est, conv_at = [], None
    for k, deg in enumerate(truths_deg, start=1):
        w = _window(math.radians(deg), True, 20.0 * k, noise=noise, rng=rng)
        assert hd.update_paper(s, w, p, 20.0 * k)
        est.append(math.degrees(s.delta))
        if s.converged and conv_at is None:
            conv_at = k
    return est, conv_at


def _first_settled(est, n_two_step=5, count=5, tol=5.0):
    """The paper's rule written out: from the sixth counted window on, converged once each of
    the last five estimates changed by at most 5° from the one before (1-based window)."""
    for k in range(n_two_step + 1, len(est) + 1):
        last = est[k - count - 1 : k]
        if len(last) == count + 1 and all(
            abs((b - a + 180.0) % 360.0 - 180.0) <= tol + 1e-9 for a, b in itertools.pairwise(last)
        ):
            return k
    return None


def test_paper_converges_on_changes_of_exactly_five_degrees():
    # estimates 10°, 15°, ..., 40°: each change is exactly the paper's 5° (not 5° + rounding)
    est, conv_at = _paper_run([10.0 + 5.0 * k for k in range(7)])
    assert est == pytest.approx([10.0 + 5.0 * k for k in range(7)], abs=1e-9)
    assert conv_at == 6


def test_paper_uses_the_two_step_grid_until_converged():
    # five unsettled windows, then the heading at 40°: not converged, so the sixth window's
    # full search finds 40° at once (the one-step grid would crawl there by 5° per window);
    # five settled estimates later it converges
    truths = [0.0, 90.0, 180.0, 270.0, 0.0] + [40.0] * 8
    est, conv_at = _paper_run(truths)
    assert est[5] == pytest.approx(40.0, abs=1e-9)
    assert conv_at == 11 == _first_settled(est)


def test_paper_uses_the_one_step_grid_once_converged():
    # after convergence a 30° jump is followed within ±5° per window (eq. 8)
    truths = [50.0] * 6 + [80.0] * 8
    est, conv_at = _paper_run(truths)
    assert conv_at == 6
    assert est[6:12] == pytest.approx([55.0, 60.0, 65.0, 70.0, 75.0, 80.0], abs=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_paper_schedule_on_noisy_windows(seed):
    # noisy accelerations (0.05 m/s² white on both, against ~0.2-0.35 m/s² of motion): the
    # first five two-step estimates at one heading, then five settled ones at another
    rng = np.random.default_rng(seed)
    first, second = rng.uniform(0, 360), rng.uniform(0, 360)
    truths = [first] * 5 + [second] * 7
    est, conv_at = _paper_run(truths, noise=0.05, seed=seed)
    err = [abs((e - t + 180.0) % 360.0 - 180.0) for e, t in zip(est, truths, strict=True)]
    assert max(err) <= 2.0  # the two-step search finds each heading to its 1° grid
    expected = _first_settled(est)
    assert conv_at == expected
    if abs((second - first + 180.0) % 360.0 - 180.0) > 7.0:
        assert conv_at == 11  # five settled estimates after the change at window 6


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
