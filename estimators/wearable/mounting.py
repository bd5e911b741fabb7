"""The product's mounting-misalignment states (not in the paper): each IMU's small rotation
from its nominal mounting, estimated with the joint angles.

A strap puts an IMU a few degrees off its nominal orientation ``R_UI`` (``R_FI``). With the true
mounting ``R_UI·Exp(δ)`` (``δ`` (3,) rad, a rotation vector in the IMU frame) every reading of
that IMU is the nominal prediction ``v`` (eqs. 12–15) turned by ``Exp(−δ)``. The product
turns it exactly (``mounting_turn="exact"``),

    h = Exp(−δ)·v,   ∂h/∂δ = Exp(−δ) [v]× J_r(−δ),   ∂h/∂x = Exp(−δ) ∂v/∂x,

or, as until 2026-12-05, to first order (``"first_order"``),

    h = v + v × δ,   ∂h/∂δ = [v]×,   ∂h/∂x = (1 + [·]×δ) ∂v/∂x

(``J_r``: SO(3)'s right Jacobian), either applied to the gyro and the accelerometer rows of
the same IMU (one rigid body) before its additive states (gyro bias, accelerometer bias) are
added.
The first order lengthens a reading by about |δ⊥v|²/2: an accelerometer's 2.5 % scale error
pulls the forearm's δ to 14° at the start's rest and the elbow the other way, while the same
lengthening holds δ near nominal where nothing else tells it from an angle
(docs/benchmarks.md, "Per-angle confidence").

``δ = B η`` with ``B`` unit vectors in the IMU frame: all three axes for the upper-arm IMU,
but for the forearm IMU only the two across the forearm's long axis: a turn about it is the
same reading as the pronation θ5 (nothing distal to the forearm moves with it, and the wrist
is on that axis), so no sensor here can tell them apart. (About the upper arm's long axis the
forearm IMU tells the mounting from θ2 once the elbow bends.) ``η`` is a random constant
(prior σ and a slow walk from the parameters).

Gravity and the gyros cannot tell ``δ`` about an angle's own axis from the angle (elbow
flexion and the forearm IMU's turn about the flexion axis turn both readings the same way);
the camera's positions can, and without a camera only the size of the kinematic
accelerations, at second order (``sigma_mounting_gain`` adds the states' departure from
nominal to the paired angles' σ while there is no camera, ``sigma_mounting_change_gain`` and
``sigma_upper_change_gain`` how far they have just moved: :func:`.steps.finish`).

Soft tissue (``soft_tissue_sigma``): the skin under the upper arm's strap slides over the
humerus, so the IMU turns about the arm's long axis by ``c·θ2`` more than the bone, θ2 being the
shoulder's rotation (``c`` a random constant, one state, ``mis[GYR_U, 4]``). θ2 is the last turn
of R_SU, about that axis, so this is a mounting turn ``δ += c·θ2·a`` (``a`` the long axis in
the IMU frame: ``R_UIᵀ ẑ``) with the gyro reading the strap's own rate ``c·θ̇2·a`` more;
``∂δ/∂c = θ2·a``, ``∂δ/∂θ2 = c·a``. (The IMU's 4 cm from the axis turn too: the accelerometer's
lever arm is left at nominal, a few 0.01 m/s² at 3 rad/s.) Only the forearm IMU across a bent
elbow sees θ2 apart from the upper arm's strap; at a straight elbow a wrong θ2 (the whole arm's
turn about the vertical) drove ``c`` to −0.5 and the upper arm's gyro bias with it, so the
EKF's ``c`` learns only while the estimated elbow flexion exceeds ``soft_tissue_min_elbow_deg``
(its column of ``H`` is zero otherwise; the UKF learns it anywhere).

The camera's joint-centre offsets (``camera_offset_sigma_m``) are additive states of the
camera's rows, like the gyro biases of the gyros' (``bias_idx`` of the ELBOW and WRIST slots).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.jit import jit
from estimators.wearable import kernel


@jit
def _turn(d: Any) -> Any:
    """``Exp(−d)`` (3, 3) and ``J_r(−d)`` (3, 3) for a rotation vector ``d`` (3,) rad
    (Rodrigues; their series near zero)."""
    th2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    th = np.sqrt(th2)
    if th < 1e-4:
        a, b, c = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        a, b, c = np.sin(th) / th, (1.0 - np.cos(th)) / th2, (th - np.sin(th)) / (th2 * th)
    K = np.zeros((3, 3))  # [−d]×
    K[0, 1], K[0, 2], K[1, 2] = d[2], -d[1], d[0]
    K[1, 0], K[2, 0], K[2, 1] = -d[2], d[1], -d[0]
    K2 = K @ K
    return np.eye(3) + a * K + b * K2, np.eye(3) - b * K + c * K2


@jit
def _additive(k: int, s: int, bias: Any, body_idx: Any) -> bool:
    """Whether state ``k`` is one of slot ``s``'s additive states (not turned)."""
    b, g = bias[s], body_idx[s]
    return bool(k == b[0] or k == b[1] or k == b[2] or k == g[0] or k == g[1] or k == g[2])


