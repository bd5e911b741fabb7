"""Relative-heading estimation between the IMU's reference frame I and the robot frame R.

Passon et al. 2020, §3.2: the elbow acceleration seen by the IMU (``a``, frame I) and the
robot (``b``, frame R) differ only by a rotation ``Rz(δ)`` about the vertical. The cost of
eqs. 3–4 over a window,

    c(δ) = Σ_k ‖Rz(δ) a_k − b_k‖² = C − 2 (S_c cos δ + S_s sin δ),
    S_c = Σ (a_x b_x + a_y b_y),  S_s = Σ (a_x b_y − a_y b_x),

is a sinusoid in δ, so the paper's grid search (eqs. 5–8) needs only two sums, and the
exact minimiser is ``atan2(S_s, S_c)`` (used by the ``improved`` method for sub-degree
heading). The improved method also fits a linear heading drift inside the window (the gyro
bias turns frame I at up to ~0.5 °/s, i.e. 10° across a 20 s window), predicts the drift
between updates, and reports an uncertainty so callers know when heading is poorly
observable.

Angles are radians inside, degrees in parameters.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Literal, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.ball import fits_in_ball
from estimators.jit import aot

Array: TypeAlias = NDArray[np.float64]
IndexArray: TypeAlias = NDArray[np.intp]
_BOOL = np.dtype(np.bool_)
Method = Literal["paper", "improved"]


@dataclass(frozen=True, slots=True)
class HeadingParams:
    """Schedule and search constants. Defaults are the improved method; see :meth:`paper`."""

    method: Method = "improved"
    update_interval_s: float = 1.0  # paper: 5 s
    window_s: float = 20.0  # paper: last 20 s (motion test and, for the paper, the fit)
    fit_window_s: float = 40.0  # improved: the drift-modelled fit uses this much history
    n_subwindows: int = 5  # paper: five 4 s sub-windows
    motion_diameter_m: float = 0.10  # paper: sphere of 10 cm diameter
    min_motion_subwindows: int = 3  # paper: at least three
    coarse_step_deg: float = 5.0  # eq. 6
    fine_halfwidth_deg: float = 5.0  # eqs. 7–8
    fine_step_deg: float = 1.0
    n_two_step: int = 5  # two-step update for the first five counted windows
    converge_count: int = 5  # last five estimates ...
    converge_tol_deg: float = 5.0  # ... each within 5° of the previous
    # improved method only
    min_excitation: float = 0.03  # m/s², rms horizontal elbow acceleration after low-pass
    drift_prior_std_dps: float = 0.5  # prior on the heading drift rate, °/s
    max_converge_std_deg: float = 2.5  # converged only when this certain
    effective_rate_hz: float = 1.0  # independent samples per second after a 0.5 Hz low-pass
    estimate_lag: bool = True  # estimate the robot's latency against the IMU (improved)
    estimate_sensor_errors: bool = True  # fit accelerometer bias and lever-arm error (improved)
    acc_bias_prior: float = 0.3  # m/s², prior std of each accelerometer bias component
    lever_prior: float = 0.05  # m, prior std of each component of the IMU→elbow lever error
    sensor_fit_iterations: int = 2
    converged_interval_s: float = 5.0  # improved: update cadence once converged (drift predicted)
    lag_every: int = 5  # improved: re-estimate the latency every this many updates
    max_lag_s: float = 0.15  # search range ± for that latency
    block_s: float = 4.0  # improved: residual blocks of the heteroscedastic refit; 0: off

    @classmethod
    def paper(cls) -> HeadingParams:
        """The paper's schedule exactly (§3.2.2)."""
        return cls(method="paper", update_interval_s=5.0)


@dataclass(slots=True)
class HeadingState:
    """Mutable schedule state (the ``zi`` of the heading estimator)."""

    delta: float | None = None  # rad, valid at ``t_update``
    rate: float = 0.0  # rad/s, predicted drift (improved)
    t_update: float = -math.inf
    std: float = math.inf  # rad, uncertainty at ``t_update``
    converged: bool = False
    n_counted: int = 0
    history: list[float] = field(default_factory=list)  # accepted estimates, rad
    t_converged: float | None = None
    excitation: float = 0.0  # last window's rms horizontal elbow acceleration, m/s²
    acc_bias: Array = field(default_factory=lambda: np.zeros(3))  # m/s², sensor frame
    lever_error: Array = field(default_factory=lambda: np.zeros(3))  # m, sensor frame
    lag: float = 0.0  # s, robot stamps later than the IMU's by this much (running estimate)
    lag_weight: float = 0.0  # accumulated information behind ``lag``


