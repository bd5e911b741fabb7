"""EKF and UKF steps of the wearable model (paper §2.2; UKF as compared in §3.1 and table 10).

Both predict with the linear process of eqs. 3–4 (exact, so the UKF needs no sigma points
there) and differ in the update: the EKF linearises ``h`` with the analytic Jacobian of
:func:`estimators.wearable.dh.sensors`; the UKF propagates scaled sigma points (α = 1, β = 2,
κ = 0) through ``h``. A step is pure: ``(x, P)`` in, ``(x, P, nis)`` out.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from estimators.wearable.dh import F64
from estimators.wearable.model import Measurement, Model


def predict(x: F64, P: F64, f: F64, q: F64) -> tuple[F64, F64]:
    """``x⁻ = F x``, ``P⁻ = F P Fᵀ + Q`` (eqs. 3, 4)."""
    return f @ x, f @ P @ f.T + q


def _gain(P: F64, Pxz: F64, S: F64, y: F64) -> tuple[F64, F64, float]:
    c = cho_factor(S, lower=True, check_finite=False)
    K = cho_solve(c, Pxz.T, check_finite=False).T
    nis = float(y @ cho_solve(c, y, check_finite=False)) / max(len(y), 1)
    return K, K @ S @ K.T, nis


def ekf_update(model: Model, x: F64, P: F64, m: Measurement) -> tuple[F64, F64, float]:
    """EKF update with the analytic Jacobian; returns ``x⁺``, ``P⁺`` and the normalised
    innovation squared per row (≈ 1 when the model fits the data)."""
    z, r = model.rows(m)
    h, H = model.predict_rows(x, m)
    y = z - h
    PHt = P @ H.T
    S = H @ PHt
    S[np.diag_indices_from(S)] += r
    K, KSK, nis = _gain(P, PHt, S, y)
    Pn = P - KSK
    return x + K @ y, 0.5 * (Pn + Pn.T), nis


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
    y = z - zm
    K, KSK, nis = _gain(P, Pxz, S, y)
    Pn = P - KSK
    return x + K @ y, 0.5 * (Pn + Pn.T), nis


def update(
    kind: Literal["ekf", "ukf"], model: Model, x: F64, P: F64, m: Measurement
) -> tuple[F64, F64, float]:
    """The selected filter's update."""
    return (ekf_update if kind == "ekf" else ukf_update)(model, x, P, m)