@jit
def _dturn(v: Any, b: Any, R: Any, J: Any, exact: bool) -> Any:
    """``∂h/∂ε`` (3,) of a reading ``v`` turned by ``δ + ε·b``: ``v × b`` to first order,
    ``Exp(−δ) (v × J_r(−δ) b)`` exactly (``R``, ``J``: :func:`_turn` of ``δ``)."""
    b0, b1, b2 = b[0], b[1], b[2]
    if exact:  # J_r(−δ) b
        b0, b1, b2 = (
            J[0, 0] * b0 + J[0, 1] * b1 + J[0, 2] * b2,
            J[1, 0] * b0 + J[1, 1] * b1 + J[1, 2] * b2,
            J[2, 0] * b0 + J[2, 1] * b1 + J[2, 2] * b2,
        )
    c0, c1, c2 = v[1] * b2 - v[2] * b1, v[2] * b0 - v[0] * b2, v[0] * b1 - v[1] * b0
    if exact:  # Exp(−δ) (v × J_r b)
        c0, c1, c2 = (
            R[0, 0] * c0 + R[0, 1] * c1 + R[0, 2] * c2,
            R[1, 0] * c0 + R[1, 1] * c1 + R[1, 2] * c2,
            R[2, 0] * c0 + R[2, 1] * c1 + R[2, 2] * c2,
        )
    return c0, c1, c2


@jit
def _turned(
    x: Any, H: Any, row: int, s: int, d: Any, v: Any, bias: Any, body_idx: Any, mis: Any,
    basis: Any, h: Any, exact: bool, st: int, k2: int, ax: Any,
) -> None:  # fmt: skip
    """Slot ``s``'s rows ``h``, ``H`` (from ``row``) turned by ``δ = d``: to first order
    ``h += v × δ``, ``H += (∂v/∂x) × δ``, ``∂h/∂η_k = v × b_k`` (the product's), or exactly
    ``h = Exp(−δ) v``, ``∂h/∂x = Exp(−δ) ∂v/∂x``, ``∂h/∂η_k = Exp(−δ) (v × J_r(−δ) b_k)``;
    with soft tissue (``st`` ≥ 0) ``δ`` holds ``c·θ2·ax`` too (``c = x[st]``, ``θ2 = x[k2]``)."""
    if exact:
        R, J = _turn(d)
        for c in range(3):
            h[row + c] += R[c, 0] * v[0] + R[c, 1] * v[1] + R[c, 2] * v[2] - v[c]
    else:
        R, J = np.eye(3), np.eye(3)
        h[row] += v[1] * d[2] - v[2] * d[1]
        h[row + 1] += v[2] * d[0] - v[0] * d[2]
        h[row + 2] += v[0] * d[1] - v[1] * d[0]
    for k in range(x.shape[0]):
        if _additive(k, s, bias, body_idx):
            continue
        j0, j1, j2 = H[row, k], H[row + 1, k], H[row + 2, k]
        if exact:
            for c in range(3):
                H[row + c, k] = R[c, 0] * j0 + R[c, 1] * j1 + R[c, 2] * j2
        else:
            H[row, k] += j1 * d[2] - j2 * d[1]
            H[row + 1, k] += j2 * d[0] - j0 * d[2]
            H[row + 2, k] += j0 * d[1] - j1 * d[0]
    for k in range(3):
        m = mis[s, k]
        if m < 0:
            continue
        c0, c1, c2 = _dturn(v, basis[s, :, k], R, J, exact)
        H[row, m] += c0
        H[row + 1, m] += c1
        H[row + 2, m] += c2
    if st >= 0:  # ∂δ/∂c = θ2·ax, ∂δ/∂θ2 = c·ax
        c0, c1, c2 = _dturn(v, ax, R, J, exact)
        H[row, st] += c0 * x[k2]
        H[row + 1, st] += c1 * x[k2]
        H[row + 2, st] += c2 * x[k2]
        H[row, k2] += c0 * x[st]
        H[row + 1, k2] += c1 * x[st]
        H[row + 2, k2] += c2 * x[st]