@dataclass(frozen=True, slots=True)
class Window:
    """One update window on the fusion grid (n samples, oldest first)."""

    t: Array  # (n,) s
    a: Array  # (n, 3) elbow acceleration from the IMU, frame I, low-passed, m/s²
    b: Array  # (n, 3) elbow acceleration from the robot, frame R, low-passed, m/s²
    p: Array  # (n, 3) elbow position from the robot, m (for the motion test)
    valid: Array  # (n,) bool
    cl: Array | None = None  # (n, 18) sensor axes x, y, z in I (9), their 2nd derivative (9)


def _all_true(v: Array) -> bool:
    """Whether the boolean mask ``v`` selects every sample (then a view replaces the copy)."""
    return v.dtype == _BOOL and bool(v.all())


def _rows(x: Array, v: Array, all_valid: bool) -> Array:
    """``x[v]``, without the copy when ``v`` is all True (same values, same C layout). The
    result may then be the caller's own buffer: it must only be read."""
    out: Array = np.ascontiguousarray(x) if all_valid else x[v]
    return out


def _rms_horizontal(b: Array) -> float:
    """``float(np.sqrt(np.mean(np.sum(b[:, :2] ** 2, axis=1))))`` of a non-empty ``b``, m/s².

    A sum over an axis of length 2 is its two terms added in order (numpy starts from −0.0
    or 0.0, which leave a square unchanged), so ``b_x² + b_y²`` is the same array at an
    eighth of the cost; the mean is the same pairwise sum divided by the same count.
    """
    h2 = b[:, 0] ** 2 + b[:, 1] ** 2
    return math.sqrt(float(np.add.reduce(h2)) / len(h2))


def wrap(x: float) -> float:
    """Angle to (−π, π]."""
    return math.atan2(math.sin(x), math.cos(x))


def sums(a: Array, b: Array) -> tuple[float, float]:
    """``(S_c, S_s)`` of the cost's sinusoid (horizontal components only)."""
    sc = float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    ss = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    return sc, ss


def cost(delta: Array, a: Array, b: Array) -> Array:
    """Eq. 4 evaluated directly for each δ in ``delta`` (rad); reference for tests."""
    c, s = np.cos(delta)[:, None], np.sin(delta)[:, None]
    rx = c * a[None, :, 0] - s * a[None, :, 1] - b[None, :, 0]
    ry = s * a[None, :, 0] + c * a[None, :, 1] - b[None, :, 1]
    rz = a[None, :, 2] - b[None, :, 2]
    return np.sum(rx * rx + ry * ry + rz * rz, axis=1)  # type: ignore[no-any-return]


def optdelta(grid: Array, sc: float, ss: float) -> float:
    """Eq. 5: the grid value minimising the cost, from the two sums."""
    return float(grid[int(np.argmax(sc * np.cos(grid) + ss * np.sin(grid)))])


def residual_std(a: Array, b: Array, delta: float, span_s: float, params: HeadingParams) -> float:
    """Standard deviation (rad) of a constant-heading estimate from its residual.

    ``Var δ ≈ Σ|e_h|² / (2 N_eff Σ|b_h|²)`` with ``N_eff`` the independent samples left
    after the 0.5 Hz low-pass (``effective_rate_hz`` per second of window).
    """
    if len(a) < 2:
        return math.inf
    c, s = math.cos(delta), math.sin(delta)
    ex = c * a[:, 0] - s * a[:, 1] - b[:, 0]
    ey = s * a[:, 0] + c * a[:, 1] - b[:, 1]
    n_eff = max(1.0, span_s * params.effective_rate_hz)
    bh = float(np.sum(b[:, 0] ** 2 + b[:, 1] ** 2))
    if bh <= 0:
        return math.inf
    return math.sqrt(float(np.sum(ex * ex + ey * ey)) / (2.0 * n_eff * bh))


def motion_subwindows(w: Window, params: HeadingParams, t_end: float) -> int:
    """Count sub-windows of the last ``window_s`` with considerable motion (§3.2.2): the
    elbow does not stay inside any sphere of ``motion_diameter_m`` diameter, i.e. its
    smallest enclosing ball is larger (:func:`estimators.ball.fits_in_ball`)."""
    return _motion_subwindows(w.t, w.p, w.valid, _all_true(w.valid), params, t_end)


