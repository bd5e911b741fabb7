"""The wearable filter's per-step arithmetic, compiled by numba (the one implementation).

:mod:`.dh` (pose, sensors), :mod:`.filters` (EKF step) and :mod:`.tracker` (outputs) call these
functions; they hold no second copy of them. Loops over 3-vectors and the 5 joints are written
out because a numpy call on a 3-vector costs ~1 µs of interpreter overhead and a step made of
~100 of them cost ~1.3 ms; compiled, a whole EKF step is a few µs (docs/benchmarks.md).
``NUMBA_DISABLE_JIT=1`` runs the same code interpreted (slow, same numbers to rounding).

Conventions as :mod:`.dh`: S frame, joint vector ``θ = [θ0, θ1, θ2, θ4, θ5]`` (rad), Jacobian
rows ``[∂/∂θ̈ (5), ∂/∂θ̇ (5), ∂/∂θ (5)]`` stored as (15, 3) (row = the derivative of the
3-vector with respect to one variable). Equation numbers are the paper's (Alizadegan &
Behzadipour 2016).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimators.jit import aot, jit, jit_inline

G = 9.81
HALF_PI = 0.5 * math.pi
# R_S0 (frame 0's axes in S) and frame 3 in U's axes: as in dh.py
R_S0 = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])
R_U3 = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

# sensor slots of the (6, 3) value and (6, 15, 3) Jacobian arrays
GYR_U, ACC_U, GYR_F, ACC_F, ELBOW, WRIST = range(6)


@jit_inline
def cross(a: Any, b: Any, out: Any) -> None:
    """``out = a × b`` for 3-vectors (out may not alias a or b)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@jit_inline
def mm_into(a: Any, b: Any, out: Any) -> None:
    """``out += a @ b`` for small matrices, written out (BLAS's call overhead dominates at
    3×3); ``out`` zeroed by the caller gives the product."""
    n, k, m = a.shape[0], a.shape[1], b.shape[1]
    for i in range(n):
        for t in range(k):
            ait = a[i, t]
            for j in range(m):
                out[i, j] += ait * b[t, j]


@jit_inline
def mm(a: Any, b: Any) -> Any:
    """``a @ b`` for small matrices (:func:`mm_into` of a new zeroed array)."""
    out = np.zeros((a.shape[0], b.shape[1]))
    mm_into(a, b, out)
    return out


@jit_inline
def mv_into(a: Any, v: Any, out: Any) -> None:
    """``out += a @ v`` for a small matrix and vector; ``out`` zeroed by the caller gives the
    product."""
    for i in range(a.shape[0]):
        for t in range(a.shape[1]):
            out[i] += a[i, t] * v[t]


@jit_inline
def mv(a: Any, v: Any) -> Any:
    """``a @ v`` for a small matrix and vector."""
    out = np.zeros(a.shape[0])
    mv_into(a, v, out)
    return out


@aot("Tuple((f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[::1], f8[::1]))(f8[::1], f8, f8)")
def pose(theta: Any, lu: float, lf: float) -> Any:
    """The DH chain (eqs. 10, 11; dh.dh_table's rows) for ``θ`` (5,) rad.

    Returns (axes (5,3), R_SU (3,3), R_SF (3,3), elbow (3,), wrist (3,)).
    """
    # rows (γ, λ, β) of dh.dh_table; δ = 0 everywhere (the work arrays are views of a few
    # blocks, and the rotation's products alternate between two of them: this runs twice per
    # filter step, where each allocation costs about as much as a 3×3 product)
    table = np.zeros((3, 7))
    gam, lam, beta = table[0], table[1], table[2]
    gam[0], gam[1], gam[2], gam[3] = theta[0], theta[1] + HALF_PI, theta[2], HALF_PI
    gam[4], gam[5], gam[6] = theta[3], theta[4], 0.0
    lam[3], lam[6] = -lu, -lf
    beta[0], beta[1], beta[3], beta[4] = HALF_PI, -HALF_PI, HALF_PI, -HALF_PI
    mats = np.empty((5, 3, 3))
    rot, nxt, step, r3, r6 = mats[0], mats[1], mats[2], mats[3], mats[4]
    rot[:] = R_S0
    vecs = np.zeros((3, 3))
    pos, elbow, wrist = vecs[0], vecs[1], vecs[2]
    axes = np.empty((5, 3))
    j = 0
    for i in range(7):
        if i != 3 and i != 6:
            for k in range(3):
                axes[j, k] = rot[k, 2]
            j += 1
        if lam[i] != 0.0:
            for k in range(3):
                pos[k] += lam[i] * rot[k, 2]
        cg, sg = math.cos(gam[i]), math.sin(gam[i])
        cb, sb = math.cos(beta[i]), math.sin(beta[i])
        # Rz(γ)·Rx(β)
        step[0, 0], step[0, 1], step[0, 2] = cg, -sg * cb, sg * sb
        step[1, 0], step[1, 1], step[1, 2] = sg, cg * cb, -cg * sb
        step[2, 0], step[2, 1], step[2, 2] = 0.0, sb, cb
        nxt[:] = 0.0  # rot @ step: each element summed from 0.0 as mm does
        mm_into(rot, step, nxt)
        rot, nxt = nxt, rot
        if i == 2:
            r3[:] = rot
        elif i == 3:
            elbow[:] = pos
        elif i == 5:
            r6[:] = rot
        elif i == 6:
            wrist[:] = pos
    return axes, mm(r3, R_U3.T), r6, elbow, wrist