@jit
def misalign(
    x: Any, have: Any, h: Any, H: Any, bias: Any, body_idx: Any, mis: Any, basis: Any,
    k2: int, k2d: int, ax: Any,
) -> None:  # fmt: skip
    """Turn the predicted IMU rows ``h`` (m,) and ``H`` (m, n) of :func:`kernel.measure` by
    the misalignment states, in place: ``δ = Σ_k basis[s, :, k]·x[mis[s, k]]`` for slot ``s``
    (``mis`` (6, 5): three state indices, −1: none, e.g. the camera slots, then 1 for the
    exact turn, 0 for the first order; ``basis`` (6, 3, 3) unit vectors in the IMU frame);
    ``bias``/``body_idx`` as in ``measure`` (additive, not turned). Soft tissue (the state
    ``mis[s, 4]`` ≥ 0, the upper-arm slots): ``δ`` adds ``c·θ2·ax`` (``ax`` (3,) the arm's
    long axis in the IMU frame; ``k2``, ``k2d`` the states of θ2 and θ̇2) and the gyro reads
    ``c·θ̇2·ax`` more."""
    row = 0
    for s in range(6):
        if not have[s]:
            continue
        if mis[s, 0] >= 0:
            d = np.zeros(3)
            for k in range(3):
                if mis[s, k] >= 0:
                    for c in range(3):
                        d[c] += basis[s, c, k] * x[mis[s, k]]
            st = mis[s, 4] if k2 >= 0 else -1
            if st >= 0:
                for c in range(3):
                    d[c] += x[st] * x[k2] * ax[c]
            v = np.empty(3)  # the kinematic prediction: h without the additive states
            for c in range(3):
                v[c] = h[row + c]
                if bias[s, c] >= 0:
                    v[c] -= x[bias[s, c]]
                if body_idx[s, c] >= 0:
                    v[c] -= x[body_idx[s, c]]
            _turned(x, H, row, s, d, v, bias, body_idx, mis, basis, h, mis[s, 3] != 0, st, k2, ax)
            if st >= 0 and s == kernel.GYR_U and k2d >= 0:  # the strap's own turning rate
                for c in range(3):
                    h[row + c] += x[st] * x[k2d] * ax[c]
                    H[row + c, st] += x[k2d] * ax[c]
                    H[row + c, k2d] += x[st] * ax[c]
        row += 3


@jit
def measure(x: Any, have: Any, ia: Any, fa: Any, mis: Any, basis: Any, jacobian: bool) -> Any:
    """:func:`kernel.measure` with the model's packed constants, then :func:`misalign`."""
    theta_idx, _, _, _, src, dst, _, bias, body_idx = kernel._unpack(ia)
    lu, lf, r_u, R_UI, r_f, R_FI = kernel.geometry(fa)
    h, H = kernel.measure(
        x,
        have,
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
        ia[kernel._IA_BODY] != 0,
        jacobian,
    )
    ax = np.ascontiguousarray(R_UI[2, :])  # the arm's long axis (U's z) in the IMU frame
    misalign(x, have, h, H, bias, body_idx, mis, basis, theta_idx[2, 2], theta_idx[1, 2], ax)
    if not jacobian:
        H = np.zeros((0, x.shape[0]))
    return h, H


@jit
def ekf_step(
    x: Any, P: Any, ts: float, z: Any, have: Any, ia: Any, fa: Any, mis: Any, basis: Any
) -> Any:
    """:func:`kernel.ekf_step_packed` with the misalignment states in ``h`` and ``H``."""
    _, i_dd, i_d, i_th, _, _, gm, _, _ = kernel._unpack(ia)
    n = ia[kernel._IA_N]
    if ts > 0.0:
        x, P = kernel.predict(
            x,
            P,
            ts,
            ia[kernel._IA_ORDER],
            i_dd,
            i_d,
            i_th,
            fa[kernel._FA_Q : kernel._FA_Q + n],
            gm,
            fa[2],
            fa[3],
        )
    h, H = measure(x, have, ia, fa, mis, basis, True)
    st = mis[kernel.GYR_U, 4]
    k4 = ia[kernel._IA_THETA + 2 * 5 + 3]  # θ4's state
    if st >= 0 and (k4 < 0 or x[k4] < fa[fa.shape[0] - 1]):
        H[:, st] = 0.0  # c learns only across a bent elbow (fa's tail: the bend)
    zv, rv = kernel.stack(z, have, fa[kernel._FA_RSLOT : kernel._FA_Q])
    PHt = P @ np.ascontiguousarray(H.T)
    S = H @ PHt
    for k in range(rv.shape[0]):
        S[k, k] += rv[k]
    return kernel.gain_update(x, P, PHt, S, zv - h)
