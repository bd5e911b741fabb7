"""The heading estimator's fast paths against straightforward references, bit for bit.

The references are the plain formulations (boolean-mask copies, one concatenated delay,
``np.mean``/``np.einsum`` per sub-window, the drift fit, rotation and lag search as first
written, with nothing taken from the module but ``wrap``/``predict``); the module's versions
avoid copies, wrappers, temporaries and short inner loops but must produce every float
identically.
"""

import copy
import dataclasses
import math

import numpy as np
import pytest

from estimators import heading as hd


def _same(x, y) -> bool:
    """Bitwise equality of floats, arrays and lists of them (NaN payloads and −0.0 too)."""
    if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
        x, y = np.asarray(x), np.asarray(y)
        return x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    if isinstance(x, list):
        return isinstance(y, list) and len(x) == len(y) and all(map(_same, x, y))
    if isinstance(x, float) or isinstance(y, float):
        return np.float64(x).tobytes() == np.float64(y).tobytes()
    return x == y


def _special(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Random values with signed zeros, ±NaN, infinities and wide exponents mixed in."""
    x = rng.normal(size=shape) * 10.0 ** rng.integers(-5, 5, size=shape)
    pick = rng.random(shape)
    x[pick < 0.02] = 0.0
    x[(pick >= 0.02) & (pick < 0.04)] = -0.0
    x[(pick >= 0.04) & (pick < 0.045)] = np.nan
    x[(pick >= 0.045) & (pick < 0.05)] = -np.float64(np.nan)
    x[(pick >= 0.05) & (pick < 0.052)] = np.inf
    return x


# ------------------------------------------------------------------ references


def _ref_rotate_z(delta, v):
    c, s = np.cos(delta), np.sin(delta)
    return np.stack((c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]), axis=1)


def _ref_fit_drift(a, b, tau, rate0, params, n_iter=4):
    sck = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]
    ssk = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    n = len(sck)
    c0, s0 = np.cos(rate0 * tau), np.sin(rate0 * tau)
    d0 = math.atan2(float(np.sum(ssk * c0 - sck * s0)), float(np.sum(sck * c0 + ssk * s0)))
    e2 = float(np.sum(a[:, :2] ** 2) + np.sum(b[:, :2] ** 2))
    span = float(tau[-1] - tau[0]) if n > 1 else 0.0
    n_eff = max(1.0, span * params.effective_rate_hz)
    sig_rho = math.radians(params.drift_prior_std_dps)
    d, r = d0, rate0
    inv_prior = 1.0 / (sig_rho * sig_rho)
    h00 = h01 = h11 = det = 0.0
    for _ in range(n_iter):
        e = d + r * tau
        ce, se = np.cos(e), np.sin(e)
        f = sck * ce + ssk * se
        g = ssk * ce - sck * se
        sf = float(f.sum())
        resid = max(e2 - 2.0 * sf, 1e-12)
        kappa = n_eff / n / (resid / (2.0 * n))
        ft = f * tau
        g0 = kappa * float(g.sum())
        g1 = kappa * float(g @ tau) - (r - rate0) * inv_prior
        h00, h01, h11 = kappa * sf, kappa * float(ft.sum()), kappa * float(ft @ tau) + inv_prior
        det = h00 * h11 - h01 * h01
        if not (math.isfinite(det) and det > 0.0):
            break
        d += (h11 * g0 - h01 * g1) / det
        r += (h00 * g1 - h01 * g0) / det
    if det != 0.0 and math.isfinite(det):
        sd, sr = math.sqrt(max(h11 / det, 0.0)), math.sqrt(max(h00 / det, 0.0))
    else:
        sd, sr = math.inf, sig_rho
    return hd.wrap(d), r, sd, sr


def _ref_estimate_lag(w, params, dt):
    t, a, b = w.t[w.valid], w.a[w.valid], w.b[w.valid]
    if len(t) < 20:
        return 0.0, 0.0
    lags = np.arange(-params.max_lag_s, params.max_lag_s + 1e-9, dt / 2.0)
    ah = np.hypot(a[:, 0], a[:, 1])
    bh = np.hypot(b[:, 0], b[:, 1])
    inner = (t >= t[0] + params.max_lag_s) & (t <= t[-1] - params.max_lag_s)
    if np.count_nonzero(inner) < 10:
        return 0.0, 0.0
    costs = []
    for lag in lags:
        dz = np.interp(t[inner] - lag, t, a[:, 2]) - b[inner, 2]
        dh = np.interp(t[inner] - lag, t, ah) - bh[inner]
        costs.append(np.sum(dz * dz + dh * dh))
    costs = np.array(costs)
    k = int(np.argmin(costs))
    if k == 0 or k == len(lags) - 1:
        return 0.0, 0.0
    c0, c1, c2 = costs[k - 1], costs[k], costs[k + 1]
    curv = c0 - 2 * c1 + c2
    if curv <= 0:
        return 0.0, 0.0
    step = lags[1] - lags[0]
    return float(lags[k] + 0.5 * step * (c0 - c2) / curv), float(curv / max(c1, 1e-12))


def _ref_jacobian(cl):
    n = len(cl)
    c = cl[:, :9].reshape(n, 3, 3).transpose(0, 2, 1)
    ldd = cl[:, 9:].reshape(n, 3, 3).transpose(0, 2, 1)
    return np.concatenate((-c, ldd), axis=2).reshape(3 * n, 6)


def _ref_delay(t, x, lag):
    s = np.clip(t - lag, t[0], t[-1])
    i1 = np.clip(np.searchsorted(t, s, side="left"), 1, len(t) - 1)
    i0 = i1 - 1
    w = ((s - t[i0]) / (t[i1] - t[i0]))[:, None]
    return x[i0] + w * (x[i1] - x[i0])


def _ref_sensor_fit(state, a, b, tau, cl, rate0, params):
    n = len(a)
    jac = _ref_jacobian(cl)
    jtj = jac.T @ jac
    prior = np.concatenate(
        (np.full(3, 1.0 / params.acc_bias_prior**2), np.full(3, 1.0 / params.lever_prior**2))
    )
    x = np.concatenate((state.acc_bias, state.lever_error))
    span = float(tau[-1] - tau[0]) if n > 1 else 0.0
    n_eff = max(1.0, span * params.effective_rate_hz)
    d0, rate, sd = 0.0, rate0, math.inf
    for _ in range(1 if state.converged else params.sensor_fit_iterations):
        ac = a + (jac @ x).reshape(n, 3)
        d0, rate, sd, _ = _ref_fit_drift(ac, b, tau, rate0, params, n_iter=3)
        y = (_ref_rotate_z(-(d0 + rate * tau), b) - a).reshape(-1)
        r = y - jac @ x
        var = max(float(r @ r) / (3 * n), 1e-8) * n / n_eff
        x = np.asarray(np.linalg.solve(jtj / var + np.diag(prior), (jac.T @ y) / var), np.float64)
    state.acc_bias, state.lever_error = x[:3].copy(), x[3:].copy()
    return d0, rate, sd


def _ref_update_improved(state, w, params, t, lag_s):
    a, b, tau = w.a[w.valid], w.b[w.valid], w.t[w.valid] - t
    recent = tau > -params.window_s
    excitation = (
        float(np.sqrt(np.mean(np.sum(b[recent, :2] ** 2, axis=1)))) if np.any(recent) else 0.0
    )
    state.excitation = excitation
    if (
        len(a) < 2
        or excitation < params.min_excitation
        or hd.motion_subwindows(w, params, t) < params.min_motion_subwindows
    ):
        return False
    v = w.valid
    cl = w.cl[v] if w.cl is not None else None
    if params.estimate_lag and (state.n_counted % params.lag_every == 0 or not state.converged):
        dt = float(np.median(np.diff(w.t))) if len(w.t) > 1 else 0.04
        k = int(np.searchsorted(w.t, t - params.window_s, side="right"))
        a_tail = w.a[k:]
        if params.estimate_sensor_errors and w.cl is not None:
            x = np.concatenate((state.acc_bias, state.lever_error))
            a_tail = a_tail + (_ref_jacobian(w.cl[k:]) @ x).reshape(-1, 3)
        tail = hd.Window(w.t[k:], a_tail, w.b[k:], w.p[k:], w.valid[k:])
        lag, weight = _ref_estimate_lag(tail, params, dt)
    else:
        lag, weight = 0.0, 0.0
    if params.estimate_lag:
        if weight > 0:
            state.lag = (state.lag * state.lag_weight + lag * weight) / (state.lag_weight + weight)
            state.lag_weight = min(state.lag_weight + weight, 50.0 * weight)
        if state.lag != 0.0:
            ac = np.concatenate((a, cl), axis=1) if cl is not None else a
            ac = _ref_delay(w.t[v], ac, state.lag)
            a, cl = ac[:, :3], (ac[:, 3:] if cl is not None else None)
    rate0 = state.rate if state.converged else 0.0
    if params.estimate_sensor_errors and cl is not None and np.any(cl):
        d0, rate, sd = _ref_sensor_fit(state, a, b, tau, cl, rate0, params)
    else:
        d0, rate, sd, _ = _ref_fit_drift(a, b, tau, rate0, params)
    d = hd.wrap(d0 + rate * lag_s)
    prev = hd.predict(state, t)
    state.n_counted += 1
    state.history.append(d)
    state.delta, state.rate, state.t_update, state.std = d, rate, t, sd
    if not state.converged:
        tol = math.radians(params.max_converge_std_deg)
        last = state.history[-3:]
        if (
            len(last) == 3
            and prev is not None
            and sd <= tol
            and all(abs(hd.wrap(last[i + 1] - last[i])) <= 2 * tol for i in range(2))
        ):
            state.converged, state.t_converged = True, t
    return True


# ------------------------------------------------------------------ data


def _motion_window(seed: int, n: int = 1000, invalid: float = 0.0, cl: bool = True) -> hd.Window:
    """An arm circling at 0.3 Hz seen by both sides (25 Hz, jittered clock), frame I turned
    by a random heading; the robot stream a little late."""
    rng = np.random.default_rng(seed)
    t = 100.0 + 0.04 * np.arange(n) + rng.normal(0.0, 2e-4, n)
    ph = 2 * np.pi * 0.3 * t
    amp = rng.uniform(0.2, 2.0)
    a = np.stack((amp * np.cos(ph), amp * np.sin(ph), 0.3 * np.sin(1.7 * ph)), axis=1)
    a += rng.normal(0.0, 0.05, (n, 3))
    d = rng.uniform(-3.0, 3.0)
    b = _ref_rotate_z(np.full(n, d), np.roll(a, 1, axis=0)) + rng.normal(0.0, 0.05, (n, 3))
    p = 0.2 * np.stack((np.cos(ph), np.sin(ph), 0.2 * np.sin(ph)), axis=1)
    p *= rng.uniform(0.2, 1.5)
    valid = rng.random(n) >= invalid
    c = rng.normal(0.0, 0.3, (n, 18)) if cl else None
    return hd.Window(t, a, b, p, valid, c)


def _read_only(w: hd.Window) -> hd.Window:
    """The window with read-only arrays: an in-place write into a caller's buffer raises."""
    arrays = {}
    for f in dataclasses.fields(w):
        x = getattr(w, f.name)
        if x is not None:
            x = x.copy()
            x.setflags(write=False)
        arrays[f.name] = x
    return hd.Window(**arrays)


def _states(rng: np.random.Generator) -> list[hd.HeadingState]:
    out = [hd.HeadingState()]
    for converged in (False, True):
        for n_counted in (3, 10, 11):
            s = hd.HeadingState(
                delta=0.4,
                rate=0.002,
                t_update=130.0,
                std=0.01,
                converged=converged,
                n_counted=n_counted,
                history=[0.41, 0.4],
                acc_bias=rng.normal(0.0, 0.05, 3),
                lever_error=rng.normal(0.0, 0.01, 3),
                lag=0.06 if n_counted != 3 else 0.0,
                lag_weight=2.0,
            )
            out.append(s)
    return out


PARAMS = [
    hd.HeadingParams(),
    hd.HeadingParams(estimate_lag=False),
    hd.HeadingParams(estimate_sensor_errors=False),
    hd.HeadingParams(sensor_fit_iterations=3, lag_every=3),
]


# ------------------------------------------------------------------ tests


@pytest.mark.parametrize("seed", range(6))
def test_update_improved_is_bit_identical_to_the_reference(seed):
    rng = np.random.default_rng(seed)
    n = [1000, 600, 520, 1000, 1000, 700][seed]
    w = _motion_window(seed, n, invalid=[0.0, 0.05, 0.0, 0.3, 0.0, 0.02][seed], cl=seed != 4)
    windows = [w, dataclasses.replace(w, valid=np.ones(n, bool))]
    if w.cl is not None:
        windows.append(dataclasses.replace(w, cl=None))
        # cl all zero (no sensor-error fit), and zero but for the last sample
        zero = np.zeros_like(w.cl)
        late = zero.copy()
        late[-1] = w.cl[-1]
        windows += [dataclasses.replace(w, cl=zero), dataclasses.replace(w, cl=late)]
    counted = 0
    for win in windows:
        fast_w = _read_only(win)
        t = float(win.t[-1]) - rng.uniform(0.0, 3.0)
        for state in _states(rng):
            for params in PARAMS:
                ref, fast = copy.deepcopy(state), copy.deepcopy(state)
                r_ref = _ref_update_improved(ref, win, params, t, 1.0)
                r_fast = hd.update_improved(fast, fast_w, params, t, 1.0)
                assert r_ref is r_fast
                counted += r_ref
                for f in dataclasses.fields(hd.HeadingState):
                    assert _same(getattr(ref, f.name), getattr(fast, f.name)), f.name
    assert counted > 0  # the fits ran, not just the early returns


@pytest.mark.parametrize("seed", range(4))
def test_update_paper_masks_like_compressing(seed):
    # with invalid samples dropped up front the paper update must see the same window
    w = _motion_window(seed, 500, invalid=0.2 * seed, cl=False)
    v = w.valid
    packed = hd.Window(w.t[v], w.a[v], w.b[v], w.p[v], np.ones(int(v.sum()), bool))
    p = hd.HeadingParams.paper()
    s1, s2 = hd.HeadingState(), hd.HeadingState()
    for t in (float(w.t[-1]) - 2.0, float(w.t[-1])):
        assert hd.update_paper(s1, _read_only(w), p, t) == hd.update_paper(s2, packed, p, t)
    for f in dataclasses.fields(hd.HeadingState):
        assert _same(getattr(s1, f.name), getattr(s2, f.name)), f.name


@pytest.mark.parametrize("n", [1, 2, 7, 300, 1000])
def test_jacobian_matches_concatenate(n):
    rng = np.random.default_rng(n)
    cl = _special(rng, (n, 18))
    assert _same(hd._jacobian(cl), _ref_jacobian(cl))
    wide = np.concatenate((cl, cl), axis=1)[:, 5:23]  # non-contiguous rows
    assert _same(hd._jacobian(wide), _ref_jacobian(wide))
    cl.setflags(write=False)  # the caller's array is only read
    assert _same(hd._jacobian(cl), _ref_jacobian(cl))


def _pair(rng: np.random.Generator, n: int, kind: int) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) of n samples: plain, special values, or non-contiguous / Fortran-ordered."""
    if kind == 1:
        return _special(rng, (n, 3)), _special(rng, (n, 3))
    a, b = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    if kind == 2:
        a = np.concatenate((a, a), axis=1)[:, 2:5]
        b = np.asfortranarray(b)
    return a, b


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NaN and inf among the values
@pytest.mark.parametrize("seed", range(18))
def test_fit_drift_matches_the_reference(seed):
    rng = np.random.default_rng(seed)
    n = [1, 2, 3, 9, 130, 1000][seed % 6]
    a, b = _pair(rng, n, seed % 3)
    tau = np.sort(rng.uniform(-40.0, 0.0, n))
    params = hd.HeadingParams(drift_prior_std_dps=float(rng.choice([0.5, 2.0])))
    for rate0 in (0.0, -0.0, 0.003, -0.01):
        for n_iter in (0, 1, 3, 4):
            got = hd.fit_drift(a, b, tau, rate0, params, n_iter)
            assert _same(list(got), list(_ref_fit_drift(a, b, tau, rate0, params, n_iter)))
    # a non-finite τ: not every prior-drift angle is ±0, so cos and sin must run
    for bad in (np.inf, np.nan):
        odd = tau.copy()
        odd[n // 2] = bad
        got = hd.fit_drift(a, b, odd, 0.0, params)
        assert _same(list(got), list(_ref_fit_drift(a, b, odd, 0.0, params)))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NaN and inf among the values
@pytest.mark.parametrize("seed", range(6))
def test_derotated_residual_matches_rotate_z(seed):
    rng = np.random.default_rng(seed)
    n = [1, 5, 1000][seed % 3]
    a, b = _pair(rng, n, seed % 3)
    tau = rng.uniform(-40.0, 0.0, n)
    for d0, rate in ((0.4, 0.002), (-3.0, -0.01), (0.0, 0.0)):
        ref = _ref_rotate_z(-(d0 + rate * tau), b) - a
        assert _same(hd._derotated_residual(d0, rate, tau, a, b), ref)


@pytest.mark.parametrize("seed", range(8))
def test_median_step_matches_numpy(seed):
    rng = np.random.default_rng(seed)
    n = [2, 3, 4, 5, 1000, 1001, 64, 65][seed]
    t = np.cumsum(rng.choice([0.04, 0.04, 0.0399, 0.0401, 0.0], n))  # ties and zero steps
    cases = [t, t[::-1], rng.normal(size=n)]
    if n > 2:
        with_nan = t.copy()
        with_nan[n // 2] = np.nan
        cases.append(with_nan)
    for x in cases:
        assert _same(hd._median_step(x), float(np.median(np.diff(x))))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # NaN and inf among the values
@pytest.mark.parametrize("seed", range(8))
def test_estimate_lag_matches_the_reference(seed):
    rng = np.random.default_rng(seed)
    w = _motion_window(seed, [25, 300, 500, 1000][seed % 4], invalid=[0.0, 0.1][seed % 2])
    if seed % 3 == 2:
        w = dataclasses.replace(w, a=w.a + _special(rng, w.a.shape) * 1e-3)
    for dt in (0.04, 0.0391, 0.2):
        assert _same(
            list(hd.estimate_lag(w, hd.HeadingParams(), dt)),
            list(_ref_estimate_lag(w, hd.HeadingParams(), dt)),
        )


@pytest.mark.parametrize("lag", [0.061, -0.03, 0.5, -3.0, 1e-9])
def test_delay_parts_match_one_concatenated_delay(lag):
    rng = np.random.default_rng(2)
    n = 400
    t = 10.0 + 0.04 * np.arange(n) + rng.normal(0.0, 3e-4, n)
    a, cl = _special(rng, (n, 3)), _special(rng, (n, 18))
    ref = _ref_delay(t, np.concatenate((a, cl), axis=1), lag)
    i0, i1, w = hd._delay_index(t, lag)
    assert _same(hd._delay_apply(a, i0, i1, w), ref[:, :3])
    assert _same(hd._delay_apply(cl, i0, i1, w), ref[:, 3:])
    assert _same(hd._delay_apply(cl, *hd._delay_index(t, lag)), _ref_delay(t, cl, lag))


@pytest.mark.parametrize("seed", range(10))
def test_rms_horizontal_matches_numpy(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 2000))
    b = _special(rng, (n, 3)) if seed % 2 else rng.normal(size=(n, 3))
    strided = np.concatenate((b, b), axis=1)[:, 1:4]
    for x in (b, strided, np.asfortranarray(b)):
        ref = float(np.sqrt(np.mean(np.sum(x[:, :2] ** 2, axis=1))))
        assert _same(hd._rms_horizontal(x), ref)
