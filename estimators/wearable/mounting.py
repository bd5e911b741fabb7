"""The product's mounting-misalignment states (not in the paper): each IMU's small rotation
from its nominal mounting, estimated with the joint angles.

A strap puts an IMU a few degrees off its nominal orientation ``R_UI`` (``R_FI``). With the true
mounting ``R_UI·Exp(δ)`` (``δ`` (3,) rad, a rotation vector in the IMU frame) every reading of
that IMU is the nominal prediction ``v`` (eqs. 12–15) turned by ``Exp(−δ)``; to first order

    h = v + v × δ,   ∂h/∂δ = [v]×,   ∂h/∂x = (1 + [·]×δ) ∂v/∂x,

applied to the gyro and the accelerometer rows of the same IMU (one rigid body) before its
gyro bias is added. ``δ = B η`` with ``B`` unit vectors in the IMU frame: all three axes for
the upper-arm IMU, but for the forearm IMU only the two across the forearm's long axis: a turn
about it is the same reading as the pronation θ5 (nothing distal to the forearm moves with it,
and the wrist is on that axis), so no sensor here can tell them apart. (About the upper arm's
long axis the forearm IMU tells the mounting from θ2 once the elbow bends.) ``η`` is a random
constant (prior σ and a slow walk from the parameters).

The accelerometers cannot tell ``δ`` about the flexion axis from the flexion itself (both turn
gravity the same way in the IMU frame): the camera's positions make it observable. Without a
camera ``δ`` stays at its prior and only widens the angles' σ where it is unobservable.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.jit import jit
from estimators.wearable import kernel


@jit
def misalign(
    x: Any, have: Any, h: Any, H: Any, bias: Any, body_idx: Any, mis: Any, basis: Any
) -> None:
    """Turn the predicted IMU rows ``h`` (m,) and ``H`` (m, n) of :func:`kernel.measure` by
    the misalignment states, in place: ``δ = Σ_k basis[s, :, k]·x[mis[s, k]]`` for slot ``s``
    (``mis`` (6, 3) state indices, −1: none, e.g. the camera slots; ``basis`` (6, 3, 3) unit
    vectors in the IMU frame); ``bias``/``body_idx`` as in ``measure``."""
    n = x.shape[0]
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
            v = np.empty(3)  # the kinematic prediction: h without the additive states
            for c in range(3):
                v[c] = h[row + c]
                if bias[s, c] >= 0:
                    v[c] -= x[bias[s, c]]
                if body_idx[s, c] >= 0:
                    v[c] -= x[body_idx[s, c]]
            h[row] += v[1] * d[2] - v[2] * d[1]
            h[row + 1] += v[2] * d[0] - v[0] * d[2]
            h[row + 2] += v[0] * d[1] - v[1] * d[0]
            for k in range(n):
                if k == bias[s, 0] or k == bias[s, 1] or k == bias[s, 2]:
                    continue
                if k == body_idx[s, 0] or k == body_idx[s, 1] or k == body_idx[s, 2]:
                    continue
                j0, j1, j2 = H[row, k], H[row + 1, k], H[row + 2, k]
                H[row, k] += j1 * d[2] - j2 * d[1]
                H[row + 1, k] += j2 * d[0] - j0 * d[2]
                H[row + 2, k] += j0 * d[1] - j1 * d[0]
            for k in range(3):  # ∂(v × δ)/∂η_k = v × b_k
                if mis[s, k] < 0:
                    continue
                b0, b1, b2 = basis[s, 0, k], basis[s, 1, k], basis[s, 2, k]
                H[row, mis[s, k]] += v[1] * b2 - v[2] * b1
                H[row + 1, mis[s, k]] += v[2] * b0 - v[0] * b2
                H[row + 2, mis[s, k]] += v[0] * b1 - v[1] * b0
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
    misalign(x, have, h, H, bias, body_idx, mis, basis)
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
    zv, rv = kernel.stack(z, have, fa[kernel._FA_RSLOT : kernel._FA_Q])
    PHt = P @ np.ascontiguousarray(H.T)
    S = H @ PHt
    for k in range(rv.shape[0]):
        S[k, k] += rv[k]
    return kernel.gain_update(x, P, PHt, S, zv - h)