def _motion_subwindows(
    t: Array, pos: Array, valid: Array, all_valid: bool, params: HeadingParams, t_end: float
) -> int:
    """:func:`motion_subwindows` on the window's arrays (``all_valid`` from :func:`_all_true`).
    A sub-window with fewer than two valid samples shows no motion."""
    sub = params.window_s / params.n_subwindows
    start = t_end - params.window_s
    idx = t.searchsorted([start + sub * i for i in range(params.n_subwindows + 1)], side="right")
    count = 0
    for lo, hi in itertools.pairwise(idx.tolist()):
        p = pos[lo:hi] if all_valid else pos[lo:hi][valid[lo:hi]]
        if len(p) >= 2 and not fits_in_ball(p, params.motion_diameter_m):
            count += 1
    return count


def _grid(center: float, half: float, step: float) -> Array:
    n = int(round(half / step))
    out: Array = center + np.radians(step) * np.arange(-n, n + 1)
    return out


def _within_deg(diff: float, tol_deg: float) -> bool:
    """``|diff| ≤ tol_deg`` for an angle difference ``diff`` (rad) of grid values: compared in
    degrees to 1e-9°, so a change of exactly 5° on the 1° grid (5.000000000000001° after the
    radian round trip) passes the paper's "at most 5°"."""
    return round(abs(math.degrees(wrap(diff))), 9) <= tol_deg


def update_paper(state: HeadingState, w: Window, params: HeadingParams, t: float) -> bool:
    """One scheduled update of §3.2.2 (eqs. 6–8). Returns whether the window counted."""
    v = w.valid
    all_valid = _all_true(v)
    a, b = _rows(w.a, v, all_valid), _rows(w.b, v, all_valid)
    state.excitation = _rms_horizontal(b) if len(b) else 0.0
    if (
        _motion_subwindows(w.t, w.p, v, all_valid, params, t) < params.min_motion_subwindows
        or len(a) == 0
    ):
        return False
    sc, ss = sums(a, b)
    if state.delta is None or not state.converged:
        # two-step update (eqs. 6–7) for the first five counted windows and every later one
        # until convergence: the paper switches to the one-step grid only once converged
        coarse = np.radians(np.arange(0.0, 360.0, params.coarse_step_deg))
        d = optdelta(coarse, sc, ss)  # eq. 6
        d = optdelta(_grid(d, params.fine_halfwidth_deg, params.fine_step_deg), sc, ss)  # eq. 7
    else:
        prev = state.delta
        d = optdelta(_grid(prev, params.fine_halfwidth_deg, params.fine_step_deg), sc, ss)  # eq. 8
    d = wrap(d)
    state.n_counted += 1
    state.history.append(d)
    state.delta, state.t_update = d, t
    state.std = math.hypot(
        residual_std(a, b, d, float(np.ptp(_rows(w.t, v, all_valid))), params),
        math.radians(params.fine_step_deg) / math.sqrt(12.0),
    )
    # checked from the first window after the five two-step ones (§3.2.2)
    if not state.converged and state.n_counted > params.n_two_step:
        last = state.history[-(params.converge_count + 1) :]
        if len(last) == params.converge_count + 1 and all(
            _within_deg(last[i + 1] - last[i], params.converge_tol_deg)
            for i in range(params.converge_count)
        ):
            state.converged, state.t_converged = True, t
    return True


def fit_drift(
    a: Array, b: Array, tau: Array, rate0: float, params: HeadingParams, n_iter: int = 4
) -> tuple[float, float, float, float]:
    """Weighted least squares of ``δ(τ) = δ0 + ρ τ`` over the window (improved method).

    Maximises ``κ Σ (S_c,k cos e_k + S_s,k sin e_k) − (ρ − ρ_prior)² / 2σ_ρ²`` with
    ``e_k = δ0 + ρ τ_k`` by Newton steps, where κ turns the cost into a log-likelihood
    (residual variance per sample, corrected for the low-pass's sample correlation).
    ``a``, ``b`` (n, 3) m/s², ``tau`` (n,) s. Returns ``(δ0, ρ, std δ0, std ρ)`` in rad and
    rad/s. (:func:`_fit_kernel` without the sensor errors and the block refit.)
    """
    out = np.empty(4)
    _fit_kernel(
        np.ascontiguousarray(a, np.float64),
        np.ascontiguousarray(b, np.float64),
        np.ascontiguousarray(tau, np.float64),
        _NO_CL,
        np.zeros(6),
        _kernel_params(params, rate0, n_iter, 0, 0.0),
        out,
    )
    return float(out[0]), float(out[1]), float(out[2]), float(out[3])


_NO_CL = np.empty((0, 18))


