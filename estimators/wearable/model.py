"""State-space model of the wearable filter (paper §2.2, eqs. 1–4, 16–19).

State (column vector, radians): the kinematic block ``[θ̈_J, θ̇_J, θ_J]`` of the estimated
joints J (eq. 1; order 2, model A), ``[θ̇_J, θ_J]`` (order 1, models B and C) or ``[θ_J]``
(order 0, the inclinometer model "I" of §3.1), then optionally the gyro biases of the upper-arm
and forearm IMUs (rad/s, 3 each; the product's addition, random constants with a slow walk),
then for model B the body accelerations of each IMU in its own frame (m/s², 3 each, GM-1)
or for model A the accelerometer biases, then the product's mounting states (rad, 3 + 2), the
upper arm's soft-tissue gain (1) and last the camera's joint-centre offsets (m, elbow and wrist
in S, 3 each) (:mod:`.mounting`).

``F`` is eq. 3 (and its order-1/0 analogues), ``Q`` eq. 4 with the noise on the top derivative
only. Measurements (eq. 16) are stacked per available sensor: upper-arm gyro and accelerometer,
forearm gyro and accelerometer, camera elbow and wrist positions; without a camera sample the
position rows are left out (σp² = ∞), never given a large variance. ``R`` is eq. 19.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from estimators.wearable import dh, kernel, mounting
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
    i_au: I64  # model B body accelerations, or model A accelerometer biases (product)
    i_af: I64
    use_forearm: bool
    src_cols: I64  # columns of dh's Jacobians ([θ̈ 5, θ̇ 5, θ 5]) that the state has ...
    dst_cols: I64  # ... and where they go in the state
    # the compiled kernel's view of the same (estimators.wearable.kernel)
    theta_idx: I64  # (3, 5) state index of θ̈, θ̇, θ of each joint, −1 if not estimated
    bias_idx: I64  # (6, 3) gyro-bias state added to each sensor slot's row, −1 if none
    body_idx: I64  # (6, 3) additive accelerometer state (B: body acceleration; A: bias), −1: none
    q_rate: F64  # (n,) process noise variance per second of each state (eq. 4)
    gm: I64  # GM-1 states (model B)
    r_slot: F64  # (6,) noise variance of each slot's rows (eq. 19)
    geo_args: tuple[float, float, F64, F64, F64, F64]  # lu, lf, r_u, R_UI, r_f, R_FI
    packed: tuple[I64, F64]  # all of the above for kernel.ekf_step_packed / kernel.emit
    i_mu: I64  # mounting-misalignment states (.mounting)
    i_mf: I64
    mis_idx: I64  # (6, 5) δ states of each slot's IMU, −1: none; 1: the exact turn; c's state
    mis_basis: F64  # (6, 3, 3) their directions in the IMU frame (.mounting)
    i_cam: I64  # the camera's joint-centre offsets (elbow xyz, wrist xyz in S), added to its rows
    i_st: I64  # the upper-arm IMU's soft-tissue gain c: it turns with (1 + c)·θ2 (.mounting)

    @classmethod
    def build(cls, p: WearableParams, camera_offsets: bool = True) -> Model:
        """The model of ``p``; ``camera_offsets=False`` leaves out the camera's offset states
        (the last six), which the tracker adds with the first camera message
        (:func:`.tracker.add_camera_offsets`)."""
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
        # model B's GM-1 body accelerations, or the product's accelerometer biases (model A):
        # additive states of the accelerometer rows either way
        acc = p.model == "B" or (p.model == "A" and p.acc_bias)
        i_au = take(3 if acc else 0)
        i_af = take(3 if acc and use_f else 0)
        i_mu = take(3 if p.mounting_states else 0)
        i_mf = take(2 if p.mounting_states and use_f else 0)
        i_st = take(1 if p.soft_tissue_sigma > 0 and p.mounting_states else 0)
        i_cam = take(6 if camera_offsets and wants_camera_offsets(p) else 0)
        mis_idx = np.full((6, 5), -1, dtype=np.intp)
        if i_st.size:
            mis_idx[kernel.GYR_U, 4] = mis_idx[kernel.ACC_U, 4] = i_st[0]
        basis = np.zeros((6, 3, 3))
        for slots, idx in (
            ((kernel.GYR_U, kernel.ACC_U), i_mu),
            ((kernel.GYR_F, kernel.ACC_F), i_mf),
        ):
            if idx.size:
                # upper arm: every axis; forearm: across its long axis only (.mounting)
                b = np.eye(3) if idx is i_mu else _across_long_axis(p.geometry().R_FI)
                for slot in slots:
                    mis_idx[slot, : idx.size] = idx
                    mis_idx[slot, 3] = p.mounting_turn == "exact"
                    basis[slot, :, : idx.size] = b
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
        theta_idx = np.full((3, 5), -1, dtype=np.intp)
        for c, j in enumerate(joints):
            for row, idx in ((0, i_dd), (1, i_d), (2, i_th)):
                if idx.size:
                    theta_idx[row, j] = idx[c]
        bias_idx = np.full((6, 3), -1, dtype=np.intp)
        body_idx = np.full((6, 3), -1, dtype=np.intp)
        for slot, idx in (
            (kernel.GYR_U, i_bu),
            (kernel.GYR_F, i_bf),
            (kernel.ELBOW, i_cam[:3]),
            (kernel.WRIST, i_cam[3:]),
        ):
            if idx.size:
                bias_idx[slot] = idx
        for slot, idx in ((kernel.ACC_U, i_au), (kernel.ACC_F, i_af)):
            if idx.size:
                body_idx[slot] = idx
        # eq. 4: the discrete variance per q_ref_dt_s step, scaled with the step (∝ ts)
        q_rate = np.zeros(k)
        top = (i_dd, i_d, i_th)[2 - order]
        sig = (p.sigma_theta_deg, p.sigma_dtheta_dps, p.sigma_ddtheta_dps2)[order]
        q_rate[top] = (sig * DEG) ** 2 / p.q_ref_dt_s
        q_rate[i_bu] = (p.gyro_bias_walk_dps_per_sqrt_s * DEG) ** 2
        q_rate[i_bf] = (p.gyro_bias_walk_dps_per_sqrt_s * DEG) ** 2
        q_rate[i_mu] = (p.mounting_walk_deg_per_sqrt_s * DEG) ** 2
        q_rate[i_mf] = (p.mounting_walk_deg_per_sqrt_s * DEG) ** 2
        if p.model == "A":  # accelerometer biases: a random walk (B's GM-1 is in kernel.fq)
            q_rate[i_au] = q_rate[i_af] = p.acc_bias_walk_ms2_per_sqrt_s**2
        sg, sa, sp = (p.sigma_gyr_dps * DEG) ** 2, p.sigma_acc_ms2**2, p.sigma_pos_m**2
        geo = p.geometry()
        f = np.float64
        gm = (
            np.concatenate((i_au, i_af)).astype(np.intp) if p.model == "B" else np.zeros(0, np.intp)
        )
        r_slot = np.array([sg, sa, sg, sa, sp, sp])
        geo_args = (
            float(geo.upper_arm_m),
            float(geo.forearm_m),
            np.ascontiguousarray(geo.r_u, dtype=f),
            np.ascontiguousarray(geo.R_UI, dtype=f),
            np.ascontiguousarray(geo.r_f, dtype=f),
            np.ascontiguousarray(geo.R_FI, dtype=f),
        )
        src_a, dst_a = np.array(src, dtype=np.intp), np.array(dst, dtype=np.intp)
        ia, fa = kernel.pack(
            order,
            k,
            p.model == "A",
            theta_idx,
            bias_idx,
            body_idx,
            src_a,
            dst_a,
            gm,
            geo_args,
            p.body_acc_tau_s,
            p.body_acc_sigma_ms2**2,
            r_slot,
            q_rate,
        )
        # fa's tail (after q_rate): the elbow flexion beyond which c learns (.mounting)
        packed = (ia, np.append(fa, p.soft_tissue_min_elbow_deg * DEG))
        return cls(
            p,
            geo,
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
            src_a,
            dst_a,
            theta_idx,
            bias_idx,
            body_idx,
            q_rate,
            gm,
            r_slot,
            geo_args,
            packed,
            i_mu,
            i_mf,
            mis_idx,
            basis,
            i_cam,
            i_st,
        )

    # ------------------------------------------------------------------ process (eqs. 3, 4)
    def transition(self, ts: float) -> tuple[F64, F64]:
        """``F`` (eq. 3) and ``Q`` (eq. 4) for a step of ``ts`` s."""
        f, q = kernel.fq(*self.process_args(ts))
        return f, np.diag(q)

    def process_args(self, ts: float) -> tuple[Any, ...]:
        """The arguments of :func:`kernel.fq` (and, after ``n``, of :func:`kernel.predict`)."""
        p = self.params
        return (
            ts,
            self.n,
            self.order,
            self.i_dd,
            self.i_d,
            self.i_th,
            self.q_rate,
            self.gm,
            p.body_acc_tau_s,
            p.body_acc_sigma_ms2**2,
        )

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
        if p.model == "A":  # the accelerometer biases (acc_bias)
            s0 = p.acc_bias_sigma_ms2
        elif p.body_acc_init_sigma_ms2 is None:  # model B's body accelerations
            s0 = 0.1 * p.body_acc_sigma_ms2
        else:
            s0 = p.body_acc_init_sigma_ms2
        var[self.i_au] = s0**2
        var[self.i_af] = s0**2
        var[self.i_mu] = (p.mounting_sigma_deg * DEG) ** 2
        var[self.i_mf] = (p.mounting_sigma_deg * DEG) ** 2
        var[self.i_cam] = p.camera_offset_sigma_m**2
        var[self.i_st] = p.soft_tissue_sigma**2
        return x, np.diag(var)

    def full_theta(self, x: F64) -> tuple[F64, F64, F64]:
        """θ, θ̇, θ̈ (5,) of all joints from the state; joints not estimated are 0."""
        th, d, dd = kernel.joint_values(x, self.theta_idx)
        return th, d, dd

    # ------------------------------------------------------------------ measurements
    def slots(self, m: Measurement) -> tuple[F64, NDArray[np.bool_]]:
        """The readings ``z`` (6, 3) in kernel slot order and which slots this step measures
        (``have`` (6,) bool): the camera rows are left out without a camera sample (σp² = ∞)."""
        z = np.zeros((6, 3))
        z[kernel.GYR_U], z[kernel.ACC_U] = m.gyr_u, m.acc_u
        fore = m.gyr_f is not None and m.acc_f is not None
        if fore:
            z[kernel.GYR_F], z[kernel.ACC_F] = m.gyr_f, m.acc_f
        if m.elbow is not None:
            z[kernel.ELBOW] = m.elbow
        if m.wrist is not None:
            z[kernel.WRIST] = m.wrist
        have = self.measured(
            np.array([fore]), np.array([m.elbow is not None]), np.array([m.wrist is not None])
        )
        return z, have[0]

    def measured(
        self, fore: NDArray[np.bool_], elbow: NDArray[np.bool_], wrist: NDArray[np.bool_]
    ) -> NDArray[np.bool_]:
        """Which slots steps measure (``have`` (N, 6) bool) from what each step has (N,):
        a forearm sample, a camera elbow and wrist. The camera rows are left out without a
        camera sample (σp² = ∞); the gyros measure nothing in the order-0 model."""
        have = np.zeros((len(fore), 6), dtype=np.bool_)
        have[:, kernel.GYR_U] = self.order >= 1
        have[:, kernel.ACC_U] = True
        f = fore & self.use_forearm
        have[:, kernel.GYR_F] = f & (self.order >= 1)
        have[:, kernel.ACC_F] = f
        cam = elbow & self.params.camera
        have[:, kernel.ELBOW] = cam
        have[:, kernel.WRIST] = cam & wrist & self.use_forearm
        return have

    def rows(self, m: Measurement) -> tuple[F64, F64]:
        """The measurement vector ``z`` and the diagonal of ``R`` (eq. 19) for what ``m`` holds."""
        z, have = self.slots(m)
        zv, rv = kernel.stack(z, have, self.r_slot)
        return zv, rv

    def measure_args(self, jacobian: bool) -> tuple[Any, ...]:
        """The arguments of :func:`kernel.measure` after ``x`` and ``have``."""
        return (
            self.theta_idx,
            self.src_cols,
            self.dst_cols,
            self.bias_idx,
            self.body_idx,
            *self.geo_args,
            self.params.model == "A",
            jacobian,
        )

    def predict_rows(self, x: F64, m: Measurement, jacobian: bool = True) -> tuple[F64, F64]:
        """``h(x)`` and its Jacobian ``H`` (rows as :meth:`rows`, columns the state)."""
        _, have = self.slots(m)
        if self.i_mu.size:
            h, H = mounting.measure(x, have, *self.packed, self.mis_idx, self.mis_basis, jacobian)
        else:
            h, H = kernel.measure(x, have, *self.measure_args(jacobian))
        return h, (H if jacobian else np.zeros((0, self.n)))


def wants_camera_offsets(p: WearableParams) -> bool:
    """Whether the model carries the camera's offset states once there is a camera."""
    return p.camera and p.camera_offset_sigma_m > 0


def _across_long_axis(r_seg_imu: F64) -> F64:
    """Two unit vectors (3, 2) in the IMU frame across the segment's long axis (the segment
    frame's z): the directions of the mounting states (:mod:`.mounting`)."""
    a = r_seg_imu.T @ np.array([0.0, 0.0, 1.0])
    u = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
    u /= np.linalg.norm(u)
    return np.column_stack((u, np.cross(a, u)))