@jit_inline
def _acc_at(al: Any, om: Any, r: Any, out: Any) -> None:
    """``out += α × r + ω × (ω × r)`` (eq. 14 with a fixed origin term)."""
    a0, a1, a2 = _cx(al[0], al[1], al[2], r[0], r[1], r[2])
    out[0] += a0
    out[1] += a1
    out[2] += a2
    c0, c1, c2 = _cx(om[0], om[1], om[2], r[0], r[1], r[2])
    e0, e1, e2 = _cx(om[0], om[1], om[2], c0, c1, c2)
    out[0] += e0
    out[1] += e1
    out[2] += e2


@jit_inline
def _cx(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> Any:
    """``a × b`` on scalars (no array: the hot loops below allocate nothing)."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@jit_inline
def _dacc(dal: Any, dom: Any, al: Any, om: Any, r: Any, dr: Any, out: Any) -> None:
    """``out += ∂(α × r + ω × (ω × r))`` for (15, 3) ∂α, ∂ω and (5, 3) ∂r (θ rows only):
    ``∂α × r + ∂ω × (ω × r) + ω × (∂ω × r)``, plus ``α × ∂r + ω × (ω × ∂r)``."""
    r0, r1, r2 = r[0], r[1], r[2]
    o0, o1, o2 = om[0], om[1], om[2]
    q0, q1, q2 = _cx(o0, o1, o2, r0, r1, r2)
    for i in range(15):
        a0, a1, a2 = _cx(dal[i, 0], dal[i, 1], dal[i, 2], r0, r1, r2)
        b0, b1, b2 = _cx(dom[i, 0], dom[i, 1], dom[i, 2], q0, q1, q2)
        c0, c1, c2 = _cx(dom[i, 0], dom[i, 1], dom[i, 2], r0, r1, r2)
        e0, e1, e2 = _cx(o0, o1, o2, c0, c1, c2)
        out[i, 0] += a0 + b0 + e0
        out[i, 1] += a1 + b1 + e1
        out[i, 2] += a2 + b2 + e2
    for m in range(5):
        a0, a1, a2 = _cx(al[0], al[1], al[2], dr[m, 0], dr[m, 1], dr[m, 2])
        c0, c1, c2 = _cx(o0, o1, o2, dr[m, 0], dr[m, 1], dr[m, 2])
        e0, e1, e2 = _cx(o0, o1, o2, c0, c1, c2)
        out[10 + m, 0] += a0 + e0
        out[10 + m, 1] += a1 + e1
        out[10 + m, 2] += a2 + e2


@jit
def sensors(
    theta: Any,
    dtheta: Any,
    ddtheta: Any,
    lu: float,
    lf: float,
    r_u: Any,
    R_UI: Any,
    r_f: Any,
    R_FI: Any,
    body: bool,
    jacobian: bool,
) -> Any:
    """Predicted readings (eqs. 12–18, 11) and their analytic Jacobians (see dh.sensors).

    Returns ``vals`` (6, 3): gyro u, specific force u (IMU frames), gyro f, specific force f,
    elbow, wrist (S); ``jac`` (6, 15, 3) (zeros unless ``jacobian``).
    """
    a, R_SU, R_SF, elbow, wrist = pose(theta, lu, lf)
    # the work arrays as views of two zeroed blocks (one allocation each, not sixteen)
    w5x3 = np.zeros((3, 5, 3))
    w, alpha, wxa = w5x3[0], w5x3[1], w5x3[2]
    v3 = np.zeros((9, 3))
    acc_w, acc_al, acc_e, v_au, v_af, d_u, d_f = v3[0], v3[1], v3[2], v3[3], v3[4], v3[5], v3[6]
    m3 = np.zeros((2, 3, 3))
    R_SIu, R_SIf = m3[0], m3[1]
    for k in range(5):  # eqs. 12, 13 in S
        if k > 0:
            cross(w[k - 1], a[k], wxa[k])
        for c in range(3):
            acc_w[c] += a[k, c] * dtheta[k]
            acc_al[c] += a[k, c] * ddtheta[k] + wxa[k, c] * dtheta[k]
        w[k] = acc_w
        alpha[k] = acc_al
    w_u, w_f, al_u, al_f = w[2], w[4], alpha[2], alpha[4]
    mv_into(R_SU, r_u, d_u)
    mv_into(R_SF, r_f, d_f)
    d_w = v3[7]
    for c in range(3):
        d_w[c] = wrist[c] - elbow[c]
    mm_into(R_SU, R_UI, R_SIu)
    mm_into(R_SF, R_FI, R_SIf)
    _acc_at(al_u, w_u, elbow, acc_e)
    if body:
        _acc_at(al_u, w_u, d_u, v_au)
        v_af += acc_e
        _acc_at(al_f, w_f, d_f, v_af)
    v_au[2] += G  # eqs. 17, 18: specific force = gravity + body acceleration
    v_af[2] += G
    vals = np.zeros((6, 3))
    mv_into(R_SIu.T, w_u, vals[GYR_U])
    mv_into(R_SIu.T, v_au, vals[ACC_U])
    mv_into(R_SIf.T, w_f, vals[GYR_F])
    mv_into(R_SIf.T, v_af, vals[ACC_F])
    vals[ELBOW] = elbow
    vals[WRIST] = wrist
    jac = np.zeros((6, 15, 3))
    if not jacobian:
        return vals, jac
    # ∂/∂θ_m: everything beyond joint m turns about a_m; joints 3, 4 do not move the upper arm
    # (the work arrays are views of two zeroed blocks: one allocation each, not twenty)
    w15 = np.zeros((8, 15, 3))
    dw_u, dw_f, dal_u, dal_f = w15[0], w15[1], w15[2], w15[3]
    g_u, g_f, a_u, a_f = w15[4], w15[5], w15[6], w15[7]
    w5 = np.zeros((8, 5, 3))
    de, ddu, ddf, dwr = w5[0], w5[1], w5[2], w5[3]
    ax_wu, ax_wf, ax_vu, ax_vf = w5[4], w5[5], w5[6], w5[7]
    for m in range(5):
        a0, a1, a2 = a[m, 0], a[m, 1], a[m, 2]
        up = m <= 2
        for seg in range(2):
            if seg == 0 and not up:
                continue
            om = w_u if seg == 0 else w_f
            al = al_u if seg == 0 else al_f
            dw = dw_u if seg == 0 else dw_f
            dal = dal_u if seg == 0 else dal_f
            n0, n1, n2 = om[0] - w[m, 0], om[1] - w[m, 1], om[2] - w[m, 2]  # Δω
            c0, c1, c2 = _cx(a0, a1, a2, n0, n1, n2)  # a × Δω
            e0, e1, e2 = _cx(w[m, 0], w[m, 1], w[m, 2], c0, c1, c2)  # ω_m × (a × Δω)
            f0, f1, f2 = _cx(w[m, 0], w[m, 1], w[m, 2], n0, n1, n2)  # ω_m × Δω
            g0, g1, g2 = _cx(
                a0,
                a1,
                a2,
                al[0] - alpha[m, 0] - f0,
                al[1] - alpha[m, 1] - f1,
                al[2] - alpha[m, 2] - f2,
            )
            dw[5 + m, 0], dw[5 + m, 1], dw[5 + m, 2] = a0, a1, a2
            dw[10 + m, 0], dw[10 + m, 1], dw[10 + m, 2] = c0, c1, c2
            dal[m, 0], dal[m, 1], dal[m, 2] = a0, a1, a2
            dal[5 + m, 0] = wxa[m, 0] + c0
            dal[5 + m, 1] = wxa[m, 1] + c1
            dal[5 + m, 2] = wxa[m, 2] + c2
            dal[10 + m, 0], dal[10 + m, 1], dal[10 + m, 2] = g0 + e0, g1 + e1, g2 + e2
        for dst_, v in ((ddf, d_f), (dwr, d_w), (ax_wf, w_f), (ax_vf, v_af)):
            dst_[m, 0], dst_[m, 1], dst_[m, 2] = _cx(a0, a1, a2, v[0], v[1], v[2])
        if up:
            for dst_, v in ((de, elbow), (ddu, d_u), (ax_wu, w_u), (ax_vu, v_au)):
                dst_[m, 0], dst_[m, 1], dst_[m, 2] = _cx(a0, a1, a2, v[0], v[1], v[2])
    g_u[:] = dw_u
    g_f[:] = dw_f
    if body:
        _dacc(dal_u, dw_u, al_u, w_u, elbow, de, a_f)  # the elbow's acceleration
        _dacc(dal_u, dw_u, al_u, w_u, d_u, ddu, a_u)
        _dacc(dal_f, dw_f, al_f, w_f, d_f, ddf, a_f)
    for m in range(5):  # a sensor's axes turn too: ∂(R_SIᵀ v)/∂θ_m = R_SIᵀ (∂v − a_m × v)
        g_u[10 + m] -= ax_wu[m]
        g_f[10 + m] -= ax_wf[m]
        a_u[10 + m] -= ax_vu[m]
        a_f[10 + m] -= ax_vf[m]
        jac[ELBOW, 10 + m] = de[m]
        jac[WRIST, 10 + m] = de[m] + dwr[m]
    mm_into(g_u, R_SIu, jac[GYR_U])
    mm_into(a_u, R_SIu, jac[ACC_U])
    mm_into(g_f, R_SIf, jac[GYR_F])
    mm_into(a_f, R_SIf, jac[ACC_F])
    return vals, jac


@jit
def outputs(x: Any, P: Any, theta_idx: Any, lu: float, lf: float, vertical_rad: float) -> Any:
    """A row's numbers: angles θ (5,) rad, their σ (5,) rad, elbow, wrist (3,) m, and the σ of
    the whole arm's turn about the vertical from P (rad).

    Each shoulder angle's σ adds its share of a pure turn about the vertical of size
    ``vertical_rad`` (the drift bound): Σ a_j δθ_j = ẑ δψ over the shoulder's joints.
    """
    block = np.zeros((3, 5))
    th, var, g = block[0], block[1], block[2]  # g: δψ = ẑ·Σ a_j δθ_j over the shoulder
    for j in range(5):
        k = theta_idx[2, j]
        if k >= 0:
            th[j] = x[k]
            var[j] = P[k, k]
    axes, _, _, elbow, wrist = pose(th, lu, lf)
    for j in range(3):
        if theta_idx[2, j] >= 0:
            g[j] = axes[j, 2]
    vert = 0.0
    for i in range(3):
        for j in range(3):
            ki, kj = theta_idx[2, i], theta_idx[2, j]
            if ki >= 0 and kj >= 0:
                vert += g[i] * P[ki, kj] * g[j]
    vert = math.sqrt(max(vert, 0.0))
    if theta_idx[2, 0] >= 0 and theta_idx[2, 1] >= 0 and theta_idx[2, 2] >= 0:
        a3 = axes[:3].T.copy()
        if abs(np.linalg.det(a3)) > 1e-6:  # away from the gimbal lock at 90° abduction
            turn = np.linalg.solve(a3, np.array([0.0, 0.0, 1.0]))
            for j in range(3):
                var[j] += (vertical_rad * turn[j]) ** 2
    return th, np.sqrt(var), elbow, wrist, vert


@jit
def fq(
    ts: float,
    n: int,
    order: int,
    i_dd: Any,
    i_d: Any,
    i_th: Any,
    q_rate: Any,
    gm: Any,
    tau: float,
    gm_var: float,
) -> Any:
    """``F`` (eq. 3) and the diagonal of ``Q`` (eq. 4) for a step of ``ts`` s.

    ``q_rate`` (n,): variance per second of each state's increment (the top derivative of each
    joint, the gyro-bias walk); ``gm``: GM-1 states (model B's body accelerations) with
    correlation time ``tau`` s and steady variance ``gm_var``.
    """
    F = np.eye(n)
    for c in range(i_th.shape[0]):
        if order == 2:
            F[i_d[c], i_dd[c]] = ts
            F[i_th[c], i_dd[c]] = 0.5 * ts * ts
        if order >= 1:
            F[i_th[c], i_d[c]] = ts
    q = q_rate * ts
    phi = math.exp(-ts / tau)
    for k in gm:
        F[k, k] = phi
        q[k] = gm_var * (1.0 - phi * phi)
    return F, q


@jit
def predict(
    x: Any,
    P: Any,
    ts: float,
    order: int,
    i_dd: Any,
    i_d: Any,
    i_th: Any,
    q_rate: Any,
    gm: Any,
    tau: float,
    gm_var: float,
) -> Any:
    """``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q`` (eqs. 3, 4), using F's structure (identity plus a few
    entries): each row then each column of P is combined as F says."""
    n = x.shape[0]
    F, q = fq(ts, n, order, i_dd, i_d, i_th, q_rate, gm, tau, gm_var)
    xn = x.copy()
    Pn = P.copy()
    for c in range(i_th.shape[0]):  # rows: Pn = F P (θ before θ̇, which θ reads)
        t, d = i_th[c], (i_d[c] if order >= 1 else -1)
        dd = i_dd[c] if order == 2 else -1
        if d >= 0:
            f1 = F[t, d]
            xn[t] += f1 * x[d]
            for k in range(n):
                Pn[t, k] += f1 * P[d, k]
        if dd >= 0:
            f2, f3 = F[t, dd], F[d, dd]
            xn[t] += f2 * x[dd]
            xn[d] += f3 * x[dd]
            for k in range(n):
                Pn[t, k] += f2 * P[dd, k]
                Pn[d, k] += f3 * P[dd, k]
    for g in gm:
        xn[g] *= F[g, g]
        for k in range(n):
            Pn[g, k] *= F[g, g]
    Q = Pn.copy()  # columns: (F P) Fᵀ
    for c in range(i_th.shape[0]):
        t, d = i_th[c], (i_d[c] if order >= 1 else -1)
        dd = i_dd[c] if order == 2 else -1
        if d >= 0:
            f1 = F[t, d]
            for k in range(n):
                Q[k, t] += f1 * Pn[k, d]
        if dd >= 0:
            f2, f3 = F[t, dd], F[d, dd]
            for k in range(n):
                Q[k, t] += f2 * Pn[k, dd]
                Q[k, d] += f3 * Pn[k, dd]
    for g in gm:
        for k in range(n):
            Q[k, g] *= F[g, g]
    for k in range(n):
        Q[k, k] += q[k]
    return xn, Q


@jit
def joint_values(x: Any, theta_idx: Any) -> Any:
    """θ, θ̇, θ̈ (5,) of all joints from the state (joints not estimated: 0)."""
    block = np.zeros((3, 5))
    th, d, dd = block[0], block[1], block[2]
    for j in range(5):
        if theta_idx[2, j] >= 0:
            th[j] = x[theta_idx[2, j]]
        if theta_idx[1, j] >= 0:
            d[j] = x[theta_idx[1, j]]
        if theta_idx[0, j] >= 0:
            dd[j] = x[theta_idx[0, j]]
    return th, d, dd


@jit
def measure(
    x: Any,
    have: Any,
    theta_idx: Any,
    src: Any,
    dst: Any,
    bias: Any,
    body_idx: Any,
    lu: float,
    lf: float,
    r_u: Any,
    R_UI: Any,
    r_f: Any,
    R_FI: Any,
    body: bool,
    jacobian: bool,
) -> Any:
    """``h(x)`` (m,) and its Jacobian ``H`` (m, n) for the slots in ``have`` (eq. 16), in slot
    order (gyro u, acc u, gyro f, acc f, elbow, wrist).

    ``theta_idx`` (3, 5): state index of θ̈, θ̇, θ of each joint (−1: not in the state);
    ``src``/``dst``: dh Jacobian columns → state columns; ``bias``/``body_idx`` (6, 3): the
    gyro-bias and GM-1 body-acceleration states added to a slot (−1: none).
    """
    n = x.shape[0]
    th, d, dd = joint_values(x, theta_idx)
    vals, jac = sensors(th, d, dd, lu, lf, r_u, R_UI, r_f, R_FI, body, jacobian)
    mrows = 0
    for s in range(6):
        if have[s]:
            mrows += 3
    H = np.zeros((mrows, n))
    h = np.empty(mrows)
    row = 0
    for s in range(6):
        if not have[s]:
            continue
        for c in range(3):
            v = vals[s, c]
            if bias[s, c] >= 0:
                v += x[bias[s, c]]
                H[row + c, bias[s, c]] = 1.0
            if body_idx[s, c] >= 0:
                v += x[body_idx[s, c]]
                H[row + c, body_idx[s, c]] = 1.0
            h[row + c] = v
            if jacobian:
                for k in range(src.shape[0]):
                    H[row + c, dst[k]] = jac[s, src[k], c]
        row += 3
    return h, H


@jit
def stack(z: Any, have: Any, r: Any) -> Any:
    """The measurement vector and the diagonal of ``R`` (eq. 19) of the slots in ``have``."""
    m = 0
    for s in range(6):
        if have[s]:
            m += 3
    zv = np.empty(m)
    rv = np.empty(m)
    row = 0
    for s in range(6):
        if have[s]:
            for c in range(3):
                zv[row + c] = z[s, c]
                rv[row + c] = r[s]
            row += 3
    return zv, rv


@jit_inline
def _cholesky(S: Any) -> Any:
    """Lower Cholesky factor of a small SPD matrix, written out (LAPACK's call and copies cost
    more than the arithmetic here); raises on a matrix that is not positive definite."""
    m = S.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        acc = S[j, j]
        for k in range(j):
            acc -= L[j, k] * L[j, k]
        if not acc > 0.0:
            raise np.linalg.LinAlgError("innovation covariance not positive definite")
        d = math.sqrt(acc)
        L[j, j] = d
        for i in range(j + 1, m):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / d
    return L


@jit_inline
def _forward(L: Any, X: Any) -> None:
    """``X ← L⁻¹ X`` in place for lower-triangular ``L`` (m, m) and ``X`` (m, k)."""
    m, k = X.shape
    for i in range(m):  # row by row, each a contiguous sweep (the same sums per element)
        for t in range(i):
            lit = L[i, t]
            for c in range(k):
                X[i, c] -= lit * X[t, c]
        d = L[i, i]
        for c in range(k):
            X[i, c] /= d


@jit
def gain_update(x: Any, P: Any, Pxz: Any, S: Any, y: Any) -> Any:
    """``x + K y``, ``P − K S Kᵀ`` (symmetrised) and NIS per row, with ``K = Pxz S⁻¹`` through
    the Cholesky factor ``S = L Lᵀ``: ``U = L⁻¹ Pxzᵀ``, ``v = L⁻¹ y``, ``K y = Uᵀ v``,
    ``K S Kᵀ = Uᵀ U``."""
    L = _cholesky(S)
    U = Pxz.T.copy()  # C order: L⁻¹ row by row
    _forward(L, U)
    vm = y.reshape((-1, 1)).copy()
    _forward(L, vm)
    v = vm[:, 0]
    m, n = U.shape
    # K y and Uᵀ U with the row r of U in the outer loop: each element still sums
    # r = 0 … m−1 in order from 0 (the same numbers as a dot per element), but the inner loop
    # runs along a row of U over independent elements, which the compiler vectorises (a dot
    # per element is a chain of m dependent adds: it was most of the update's time). The
    # whole square, not a triangle: the same products in the same order make it exactly
    # symmetric, as is ½(P + Pᵀ), so each row of P⁺ is written in one contiguous sweep.
    ky = np.zeros(n)
    Pn = np.zeros((n, n))  # Uᵀ U, then P⁺
    for r in range(m):
        vr = v[r]
        for i in range(n):
            uri = U[r, i]
            ky[i] += uri * vr
            for j in range(n):
                Pn[i, j] += uri * U[r, j]
    xn = np.empty(n)
    for i in range(n):
        xn[i] = x[i] + ky[i]
        for j in range(n):
            Pn[i, j] = 0.5 * (P[i, j] + P[j, i]) - Pn[i, j]
    nis = 0.0
    for r in range(m):
        nis += v[r] * v[r]
    return xn, Pn, nis / max(m, 1)


@jit
def ekf_step(
    x: Any,
    P: Any,
    ts: float,
    z: Any,
    have: Any,
    r: Any,
    order: int,
    i_dd: Any,
    i_d: Any,
    i_th: Any,
    q_rate: Any,
    gm: Any,
    tau: float,
    gm_var: float,
    theta_idx: Any,
    src: Any,
    dst: Any,
    bias: Any,
    body_idx: Any,
    lu: float,
    lf: float,
    r_u: Any,
    R_UI: Any,
    r_f: Any,
    R_FI: Any,
    body: bool,
) -> Any:
    """One EKF step: :func:`predict` over ``ts`` s (none if ``ts`` ≤ 0), then the update with
    the analytic Jacobian (eqs. 16–19) on the slots in ``have`` (``z`` (6, 3) readings, ``r``
    (6,) each slot's noise variance; a slot left out is σ² = ∞: no rows at all).
    Returns ``x⁺``, ``P⁺`` and the normalised innovation squared per row."""
    if ts > 0.0:
        x, P = predict(x, P, ts, order, i_dd, i_d, i_th, q_rate, gm, tau, gm_var)
    h, H = measure(
        x, have, theta_idx, src, dst, bias, body_idx, lu, lf, r_u, R_UI, r_f, R_FI, body, True
    )
    zv, rv = stack(z, have, r)
    PHt = P @ np.ascontiguousarray(H.T)
    S = H @ PHt
    for k in range(rv.shape[0]):
        S[k, k] += rv[k]
    return gain_update(x, P, PHt, S, zv - h)


# The model's constants packed into one int and one float array (numba unboxes each argument
# of a call from Python, ~0.4 µs apiece: two arrays instead of twenty). Layout of ``ia``:
_IA_ORDER, _IA_N, _IA_BODY, _IA_NSRC, _IA_NGM = range(5)
_IA_THETA = 5  # (3, 5) theta_idx
_IA_BIAS = _IA_THETA + 15  # (6, 3) bias_idx
_IA_BODYI = _IA_BIAS + 18  # (6, 3) body_idx
_IA_VAR = _IA_BODYI + 18  # then src, dst (nsrc each), gm (ngm)
# ``fa``: lu, lf, tau, gm_var, r_u (3), R_UI (9), r_f (3), R_FI (9), r_slot (6), q_rate (n)
_FA_RSLOT = 4 + 24
_FA_Q = _FA_RSLOT + 6


def pack(
    order: int,
    n: int,
    body: bool,
    theta_idx: Any,
    bias: Any,
    body_idx: Any,
    src: Any,
    dst: Any,
    gm: Any,
    geo: tuple[float, float, Any, Any, Any, Any],
    tau: float,
    gm_var: float,
    r_slot: Any,
    q_rate: Any,
) -> tuple[Any, Any]:
    """The model's constants as (``ia``, ``fa``) for :func:`ekf_step_packed`, :func:`emit`."""
    ia = np.concatenate(
        (
            np.array([order, n, int(body), len(src), len(gm)]),
            np.ravel(theta_idx),
            np.ravel(bias),
            np.ravel(body_idx),
            src,
            dst,
            gm,
        )
    ).astype(np.intp)
    lu, lf, r_u, R_UI, r_f, R_FI = geo
    fa = np.concatenate(
        (
            np.array([lu, lf, tau, gm_var]),
            np.ravel(r_u),
            np.ravel(R_UI),
            np.ravel(r_f),
            np.ravel(R_FI),
            r_slot,
            q_rate,
        )
    ).astype(np.float64)
    return ia, fa


@jit
def _unpack(ia: Any) -> Any:
    theta_idx = ia[_IA_THETA:_IA_BIAS].reshape((3, 5))
    nj = 0
    for j in range(5):
        if theta_idx[2, j] >= 0:
            nj += 1
    i_dd = np.empty(nj, dtype=np.intp)
    i_d = np.empty(nj, dtype=np.intp)
    i_th = np.empty(nj, dtype=np.intp)
    c = 0
    for j in range(5):
        if theta_idx[2, j] >= 0:
            i_dd[c], i_d[c], i_th[c] = theta_idx[0, j], theta_idx[1, j], theta_idx[2, j]
            c += 1
    nsrc, ngm = ia[_IA_NSRC], ia[_IA_NGM]
    src = ia[_IA_VAR : _IA_VAR + nsrc]
    dst = ia[_IA_VAR + nsrc : _IA_VAR + 2 * nsrc]
    gm = ia[_IA_VAR + 2 * nsrc : _IA_VAR + 2 * nsrc + ngm]
    bias = ia[_IA_BIAS:_IA_BODYI].reshape((6, 3))
    body_idx = ia[_IA_BODYI:_IA_VAR].reshape((6, 3))
    return theta_idx, i_dd, i_d, i_th, src, dst, gm, bias, body_idx


@jit_inline
def geometry(fa: Any) -> Any:
    """The segments and IMU mountings packed by :func:`pack`: ``lu``, ``lf`` (m), ``r_u`` (3,)
    m, ``R_UI`` (3, 3), ``r_f`` (3,) m, ``R_FI`` (3, 3)."""
    return fa[0], fa[1], fa[4:7], fa[7:16].reshape((3, 3)), fa[16:19], fa[19:28].reshape((3, 3))


@jit
def ekf_step_packed(x: Any, P: Any, ts: float, z: Any, have: Any, ia: Any, fa: Any) -> Any:
    """:func:`ekf_step` with the model's constants packed by :func:`pack`."""
    theta_idx, i_dd, i_d, i_th, src, dst, gm, bias, body_idx = _unpack(ia)
    lu, lf, r_u, R_UI, r_f, R_FI = geometry(fa)
    n = ia[_IA_N]
    return ekf_step(
        x,
        P,
        ts,
        z,
        have,
        fa[_FA_RSLOT:_FA_Q],
        ia[_IA_ORDER],
        i_dd,
        i_d,
        i_th,
        fa[_FA_Q : _FA_Q + n],
        gm,
        fa[2],
        fa[3],
        theta_idx,
        src,
        dst,
        bias,
        body_idx,
        lu,
        lf,
        r_u,
        R_UI,
        r_f,
        R_FI,
        ia[_IA_BODY] != 0,
    )


@jit_inline
def camera_offsets(x: Any, ia: Any) -> Any:
    """The camera's joint-centre offset states in ``x`` (elbow xyz, wrist xyz in S, m; 0 where
    the model has none): what :func:`measure` adds to its position rows."""
    off = np.zeros(6)
    for c in range(3):
        for r, slot in ((0, ELBOW), (1, WRIST)):
            k = ia[_IA_BIAS + 3 * slot + c]
            if k >= 0:
                off[3 * r + c] = x[k]
    return off


@jit
def camera_angles(
    theta: Any, lu: float, lf: float, z: Any, wrist: bool, off: Any, ridge: float
) -> Any:
    """The change of θ0…θ3 (4,) rad that explains the camera's positions ``z`` (6, 3) slots
    (elbow, and the wrist if ``wrist``), less the offsets ``off`` (6,) m, against the pose at
    ``θ`` (5,) rad: least squares on the chain's position Jacobian (eq. 11's joint axes through
    the shoulder and elbow) with ``ridge`` m² per rad², so that an angle that hardly moves the
    points (rotation with the elbow straight) takes none of the residual."""
    axes, _, _, elbow, wrist_p = pose(theta, lu, lf)
    J = np.zeros((6, 4))
    r = np.zeros(6)
    fore = np.empty(3)
    for c in range(3):
        r[c] = z[ELBOW, c] - off[c] - elbow[c]
        fore[c] = wrist_p[c] - elbow[c]
    col = np.empty(3)
    for j in range(3):
        cross(axes[j], elbow, col)
        J[0:3, j] = col
    if wrist:
        for c in range(3):
            r[3 + c] = z[WRIST, c] - off[3 + c] - wrist_p[c]
        for j in range(3):
            cross(axes[j], wrist_p, col)
            J[3:6, j] = col
        cross(axes[3], fore, col)
        J[3:6, 3] = col
    A = J.T @ J
    for j in range(4):
        A[j, j] += ridge
    return np.linalg.solve(A, J.T @ r)


@jit
def emit(x: Any, P: Any, ia: Any, fa: Any, vertical_rad: float) -> Any:
    """:func:`outputs` as one array (17,): θ (5), σ (5) in degrees, elbow, wrist (3) m, the σ
    of the turn about the vertical from P (degrees)."""
    th, std, elbow, wrist, vert = outputs(
        x, P, ia[_IA_THETA:_IA_BIAS].reshape((3, 5)), fa[0], fa[1], vertical_rad
    )
    out = np.empty(17)
    deg = 180.0 / math.pi
    for j in range(5):
        out[j] = th[j] * deg
        out[5 + j] = std[j] * deg
    out[10:13] = elbow
    out[13:16] = wrist
    out[16] = vert * deg
    return out