def _kernel_params(
    params: HeadingParams, rate0: float, n_iter: int, n_alt: int, block_s: float
) -> Array:
    """:func:`_fit_kernel`'s ``par``."""
    return np.array(
        [
            rate0,
            params.effective_rate_hz,
            math.radians(params.drift_prior_std_dps),
            float(n_iter),
            float(n_alt),
            params.acc_bias_prior,
            params.lever_prior,
            block_s,
        ]
    )


@aot("void(f8[:, ::1], f8[:, ::1], f8[::1], f8[:, ::1], f8[::1], f8[::1], f8[::1])")
def _fit_kernel(  # pragma: no cover - compiled
    a: Any, b: Any, tau: Any, cl: Any, x: Any, par: Any, out: Any
) -> None:
    """The improved update's fit: heading and drift (:func:`fit_drift`'s Newton steps),
    jointly with the accelerometer bias and the lever-arm error when ``cl`` has rows, then
    the heteroscedastic block refit when ``block_s > 0``.

    ``a``, ``b`` (n, 3) m/s², ``tau`` (n,) s. ``cl`` (n, 18) (:class:`Window`'s, delayed like
    ``a``) or (0, 18): no sensor errors; their Jacobian (the one :func:`_correction`
    applies) is made here. A sensor-frame
    accelerometer bias β appears in frame I as ``Σ_j β_j c_j(t)`` and an error Δr of the assumed
    IMU→elbow vector as ``Σ_j Δr_j c̈_j(t)``; both are linear in their unknowns once δ(t) is
    fixed, so the fit alternates the drift fit (``n_iter`` Newton steps) with a regularised
    least squares (``n_alt`` times). ``x`` (6,): [β (m/s²), Δr (m)], the warm start, updated.
    ``par``: ρ_prior (rad/s), effective rate (Hz), σ_ρ (rad/s), n_iter, n_alt, the priors' std
    of β and Δr, block_s (s). ``out`` (4,): δ0 (rad), ρ (rad/s), std δ0, std ρ.

    Block refit: the horizontal residual's mean square in blocks of ``block_s`` gives each
    block the weight ``min(1, median / block's)``, so stretches the model does not explain
    (above all the 6D filter's levelling transient while its gyro-bias estimate settles)
    count with the weight their own residual gives them, instead of inflating the
    uncertainty of the whole window; the fit then runs again on the weighted samples
    (the sensor errors from the first fit as warm start). Sums are the kernel's running
    sums (not numpy's pairwise ones)."""
    n = a.shape[0]
    rate0, eff_rate, sig_rho = par[0], par[1], par[2]
    n_iter, n_alt, block_s = int(par[3]), int(par[4]), par[7]
    has_jac = cl.shape[0] == n and n > 0
    jac = np.empty((3 * n if has_jac else 0, 6))  # as in _correction
    if has_jac:
        for k in range(n):
            for i in range(3):
                for j in range(6):
                    v = cl[k, 3 * j + i]
                    jac[3 * k + i, j] = -v if j < 3 else v
    if not has_jac:
        n_alt = 1
    prior = np.empty(6)
    for j in range(3):
        prior[j] = 1.0 / (par[5] * par[5])
        prior[3 + j] = 1.0 / (par[6] * par[6])
    span = tau[n - 1] - tau[0] if n > 1 else 0.0
    n_eff = max(1.0, span * eff_rate)
    inv_prior = 1.0 / (sig_rho * sig_rho)
    sw = np.ones(n)  # square roots of the samples' weights
    ac = np.empty((n, 3))  # a corrected for the sensor errors, weighted
    sc = np.empty(n)  # per-sample S_c,k and S_s,k
    ss = np.empty(n)
    jx = np.empty((n, 3))
    mat = np.empty((6, 6))
    rhs = np.empty(6)
    d = r = sd = sr = 0.0
    jtj = np.zeros((6, 6))
    # cos and sin of the prior drift's angles ρ_prior τ (every fit's start), and of the
    # current angles d + ρ τ: moved by angle addition, with a series for small moves
    cos0, sin0 = np.ones(n), np.zeros(n)
    if rate0 != 0.0:
        for k in range(n):
            cos0[k], sin0[k] = math.cos(rate0 * tau[k]), math.sin(rate0 * tau[k])
    cs, sn = np.empty(n), np.empty(n)
    n_pass = 2 if block_s > 0.0 else 1
    for pas in range(n_pass):
        if pas == 1:
            # block weights from the unweighted residual at the first fit
            nb = int((tau[n - 1] - tau[0]) // block_s) + 1
            if nb < 3:
                break
            cnt = np.zeros(nb)
            msq = np.zeros(nb)
            blk = np.empty(n, np.int64)
            for k in range(n):
                c, s = cs[k], -sn[k]  # of −(d + r τ): the last fit's angles
                ex = c * b[k, 0] - s * b[k, 1] - a[k, 0]
                ey = s * b[k, 0] + c * b[k, 1] - a[k, 1]
                if has_jac:
                    for i in range(2):
                        v = 0.0
                        for j in range(6):
                            v += jac[3 * k + i, j] * x[j]
                        if i == 0:
                            ex -= v
                        else:
                            ey -= v
                ib = int((tau[k] - tau[0]) // block_s)
                blk[k] = ib
                cnt[ib] += 1.0
                msq[ib] += ex * ex + ey * ey
            m = 0
            for ib in range(nb):
                if cnt[ib] > 0:
                    msq[ib] /= cnt[ib]
                    m += 1
            filled = np.empty(m)
            m = 0
            for ib in range(nb):
                if cnt[ib] > 0:
                    filled[m] = msq[ib]
                    m += 1
            med = np.median(filled)
            if not med > 0.0:
                break
            any_weighted = False
            wb = np.empty(nb)
            for ib in range(nb):
                wb[ib] = min(1.0, med / max(msq[ib], 1e-300))
                if cnt[ib] > 0 and wb[ib] != 1.0:
                    any_weighted = True
            if not any_weighted:
                break
            for k in range(n):
                sw[k] = math.sqrt(wb[blk[k]])
        if has_jac:
            # jtj of the weighted Jacobian, with the weighted residual's information
            for i in range(6):
                for j in range(6):
                    mat[i, j] = 0.0
            for k in range(n):
                w2 = sw[k] * sw[k]
                for q in range(3):
                    row = 3 * k + q
                    for i in range(6):
                        ji = jac[row, i] * w2
                        for j in range(i, 6):
                            mat[i, j] += ji * jac[row, j]
            jtj[:, :] = mat
        for _alt in range(n_alt):
            for k in range(n):
                for q in range(3):
                    v = 0.0
                    if has_jac:
                        for j in range(6):
                            v += jac[3 * k + q, j] * x[j]
                    jx[k, q] = sw[k] * v
                    ac[k, q] = sw[k] * a[k, q] + jx[k, q]
            # drift fit on (ac, sw b)
            e2 = 0.0
            for k in range(n):
                w = sw[k]
                ax, ay, bx, by = ac[k, 0], ac[k, 1], w * b[k, 0], w * b[k, 1]
                sc[k] = ax * bx + ay * by
                ss[k] = ax * by - ay * bx
                e2 += ax * ax + ay * ay + bx * bx + by * by
            s0 = s1 = 0.0
            for k in range(n):
                s0 += sc[k] * cos0[k] + ss[k] * sin0[k]
                s1 += ss[k] * cos0[k] - sc[k] * sin0[k]
            d, r = math.atan2(s1, s0), rate0
            cd, sdd = math.cos(d), math.sin(d)
            for k in range(n):  # the start's angles turned by d
                cs[k] = cos0[k] * cd - sin0[k] * sdd
                sn[k] = sin0[k] * cd + cos0[k] * sdd
            dc, rc = d, r  # the angles cs, sn hold: dc + rc τ
            h00 = h01 = h11 = det = 0.0
            for it in range(n_iter + 1):
                if it > 0:
                    # move the angles by ε_k = Δd + Δρ τ_k to d + r τ (also after the last
                    # step: the residual uses them)
                    dd, dr = d - dc, r - rc
                    if max(abs(dd + dr * tau[0]), abs(dd + dr * tau[n - 1])) <= 0.05:
                        # Taylor series to ε⁹ / ε¹⁰: error below 1e-21 for |ε| ≤ 0.05
                        for k in range(n):
                            eps = dd + dr * tau[k]
                            q2 = eps * eps
                            se = eps * (
                                1.0
                                - q2
                                / 6.0
                                * (1.0 - q2 / 20.0 * (1.0 - q2 / 42.0 * (1.0 - q2 / 72.0)))
                            )
                            ce = 1.0 - q2 / 2.0 * (
                                1.0
                                - q2
                                / 12.0
                                * (1.0 - q2 / 30.0 * (1.0 - q2 / 56.0 * (1.0 - q2 / 90.0)))
                            )
                            c, s = cs[k], sn[k]
                            cs[k] = c * ce - s * se
                            sn[k] = s * ce + c * se
                    else:
                        for k in range(n):
                            e = d + r * tau[k]
                            cs[k], sn[k] = math.cos(e), math.sin(e)
                    dc, rc = d, r
                if it == n_iter:
                    break
                sf = sg = sft = sgt = sftt = 0.0
                for k in range(n):
                    c, s = cs[k], sn[k]
                    f = sc[k] * c + ss[k] * s
                    g = ss[k] * c - sc[k] * s
                    sf += f
                    sg += g
                    sft += f * tau[k]
                    sgt += g * tau[k]
                    sftt += f * tau[k] * tau[k]
                resid = max(e2 - 2.0 * sf, 1e-12)
                kappa = n_eff / n / (resid / (2.0 * n))
                g0 = kappa * sg
                g1 = kappa * sgt - (r - rate0) * inv_prior
                h00, h01 = kappa * sf, kappa * sft
                h11 = kappa * sftt + inv_prior
                det = h00 * h11 - h01 * h01
                if not (math.isfinite(det) and det > 0.0):
                    break
                d += (h11 * g0 - h01 * g1) / det
                r += (h00 * g1 - h01 * g0) / det
            if det != 0.0 and math.isfinite(det):
                sd, sr = math.sqrt(max(h11 / det, 0.0)), math.sqrt(max(h00 / det, 0.0))
            else:
                sd, sr = math.inf, sig_rho
            d = math.atan2(math.sin(d), math.cos(d))
            if not has_jac:
                break
            # sensor errors: the residual in frame I, Rz(−δ_k) b_k − a_k = jac_k x + noise
            rr = 0.0
            for i in range(6):
                rhs[i] = 0.0
            for k in range(n):
                c, s = cs[k], -sn[k]  # of −(d + r τ)
                w = sw[k]
                bx, by = w * b[k, 0], w * b[k, 1]
                y0 = c * bx - s * by - w * a[k, 0]
                y1 = s * bx + c * by - w * a[k, 1]
                y2 = w * b[k, 2] - w * a[k, 2]
                for q in range(3):
                    y = y0 if q == 0 else (y1 if q == 1 else y2)
                    u = y - jx[k, q]
                    rr += u * u
                    wj = w  # the weighted Jacobian's row: jac * sw
                    for i in range(6):
                        rhs[i] += wj * jac[3 * k + q, i] * y
            var = max(rr / (3 * n), 1e-8) * n / n_eff
            # Cholesky of jtj / var + prior (symmetric positive definite), then solve
            for i in range(6):
                for j in range(i, 6):
                    mat[i, j] = jtj[i, j] / var + (prior[i] if i == j else 0.0)
                rhs[i] /= var
            for j in range(6):
                v = mat[j, j]
                for q in range(j):
                    v -= mat[q, j] * mat[q, j]
                mat[j, j] = math.sqrt(v)
                for i in range(j + 1, 6):
                    v = mat[j, i]
                    for q in range(j):
                        v -= mat[q, j] * mat[q, i]
                    mat[j, i] = v / mat[j, j]
            for i in range(6):  # Uᵀ z = rhs
                v = rhs[i]
                for q in range(i):
                    v -= mat[q, i] * rhs[q]
                rhs[i] = v / mat[i, i]
            for i in range(5, -1, -1):  # U x = z
                v = rhs[i]
                for q in range(i + 1, 6):
                    v -= mat[i, q] * x[q]
                x[i] = v / mat[i, i]
    out[0], out[1], out[2], out[3] = d, r, sd, sr


def estimate_lag(w: Window, params: HeadingParams, dt: float) -> tuple[float, float]:
    """Latency of the robot stream against the IMU, from heading-invariant features.

    A time shift between the two accelerations looks like a heading rotation on circular
    paths, so it is found from what a heading offset cannot change: the vertical component
    and the horizontal magnitude. Returns ``(lag s, curvature weight)``; weight 0 if the
    minimum is not clear.
    """
    v = w.valid
    all_valid = _all_true(v)
    t, a, b = _rows(w.t, v, all_valid), _rows(w.a, v, all_valid), _rows(w.b, v, all_valid)
    return _estimate_lag(t, a, b, params, dt)


def _estimate_lag(
    t: Array, a: Array, b: Array, params: HeadingParams, dt: float
) -> tuple[float, float]:
    """:func:`estimate_lag` on the valid samples."""
    if len(t) < 20:
        return 0.0, 0.0
    lags = np.arange(-params.max_lag_s, params.max_lag_s + 1e-9, dt / 2.0)
    ah = np.hypot(a[:, 0], a[:, 1])
    bh = np.hypot(b[:, 0], b[:, 1])
    inner = (t >= t[0] + params.max_lag_s) & (t <= t[-1] - params.max_lag_s)
    if np.count_nonzero(inner) < 10:
        return 0.0, 0.0
    ti = t[inner]
    # a at t − lag paired with b at t (robot late by lag), every lag in one call
    s = (ti[None, :] - lags[:, None]).ravel()
    dz = np.interp(s, t, a[:, 2]).reshape(len(lags), -1)
    dh = np.interp(s, t, ah).reshape(len(lags), -1)
    # Σ (dz² + dh²) per lag, the same operations in place (no temporaries of L × m)
    np.subtract(dz, b[:, 2][inner], out=dz)  # the values of b[inner, 2], gathered cheaper
    np.subtract(dh, bh[inner], out=dh)
    np.multiply(dz, dz, out=dz)
    np.multiply(dh, dh, out=dh)
    costs = np.add.reduce(np.add(dz, dh, out=dz), axis=1)
    k = int(np.argmin(costs))
    if k == 0 or k == len(lags) - 1:
        return 0.0, 0.0
    c0, c1, c2 = costs[k - 1], costs[k], costs[k + 1]
    curv = c0 - 2 * c1 + c2
    if curv <= 0:
        return 0.0, 0.0
    step = lags[1] - lags[0]
    return float(lags[k] + 0.5 * step * (c0 - c2) / curv), float(curv / max(c1, 1e-12))


# cl's columns (x, y, z in I of the three sensor axes, then of their 2nd derivatives) in the
_JAC_SIGN = np.array([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])


def _correction(cl: Array, x: Array) -> Array:
    """(n, 3): ``jac · x``, how the accelerometer bias and the lever error ``x = [β, Δr]``
    enter the elbow acceleration (``a_true ≈ a + jac · x``), sample by sample, with the fit
    kernel's Jacobian: ``jac[3k + i, j] = ∓cl[k, 3j + i]`` (− for β), ``cl`` (n, 18)."""
    # contiguous, so the products are summed as one (3n, 6) · (6,) product would sum them
    jac = np.ascontiguousarray(cl.reshape(-1, 6, 3).transpose(0, 2, 1))
    out: Array = jac @ (x * _JAC_SIGN)
    return out


def _delay_index(t: Array, lag: float) -> tuple[IndexArray, IndexArray, Array]:
    """Linear interpolation at ``t − lag`` (held at the ends) for :func:`_delay_apply`:
    ``(i0, i1, w)``, ``w`` as a column (n, 1)."""
    n = len(t)
    # the methods, not np.clip / np.searchsorted: the same calls without a wrapper's cost
    s = (t - lag).clip(t[0], t[-1])
    i1 = t.searchsorted(s, side="left")
    # np.clip(i1, 1, n - 1) as two plain ufuncs (np.clip's wrapping costs more than both)
    np.minimum(np.maximum(i1, 1, out=i1), n - 1, out=i1)
    i0 = i1 - 1
    t0 = t.take(i0)
    w = ((s - t0) / (t.take(i1) - t0))[:, None]
    return i0, i1, w


def _delay_apply(x: Array, i0: IndexArray, i1: IndexArray, w: Array) -> Array:
    """``x`` (n, c) delayed: ``x[i0] + w * (x[i1] - x[i0])`` with the same operations in the
    same operand order, in two buffers instead of five (fresh arrays of this size are slow
    to allocate here)."""
    out: Array = x.take(i0, axis=0)
    dx = x.take(i1, axis=0)
    np.subtract(dx, out, out=dx)
    np.multiply(w, dx, out=dx)
    np.add(out, dx, out=out)
    return out


def _median_step(t: Array) -> float:
    """``float(np.median(np.diff(t)))`` (s) for ``len(t) > 1`` (:func:`_median`)."""
    return _median(np.diff(t))


def _median(d: Array) -> float:
    """``float(np.median(d))`` of a non-empty 1-D ``d``, without ``np.median``'s ~30 µs of
    wrapping: the same order statistics from one partition, the middle two averaged as
    ``np.mean`` does (their sum over 2), and NaN if a value is NaN (NaN sorts last)."""
    n = len(d)
    h = n // 2
    part = np.partition(d, [h - 1, h, n - 1] if n % 2 == 0 else [h, n - 1])
    if math.isnan(part[-1]):
        return float(part[-1])
    if n % 2:
        return float(part[h])
    return float(np.add.reduce(part[h - 1 : h + 1]) / 2)


def update_improved(
    state: HeadingState, w: Window, params: HeadingParams, t: float, lag_s: float
) -> bool:
    """One update of the improved method. ``lag_s`` is the low-pass's group delay.

    The window's data describe the heading ``lag_s`` earlier than their time stamps, so the
    estimate is carried forward by the fitted drift. Returns whether the window counted.
    """
    v = w.valid
    all_valid = _all_true(v)
    # views instead of copies when every sample is valid: nothing below writes into them
    a, b, ts = _rows(w.a, v, all_valid), _rows(w.b, v, all_valid), _rows(w.t, v, all_valid)
    tau = ts - t
    # the last ``window_s`` of the (time-ordered) window: a suffix
    k = int(tau.searchsorted(-params.window_s, side="right"))
    excitation = _rms_horizontal(b[k:]) if k < len(b) else 0.0
    state.excitation = excitation
    if (
        len(a) < 2
        or excitation < params.min_excitation
        or _motion_subwindows(w.t, w.p, v, all_valid, params, t) < params.min_motion_subwindows
    ):
        return False
    if params.estimate_lag and (state.n_counted % params.lag_every == 0 or not state.converged):
        dt = _median_step(w.t) if len(w.t) > 1 else 0.04
        k = int(np.searchsorted(w.t, t - params.window_s, side="right"))
        a_tail = w.a[k:]
        if params.estimate_sensor_errors and w.cl is not None:
            # the latency is read from the elbow acceleration as corrected so far: an
            # uncorrected lever error distorts the features and shows up as a false lag
            x = np.concatenate((state.acc_bias, state.lever_error))
            a_tail = a_tail + _correction(w.cl[k:], x)
        v_tail = v[k:]
        tail_valid = all_valid or _all_true(v_tail)
        lag, weight = _estimate_lag(
            _rows(w.t[k:], v_tail, tail_valid),
            _rows(a_tail, v_tail, tail_valid),
            _rows(w.b[k:], v_tail, tail_valid),
            params,
            dt,
        )
    else:
        lag, weight = 0.0, 0.0
    delay: tuple[IndexArray, IndexArray, Array] | None = None
    if params.estimate_lag:
        if weight > 0:
            # the latency is constant: pool the windows' estimates by their sharpness
            state.lag = (state.lag * state.lag_weight + lag * weight) / (state.lag_weight + weight)
            state.lag_weight = min(state.lag_weight + weight, 50.0 * weight)
        if state.lag != 0.0:
            # a and cl delayed apart (the same indices and weights as one concatenated array)
            delay = _delay_index(ts, state.lag)
            a = _delay_apply(a, *delay)
    rate0 = state.rate if state.converged else 0.0
    cl = None
    if params.estimate_sensor_errors and w.cl is not None:
        cl = _rows(w.cl, v, all_valid)
        if delay is not None:
            cl = _delay_apply(cl, *delay)
    # the sensor errors need cl not all zero (as np.any(cl); a nonzero first sample answers)
    if cl is None or not cl.any():
        cl = None
    x = np.concatenate((state.acc_bias, state.lever_error))
    n_alt = 1 if state.converged else params.sensor_fit_iterations  # warm start once converged
    par = _kernel_params(params, rate0, 4 if cl is None else 3, n_alt, params.block_s)
    out = np.empty(4)
    _fit_kernel(a, b, tau, _NO_CL if cl is None else cl, x, par, out)
    if cl is not None:
        state.acc_bias, state.lever_error = x[:3].copy(), x[3:].copy()
    d0, rate, sd = float(out[0]), float(out[1]), float(out[2])
    d = wrap(d0 + rate * lag_s)
    prev = predict(state, t)
    state.n_counted += 1
    state.history.append(d)
    state.delta, state.rate, state.t_update, state.std = d, rate, t, sd
    if not state.converged:
        k = 3
        tol = math.radians(params.max_converge_std_deg)
        recent = state.history[-k:]
        if (
            len(recent) == k
            and prev is not None
            and sd <= tol
            and all(abs(wrap(recent[i + 1] - recent[i])) <= 2 * tol for i in range(k - 1))
        ):
            state.converged, state.t_converged = True, t
    return True


def predict(state: HeadingState, t: float) -> float | None:
    """Heading offset at time ``t`` (rad), with the drift prediction; None if never estimated."""
    if state.delta is None:
        return None
    return state.delta + state.rate * (t - state.t_update)
