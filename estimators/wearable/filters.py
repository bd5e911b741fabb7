"""EKF and UKF steps of the wearable model (paper §2.2; UKF as compared in §3.1 and table 10).

Both predict with the linear process of eqs. 3–4 (exact, so the UKF needs no sigma points
there) and differ in the update: the EKF linearises ``h`` with the analytic Jacobian of
:func:`estimators.wearable.dh.sensors`; the UKF propagates scaled sigma points (α = 1, β = 2,
κ = 0) through ``h``. A step is pure: ``(x, P)`` in, ``(x, P, nis)`` out. The arithmetic is
:mod:`estimators.wearable.kernel` (compiled); the EKF's whole step is one call into it.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from estimators.wearable import kernel, mounting
from estimators.wearable.dh import F64
from estimators.wearable.model import Measurement, Model


def predict(model: Model, x: F64, P: F64, ts: float) -> tuple[F64, F64]:
    """``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q`` (eqs. 3, 4) over ``ts`` s."""
    args = model.process_args(ts)
    xn, Pn = kernel.predict(x, P, args[0], *args[2:])
    return xn, Pn


def ekf_update(model: Model, x: F64, P: F64, m: Measurement) -> tuple[F64, F64, float]:
    """EKF update with the analytic Jacobian; returns ``x⁺``, ``P⁺`` and the normalised
    innovation squared per row (≈ 1 when the model fits the data)."""
    return ekf_step(model, x, P, 0.0, m)


def ekf_step(model: Model, x: F64, P: F64, ts: float, m: Measurement) -> tuple[F64, F64, float]:
    """:func:`predict` over ``ts`` s (none if ``ts`` ≤ 0), then :func:`ekf_update`."""
    z, have = model.slots(m)
    if model.i_mu.size:  # the product's mounting states (.mounting)
        xn, Pn, nis = mounting.ekf_step(
            x, P, ts, z, have, *model.packed, model.mis_idx, model.mis_basis
        )
    else:
        xn, Pn, nis = kernel.ekf_step_packed(x, P, ts, z, have, *model.packed)
    return xn, Pn, float(nis)


def ukf_update(model: Model, x: F64, P: F64, m: Measurement) -> tuple[F64, F64, float]:
    """Unscented update (scaled sigma points, α = 1, β = 2, κ = 0)."""
    n = len(x)
    z, r = model.rows(m)
    try:
        L = np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(0.5 * (P + P.T))
        L = v * np.sqrt(np.clip(w, 0.0, None))
    s = np.sqrt(float(n))  # n + λ with λ = α²(n + κ) − n = 0
    pts = np.vstack((x, x + s * L.T, x - s * L.T))
    wm = np.full(2 * n + 1, 0.5 / n)
    wm[0] = 0.0
    wc = wm.copy()
    wc[0] = 2.0  # (λ / (n + λ)) + 1 − α² + β
    Z = np.array([model.predict_rows(p, m, jacobian=False)[0] for p in pts])
    zm = wm @ Z
    dz = Z - zm
    dx = pts - x
    S = (dz.T * wc) @ dz
    S[np.diag_indices_from(S)] += r
    Pxz = (dx.T * wc) @ dz
    xn, Pn, nis = kernel.gain_update(x, P, Pxz, S, z - zm)
    return xn, Pn, float(nis)


def step(
    kind: Literal["ekf", "ukf"], model: Model, x: F64, P: F64, ts: float, m: Measurement
) -> tuple[F64, F64, float]:
    """The selected filter's step: predict over ``ts`` s (none if ``ts`` ≤ 0), then update."""
    if kind == "ekf":
        return ekf_step(model, x, P, ts, m)
    if ts > 0.0:
        x, P = predict(model, x, P, ts)
    return ukf_update(model, x, P, m)


def update(
    kind: Literal["ekf", "ukf"], model: Model, x: F64, P: F64, m: Measurement
) -> tuple[F64, F64, float]:
    """The selected filter's update."""
    return (ekf_update if kind == "ekf" else ukf_update)(model, x, P, m)
