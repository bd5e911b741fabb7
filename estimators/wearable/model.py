"""State-space model of the wearable filter (paper §2.2, eqs. 1–4, 16–19).

State (column vector, radians): the kinematic block ``[θ̈_J, θ̇_J, θ_J]`` of the estimated
joints J (eq. 1; order 2, model A), ``[θ̇_J, θ_J]`` (order 1, models B and C) or ``[θ_J]``
(order 0, the inclinometer model "I" of §3.1), then optionally the gyro biases of the upper-arm
and forearm IMUs (rad/s, 3 each; the product's addition, random constants with a slow walk),
then for model B the body accelerations of each IMU in its own frame (m/s², 3 each, GM-1).

``F`` is eq. 3 (and its order-1/0 analogues), ``Q`` eq. 4 with the noise on the top derivative
only. Measurements (eq. 16) are stacked per available sensor: upper-arm gyro and accelerometer,
forearm gyro and accelerometer, camera elbow and wrist positions; without a camera sample the
position rows are left out (σp² = ∞), never given a large variance. ``R`` is eq. 19.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from estimators.wearable import dh
from estimators.wearable.dh import F64, I64
from estimators.wearable.params import WearableParams

DEG = np.pi / 180.0
ORDER = {"A": 2, "B": 1, "C": 1, "I": 0}


class Measurement(NamedTuple):
    """One step's observations (virtual right arm): ``gyr_u``, ``acc_u`` (3,) always;
    ``gyr_f``, ``acc_f`` (3,) or None; ``elbow``, ``wrist`` (3,) in S or None."""

    gyr_u: F64
    acc_u: F64
    gyr_f: F64 | None = None
    acc_f: F64 | None = None
    elbow: F64 | None = None
    wrist: F64 | None = None


@dataclass(frozen=True)
class Model:
    """The filter's model for given parameters; indices into the state vector."""

    params: WearableParams
    geo: dh.Geometry
    order: int
    joints: tuple[int, ...]
    n: int  # state dimension
    i_dd: I64  # state indices of θ̈_J, θ̇_J, θ_J (empty where the order lacks them)
    i_d: I64
    i_th: I64
    i_bu: I64  # gyro biases
    i_bf: I64
    i_au: I64  # model B body accelerations
    i_af: I64
    use_forearm: bool
    src_cols: I64  # columns of dh's Jacobians ([θ̈ 5, θ̇ 5, θ 5]) that the state has ...
    dst_cols: I64  # ... and where they go in the state

    @classmethod
    def build(cls, p: WearableParams) -> Model:
        order = ORDER[p.model]
        joints = p.estimated
        nj = len(joints)
        k = 0

        def take(m: int) -> I64:
            nonlocal k
            out = np.arange(k, k + m)
            k += m
            return out

        i_dd = take(nj if order >= 2 else 0)
        i_d = take(nj if order >= 1 else 0)
        i_th = take(nj)
        use_f = p.forearm and any(j >= 3 for j in joints)
        i_bu = take(3 if p.gyro_bias and order >= 1 else 0)
        i_bf = take(3 if p.gyro_bias and order >= 1 and use_f else 0)
        i_au = take(3 if p.model == "B" else 0)
        i_af = take(3 if p.model == "B" and use_f else 0)
        src: list[int] = []
        dst: list[int] = []
        for c, j in enumerate(joints):
            if order >= 2:
                src.append(j)
                dst.append(int(i_dd[c]))
            if order >= 1:
                src.append(5 + j)
                dst.append(int(i_d[c]))
            src.append(10 + j)
            dst.append(int(i_th[c]))
        return cls(
            p,
            p.geometry(),
            order,
            joints,
            k,
            i_dd,
            i_d,
            i_th,
            i_bu,
            i_bf,
            i_au,
            i_af,
            use_f,
            np.array(src),
            np.array(dst),
        )

    # ------------------------------------------------------------------ process (eqs. 3, 4)
    def transition(self, ts: float) -> tuple[F64, F64]:
        """``F`` (eq. 3) and ``Q`` (eq. 4) for a step of ``ts`` s."""
        p, n = self.params, self.n
        f = np.eye(n)
        q = np.zeros(n)
        scale = ts / p.q_ref_dt_s
        if self.order == 2:
            f[self.i_d, self.i_dd] = ts
            f[self.i_th, self.i_dd] = 0.5 * ts * ts
            f[self.i_th, self.i_d] = ts
            q[self.i_dd] = (p.sigma_ddtheta_dps2 * DEG) ** 2 * scale
        elif self.order == 1:
            f[self.i_th, self.i_d] = ts
            q[self.i_d] = (p.sigma_dtheta_dps * DEG) ** 2 * scale
        else:
            q[self.i_th] = (p.sigma_theta_deg * DEG) ** 2 * scale
        walk = (p.gyro_bias_walk_dps_per_sqrt_s * DEG) ** 2 * ts
        q[self.i_bu] = walk
        q[self.i_bf] = walk
        if p.model == "B":
            phi = np.exp(-ts / p.body_acc_tau_s)
            for idx in (self.i_au, self.i_af):
                f[idx, idx] = phi
                q[idx] = p.body_acc_sigma_ms2**2 * (1.0 - phi * phi)
        return f, np.diag(q)

    def initial(self) -> tuple[F64, F64]:
        """Zero pose at rest (contract §8 "Start"): ``x0`` (n,), ``P0`` (n, n)."""
        p = self.params
        x = np.zeros(self.n)
        var = np.zeros(self.n)
        var[self.i_dd] = (1.0 * DEG) ** 2
        var[self.i_d] = (1.0 * DEG) ** 2
        var[self.i_th] = (p.init_sigma_deg * DEG) ** 2
        var[self.i_bu] = (p.gyro_bias_sigma_dps * DEG) ** 2
        var[self.i_bf] = (p.gyro_bias_sigma_dps * DEG) ** 2
        var[self.i_au] = (0.1 * p.body_acc_sigma_ms2) ** 2
        var[self.i_af] = (0.1 * p.body_acc_sigma_ms2) ** 2
        return x, np.diag(var)

    # ------------------------------------------------------------------ measurements
    def full_theta(self, x: F64) -> tuple[F64, F64, F64]:
        """θ, θ̇, θ̈ (5,) of all joints from the state; joints not estimated are 0."""
        th, d, dd = np.zeros(5), np.zeros(5), np.zeros(5)
        j = list(self.joints)
        th[j] = x[self.i_th]
        if self.order >= 1:
            d[j] = x[self.i_d]
        if self.order >= 2:
            dd[j] = x[self.i_dd]
        return th, d, dd

    def rows(self, m: Measurement) -> tuple[F64, F64]:
        """The measurement vector ``z`` and the diagonal of ``R`` (eq. 19) for what ``m`` holds."""
        p = self.params
        parts: list[F64] = []
        var: list[float] = []
        sg, sa, sp = (p.sigma_gyr_dps * DEG) ** 2, p.sigma_acc_ms2**2, p.sigma_pos_m**2
        if self.order >= 1:
            parts.append(m.gyr_u)
            var += [sg] * 3
        parts.append(m.acc_u)
        var += [sa] * 3
        if self.use_forearm and m.gyr_f is not None and m.acc_f is not None:
            if self.order >= 1:
                parts.append(m.gyr_f)
                var += [sg] * 3
            parts.append(m.acc_f)
            var += [sa] * 3
        if p.camera and m.elbow is not None:
            parts.append(m.elbow)
            var += [sp] * 3
            if self.use_forearm and m.wrist is not None:
                parts.append(m.wrist)
                var += [sp] * 3
        return np.concatenate(parts), np.array(var)

    def predict_rows(self, x: F64, m: Measurement, jacobian: bool = True) -> tuple[F64, F64]:
        """``h(x)`` and its Jacobian ``H`` (rows as :meth:`rows`, columns the state)."""
        th, d, dd = self.full_theta(x)
        s = dh.sensors(th, d, dd, self.geo, body=self.params.model == "A", jacobian=jacobian)
        hs: list[F64] = []
        hj: list[F64] = []
        src, dst = self.src_cols, self.dst_cols
        with_f = self.use_forearm and m.gyr_f is not None and m.acc_f is not None

        def add(v: F64, jac: F64 | None, bias: I64 | None = None, body: I64 | None = None) -> None:
            val = v
            if bias is not None and bias.size:
                val = val + x[bias]
            if body is not None and body.size:
                val = val + x[body]
            hs.append(val)
            if jacobian:
                assert jac is not None
                row = np.zeros((3, self.n))
                row[:, dst] = jac[:, src]
                if bias is not None and bias.size:
                    row[:, bias] = np.eye(3)
                if body is not None and body.size:
                    row[:, body] = np.eye(3)
                hj.append(row)

        if self.order >= 1:
            add(s.gyr_u, s.J_gyr_u, self.i_bu)
        add(s.acc_u, s.J_acc_u, None, self.i_au)
        if with_f:
            if self.order >= 1:
                add(s.gyr_f, s.J_gyr_f, self.i_bf)
            add(s.acc_f, s.J_acc_f, None, self.i_af)
        if self.params.camera and m.elbow is not None:
            add(s.elbow, s.J_elbow)
            if self.use_forearm and m.wrist is not None:
                add(s.wrist, s.J_wrist)
        h = np.concatenate(hs)
        return h, (np.vstack(hj) if jacobian else np.zeros((0, self.n)))
