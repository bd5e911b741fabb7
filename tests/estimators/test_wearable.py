"""Wearable estimator (Alizadegan & Behzadipour 2016): kinematics, model, filters, streaming.

Expectations are independent of the estimator's code: contract §8's rotations through scipy,
IMU readings by numerical differentiation (simulator.wearable_arm), finite differences for the
Jacobians, the paper's equations for F and the measurement rows.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimators.wearable import dh, kernel, steps, tracker
from estimators.wearable.model import Measurement, Model
from estimators.wearable.params import WearableParams, WearableParamsError
from simulator.wearable_arm import Mount, imu_readings, joint_positions

DEFAULT_R = Rotation.from_quat([0.5, 0.5, -0.5, 0.5]).as_matrix()  # scipy: [x, y, z, w]
MU = Mount(np.array([0.0, -0.04, -0.24]), DEFAULT_R)
MF = Mount(np.array([0.0, -0.03, -0.20]), DEFAULT_R)
SIG_G = np.radians(np.sqrt(0.1))  # table 5
SIG_A = 0.1


def _motion(amp_deg: tuple[float, ...], freq: float, rest: float = 2.0):
    """θ(t): at rest in the zero pose for ``rest`` s, then smooth sinusoids (rad)."""
    amp = np.radians(np.asarray(amp_deg, dtype=float))
    phase = np.array([0.0, 0.7, 1.3, 0.4, 2.1])

    def fn(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        s = np.clip(t - rest, 0.0, None)
        ramp = np.where(s < 1.0, s**3 * (10 - 15 * s + 6 * s * s), 1.0)  # smoothstep
        w = 2 * np.pi * freq * np.array([1.0, 0.8, 0.6, 1.1, 0.9])
        base = 0.5 * (1 - np.cos(w * s[:, None] + 0 * phase))
        out = amp * ramp[:, None] * base
        out[:, 3] = np.abs(out[:, 3])
        return out

    return fn


def _session(fn, fs=100.0, dur=12.0, seed=0, camera=False, cam_sigma=0.01):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, dur, 1.0 / fs)
    gu, au = imu_readings(fn, t, 0, MU, 0.30)
    gf, af = imu_readings(fn, t, 1, MF, 0.30)
    msgs = []
    n = 10
    for k in range(0, len(t), n):
        sl = slice(k, k + n)
        msgs.append(
            (
                "upperarm",
                t[sl],
                gu[sl] + rng.normal(0, SIG_G, gu[sl].shape),
                au[sl] + rng.normal(0, SIG_A, au[sl].shape),
            )
        )
        msgs.append(
            (
                "forearm",
                t[sl],
                gf[sl] + rng.normal(0, SIG_G, gf[sl].shape),
                af[sl] + rng.normal(0, SIG_A, af[sl].shape),
            )
        )
        if camera:
            tc = t[sl][::3]
            e, w = joint_positions(fn(tc), 0.30, 0.25)
            msgs.append(
                (
                    "camera",
                    tc,
                    e + rng.normal(0, cam_sigma, e.shape),
                    w + rng.normal(0, cam_sigma, w.shape),
                )
            )
    return t, msgs


def _rand_theta(rng):
    return rng.uniform(-1.4, 1.4, 5)


def test_dh_chain_is_the_contract_rotations():
    rng = np.random.default_rng(0)
    for _ in range(20):
        th = _rand_theta(rng)
        ps = dh.pose(th, 0.3, 0.25)
        su = Rotation.from_euler("YXZ", [-th[0], -th[1], th[2]])
        sf = su * Rotation.from_euler("YZ", [-th[3], th[4]])
        np.testing.assert_allclose(ps.R_SU, su.as_matrix(), atol=1e-12)
        np.testing.assert_allclose(ps.R_SF, sf.as_matrix(), atol=1e-12)
        np.testing.assert_allclose(ps.elbow, su.apply([0, 0, -0.3]), atol=1e-12)
        np.testing.assert_allclose(
            ps.wrist, su.apply([0, 0, -0.3]) + sf.apply([0, 0, -0.25]), atol=1e-12
        )


def test_dh_row_is_eq10():
    r, p = dh.dh(0.3, 0.2, -0.7, 0.1)
    h = np.eye(4)
    for m in (
        Rotation.from_euler("z", 0.3),
        [0, 0, 0.2],
        Rotation.from_euler("x", -0.7),
        [0.1, 0, 0],
    ):
        step = np.eye(4)
        if isinstance(m, Rotation):
            step[:3, :3] = m.as_matrix()
        else:
            step[:3, 3] = m
        h = h @ step
    np.testing.assert_allclose(r, h[:3, :3], atol=1e-12)
    np.testing.assert_allclose(p, h[:3, 3], atol=1e-12)


def test_default_mounting_and_zero_pose_reading():
    # contract §8: IMU x along the segment toward the distal joint, y forward, z lateral (−y_S)
    R = dh.quat_to_matrix((0.5, 0.5, 0.5, -0.5))
    np.testing.assert_allclose(R[:, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(R[:, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R[:, 2], [0, -1, 0], atol=1e-12)
    geo = WearableParams().geometry()
    s = dh.sensors(np.zeros(5), np.zeros(5), np.zeros(5), geo, jacobian=False)
    np.testing.assert_allclose(s.acc_u, [-9.81, 0, 0], atol=1e-12)  # x points down
    np.testing.assert_allclose(s.acc_f, [-9.81, 0, 0], atol=1e-12)


def test_predicted_readings_match_differentiated_motion():
    """Eqs. 12–18 against readings obtained by differentiating positions and rotations."""
    fn = _motion((60, 30, 40, 80, 50), 0.7, rest=0.0)
    geo = WearableParams().geometry()
    t = np.array([0.3, 1.1, 2.7])
    gu, au = imu_readings(fn, t, 0, MU, 0.30)
    gf, af = imu_readings(fn, t, 1, MF, 0.30)
    h = 1e-4
    for k, tk in enumerate(t):
        th = fn(tk)[0]
        d = (fn(tk + h)[0] - fn(tk - h)[0]) / (2 * h)
        dd = (fn(tk + h)[0] - 2 * th + fn(tk - h)[0]) / h**2
        s = dh.sensors(th, d, dd, geo, jacobian=False)
        np.testing.assert_allclose(s.gyr_u, gu[k], atol=1e-6)
        np.testing.assert_allclose(s.gyr_f, gf[k], atol=1e-6)
        np.testing.assert_allclose(s.acc_u, au[k], atol=1e-4)
        np.testing.assert_allclose(s.acc_f, af[k], atol=1e-4)


@pytest.mark.parametrize("mounting", ["first_order", "exact", None])
@pytest.mark.parametrize("model", ["A", "B", "C", "I"])
def test_jacobian_matches_finite_differences(model, mounting):
    turn = mounting or "first_order"
    p = WearableParams(model=model, mounting_states=mounting is not None, mounting_turn=turn)
    p = replace(p, acc_bias=model == "A")  # accelerometer biases are model A's only
    mdl = Model.build(p)
    rng = np.random.default_rng(3)
    x = rng.normal(0, 0.8, mdl.n)
    m = Measurement(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    _, H = mdl.predict_rows(x, m)
    Hn = np.empty_like(H)
    for i in range(mdl.n):
        e = np.zeros(mdl.n)
        e[i] = 1e-6
        Hn[:, i] = (
            mdl.predict_rows(x + e, m, False)[0] - mdl.predict_rows(x - e, m, False)[0]
        ) / 2e-6
    np.testing.assert_allclose(H, Hn, atol=1e-6)


def test_process_model_eq3_eq4():
    p = WearableParams(
        gyro_bias=False, mounting_states=False, acc_bias=False, camera_offset_sigma_m=0.0
    )
    mdl = Model.build(p)
    ts = 0.01
    f, q = mdl.transition(ts)
    x = np.random.default_rng(0).normal(size=15)
    dd, d, th = x[:5], x[5:10], x[10:]
    y = f @ x
    np.testing.assert_allclose(y[:5], dd)  # GM-1 joint acceleration, eq. 3 first block row
    np.testing.assert_allclose(y[5:10], d + ts * dd)
    np.testing.assert_allclose(y[10:], th + ts * d + 0.5 * ts**2 * dd)
    # eq. 4: noise on θ̈ only, σ² = 1 (°/s²)² per 1 ms step (table 5), scaled with the step
    np.testing.assert_allclose(np.diag(q)[:5], np.radians(1.0) ** 2 * 10)
    assert not np.diag(q)[5:].any()


@pytest.mark.parametrize("model", ["A", "B", "C", "I"])
def test_compiled_predict_and_ekf_step_equal_the_dense_equations(model: str) -> None:
    """The kernel's structured predict equals F P Fᵀ + Q, and its one-call EKF step equals
    the textbook update with the model's h and H (K = P Hᵀ S⁻¹, P⁺ = P − K S Kᵀ)."""
    from estimators.wearable import filters

    mdl = Model.build(WearableParams(model=model))  # type: ignore[arg-type]
    rng = np.random.default_rng(3)
    x = rng.normal(scale=0.3, size=mdl.n)
    x[mdl.theta_idx[2, 3]] = 1.0  # a bent elbow: the soft-tissue gain learns (.mounting)
    a = rng.normal(size=(mdl.n, mdl.n))
    P = a @ a.T * 1e-3 + np.eye(mdl.n) * 1e-4
    ts = 0.01
    f, q = mdl.transition(ts)
    xp, Pp = filters.predict(mdl, x, P, ts)
    np.testing.assert_allclose(xp, f @ x, atol=1e-12)
    np.testing.assert_allclose(Pp, f @ P @ f.T + q, atol=1e-12)
    g = np.array([0.1, -0.2, 0.3])
    acc = np.array([0.5, 9.7, -0.4])
    m = Measurement(g, acc, -g, acc[::-1].copy(), np.array([0.0, -0.05, -0.3]))
    z, r = mdl.rows(m)
    h, H = mdl.predict_rows(xp, m)
    S = H @ Pp @ H.T + np.diag(r)
    K = Pp @ H.T @ np.linalg.inv(S)
    xn, Pn, nis = filters.ekf_step(mdl, x, P, ts, m)
    np.testing.assert_allclose(xn, xp + K @ (z - h), atol=1e-9)
    np.testing.assert_allclose(Pn, Pp - K @ S @ K.T, atol=1e-12)
    assert nis == pytest.approx((z - h) @ np.linalg.solve(S, z - h) / len(z))


def test_mounting_states_learn_a_misalignment_from_the_camera():
    """IMUs strapped a few degrees off their nominal mounting: with the camera the product's
    mounting states find the misalignment and the flexion angles lose the error it causes;
    the paper's model (mounting taken as exact) keeps it."""
    rot = [np.radians([1.5, -2.0, 4.0]), np.radians([-3.0, 2.5, -4.0])]  # S axes, rad
    mu = Mount(MU.position, Rotation.from_rotvec(rot[0]).as_matrix() @ DEFAULT_R)
    mf = Mount(MF.position, Rotation.from_rotvec(rot[1]).as_matrix() @ DEFAULT_R)
    fn = _motion((60, 20, 20, 70, 30), 0.3)
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 30.0, 0.01)
    gu, au = imu_readings(fn, t, 0, mu, 0.30)
    gf, af = imu_readings(fn, t, 1, mf, 0.30)
    msgs = []
    for k in range(0, len(t), 10):
        sl = slice(k, k + 10)
        for seg, g, a in (("upperarm", gu, au), ("forearm", gf, af)):
            noise_g = rng.normal(0, SIG_G, g[sl].shape)
            msgs.append((seg, t[sl], g[sl] + noise_g, a[sl] + rng.normal(0, SIG_A, a[sl].shape)))
        tc = t[sl][::3]
        e, w = joint_positions(fn(tc), 0.30, 0.25)
        msgs.append(("camera", tc, e + rng.normal(0, 0.01, e.shape), w + rng.normal(0, 0.01, 3)))
    truth = np.degrees(fn(t))
    late = t >= 15.0
    err = {}
    for label, p in (
        ("product", WearableParams()),
        (
            "paper",
            WearableParams(
                gyro_bias=False, acc_bias=False, mounting_states=False, camera_offset_sigma_m=0.0
            ),
        ),
    ):
        rows, st = tracker.run(p, msgs)
        err[label] = [
            np.sqrt(np.mean((rows[c][late] - truth[late, i]) ** 2))
            for i, c in ((0, "shoulder_flexion_deg"), (3, "elbow_flexion_deg"))
        ]
        if label == "product":
            mdl = st.model
            # δ is a rotation vector in the IMU frame (R_nomᵀ · the S-axis vector here, the
            # zero pose's segment axes being S's); the forearm's states are the parts across
            # its long axis (a turn about it is the pronation's)
            for idx, slot, r in ((mdl.i_mu, 0, rot[0]), (mdl.i_mf, 2, rot[1])):
                want = mdl.mis_basis[slot][:, : idx.size].T @ (DEFAULT_R.T @ r)
                np.testing.assert_allclose(np.degrees(st.x[idx]), np.degrees(want), atol=1.0)
    assert max(err["product"]) < 1.0
    assert min(err["paper"]) > 2.0 * max(err["product"])


def test_soft_tissue_gain_learns_only_across_a_bent_elbow() -> None:
    """At a straight elbow no sensor tells the upper arm's strap turning with c·θ2 from θ2
    itself, so the EKF leaves c (and its variance) alone there; across a bent elbow it learns."""
    from estimators.wearable import filters

    mdl = Model.build(WearableParams())
    c = int(mdl.i_st[0])
    x = np.zeros(mdl.n)
    x[mdl.theta_idx[2, 2]], x[mdl.theta_idx[1, 2]] = 0.8, 1.0  # θ2, θ̇2: the arm rotating
    P = np.eye(mdl.n) * 1e-3
    P[c, c] = 0.1**2
    m = Measurement(np.array([0.3, 0.2, -0.1]), np.array([0.4, 9.6, 0.3]))
    for elbow, learns in ((0.2, False), (1.2, True)):
        x[mdl.theta_idx[2, 3]] = elbow
        xn, Pn, _ = filters.ekf_step(mdl, x, P, 0.0, m)
        assert (xn[c] != x[c]) == learns, elbow
        assert (Pn[c, c] < P[c, c]) == learns, elbow


@pytest.mark.parametrize("camera", [True, False], ids=["camera", "no-camera"])
def test_soft_tissue_gain_is_found_in_the_rom_moves(camera: bool) -> None:
    """The simulator's upper-arm strap turns with 1.10·θ2 (sta_upper = 0.10; the filter's
    prior is 0 ± 0.1): the ROM moves' rotations at a bent elbow find it."""
    from simulator import wearable as w

    for seed in (0, 1):
        cfg = w.WearableSimConfig(move="rom", duration_s=60.0, seed=seed, camera=camera)
        sim = w.simulate(cfg)
        _, st = tracker.run(WearableParams.from_json(sim.params), w.tracker_inputs(sim.messages))
        assert st.x[st.model.i_st[0]] == pytest.approx(cfg.imu.sta_upper, abs=0.03), seed


def test_camera_offsets_join_with_the_first_camera_message_as_if_from_the_start() -> None:
    """A camera-less session never carries the camera's offset states; a session with a
    camera gets them with its first camera message, and that is the filter that had them from
    the start (independent of everything until a camera row)."""
    from simulator import wearable as w

    sim = w.simulate(w.WearableSimConfig(move="reaching", duration_s=8.0, seed=4))
    p = WearableParams.from_json(sim.params)
    msgs = w.tracker_inputs(sim.messages)
    assert msgs[0][0] != "camera"
    rows, st = tracker.run(p, msgs)
    assert st.model.i_cam.size == 6
    early = tracker.initial_state(p)
    tracker.add_camera_offsets(p, early)  # before any message
    parts = [tracker.feed(p, early, kind, t, u, v)[0] for kind, t, u, v in msgs]
    want = tracker.concat([*parts, tracker.flush(p, early)[0]])
    for key in tracker.ROW_KEYS:
        np.testing.assert_allclose(rows[key], want[key], rtol=0, atol=1e-9, err_msg=key)
    none = [m for m in msgs if m[0] != "camera"]
    _, st = tracker.run(p, none)
    assert st.model.i_cam.size == 0 and st.model.n == early.model.n - 6


def test_elbow_mounting_term_signs_a_relative_turn() -> None:
    """Without a camera the elbow's σ takes the two IMUs' departures about its axis with
    signs: both straps turned the same way is the whole arm turned (no elbow error), turned
    apart is an elbow error of both turns together."""
    mdl = Model.build(WearableParams())
    zero = dh.pose(np.zeros(5), mdl.geo.upper_arm_m, mdl.geo.forearm_m)
    pairs, signs = tracker._mounting_pairs(mdl, zero)
    k_u, k_f = pairs[:, 3]
    assert k_u in mdl.i_mu and k_f in mdl.i_mf

    def along(idx: np.ndarray, slot: int, R_seg: np.ndarray, R_xi: np.ndarray, k: int) -> float:
        dirs = R_seg @ R_xi @ mdl.mis_basis[slot][:, : idx.size]  # the states' axes in S
        return float(zero.axes[3] @ dirs[:, list(idx).index(k)])

    p_u = along(mdl.i_mu, 0, zero.R_SU, mdl.geo.R_UI, k_u)
    p_f = along(mdl.i_mf, 2, zero.R_SF, mdl.geo.R_FI, k_f)
    eps = 0.1  # rad about the elbow's axis: each state's share of it
    together = signs[0, 3] * p_u * eps + signs[1, 3] * p_f * eps
    apart = signs[0, 3] * p_u * eps - signs[1, 3] * p_f * eps
    assert abs(together) < 1e-9
    assert abs(apart) == pytest.approx(2 * eps, rel=1e-6)


def test_camera_rows_are_left_out_without_camera():
    mdl = Model.build(WearableParams())
    z3 = np.zeros(3)
    z, r = mdl.rows(Measurement(z3, z3, z3, z3))
    assert len(z) == 12 and len(r) == 12
    z, r = mdl.rows(Measurement(z3, z3, z3, z3, z3, z3))
    assert len(z) == 18
    np.testing.assert_allclose(r[12:], 1e-4)  # σp² of table 5
    np.testing.assert_allclose(r[:3], np.radians(np.sqrt(0.1)) ** 2)


def test_params_from_json_contract_keys_and_refusals():
    p = WearableParams.from_json(
        {
            "mode": "wearable",
            "side": "right",
            "upper_arm_length_m": 0.31,
            "forearm_length_m": 0.26,
            "filter": "ukf",
            "model": "B",
            "upperarm_imu": {"position_m": [0.0, -0.05, -0.2], "quat": [0.5, 0.5, 0.5, -0.5]},
        }
    )
    assert p.filter == "ukf" and p.model == "B" and p.upper_arm_length_m == 0.31
    assert p.upperarm_imu.position_m == (0.0, -0.05, -0.2)
    for bad in (
        {"side": "up"},
        {"model": "D"},
        {"filter": "pf"},
        {"upper_arm_length_m": "x"},
        {"upperarm_imu": {"quat": [1, 1, 0, 0]}},
        {"bogus": 1},
        {"mode": "robot"},
    ):
        with pytest.raises(WearableParamsError):
            WearableParams.from_json(bad)
    left = WearableParams.from_json({"side": "left"})
    assert left.upperarm_imu.position_m == (0.0, 0.04, -0.24)


def _rmse(a, b):
    return float(np.sqrt(np.nanmean((a - b) ** 2)))


def test_tracks_a_two_segment_motion_at_100hz():
    fn = _motion((50, 20, 30, 70, 40), 0.4)
    t, msgs = _session(fn, dur=10.0)
    rows, st = tracker.run(WearableParams(), msgs)
    assert len(rows["t"]) == len(t)
    truth = np.degrees(fn(t))
    names = tracker.COLUMNS[1:6]
    errs = [_rmse(rows[c][t > 2], truth[t > 2, i]) for i, c in enumerate(names)]
    assert errs[0] < 2.0 and errs[3] < 2.0, errs  # flexions: gravity + body acceleration
    assert max(errs) < 6.0, errs
    e, _ = joint_positions(fn(t), 0.30, 0.25)
    assert np.nanmax(np.abs(rows["elbow_x"] - e[:, 0])) < 0.05
    assert not st.rejected.get("forearm_missing")


def test_model_a_beats_uncompensated_models_with_body_acceleration():
    """Table 6's ordering on a fast one-segment flexion with the IMU near the elbow."""

    def fn(t):
        t = np.atleast_1d(t)
        out = np.zeros((len(t), 5))
        out[:, 0] = np.radians(90) * np.sin(2 * np.pi * t)
        return out

    rng = np.random.default_rng(5)
    t = np.arange(0, 6, 0.01)
    gu, au = imu_readings(fn, t, 0, MU, 0.30)
    gu = gu + rng.normal(0, SIG_G, gu.shape)
    au = au + rng.normal(0, SIG_A, au.shape)
    err = {}
    for model in "ABC":
        p = WearableParams(model=model, joints=(0,), forearm=False, gyro_bias=False)
        rows, _ = tracker.run(p, [("upperarm", t, gu, au)])
        err[model] = _rmse(rows["shoulder_flexion_deg"][t > 2], np.degrees(fn(t)[t > 2, 0]))
    assert err["A"] < 0.6 < err["B"] < err["C"], err


def test_body_acceleration_prior_is_selectable():
    """Model B's body-acceleration prior: a tenth of the GM-1's steady σ, or given (a random
    walk, eq. 3's form, has no steady σ to take it from); nonsense is refused."""
    base = WearableParams(model="B", joints=(0,), forearm=False, gyro_bias=False)
    walk = {"body_acc_tau_s": 1e6, "body_acc_sigma_ms2": 1e3}
    for kw, sigma in (({}, 0.5), (walk, 100.0), ({**walk, "body_acc_init_sigma_ms2": 0.02}, 0.02)):
        mdl = Model.build(replace(base, **kw))
        _, P0 = mdl.initial()
        assert len(mdl.i_au) == 3
        assert np.allclose(np.diag(P0)[mdl.i_au], sigma**2)
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(WearableParamsError):
            replace(base, body_acc_init_sigma_ms2=bad)


def test_streaming_equals_batch():
    fn = _motion((40, 20, 20, 60, 30), 0.5)
    _, msgs = _session(fn, dur=5.0, camera=True)
    p = WearableParams()
    batch, st_b = tracker.run(p, msgs)
    state = tracker.initial_state(p)
    parts = []
    for kind, tt, u, v in msgs:  # and each message cut into single samples
        for i in range(len(tt)):
            r, state = tracker.feed(p, state, kind, tt[i : i + 1], u[i : i + 1], v[i : i + 1])
            parts.append(r)
    r, state = tracker.flush(p, state)
    parts.append(r)
    stream = tracker.concat(parts)
    for c in (*tracker.COLUMNS, *tracker.STD_COLUMNS, "flags"):
        np.testing.assert_array_equal(stream[c], batch[c])
    assert st_b.rejected == state.rejected


def test_left_arm_is_the_mirror_image():
    fn = _motion((40, 25, 20, 60, 30), 0.5)
    _, msgs = _session(fn, dur=6.0, camera=True)
    right, _ = tracker.run(WearableParams(), msgs)
    flip_v = np.array([1.0, -1.0, 1.0])
    flip_w = np.array([-1.0, 1.0, -1.0])
    mirrored = []
    for kind, tt, u, v in msgs:
        if kind == "camera":
            mirrored.append((kind, tt, u * flip_v, v * flip_v))
        else:  # a left IMU mounted as the mirror image: x, −y, z for vectors, pseudovector rates
            mirrored.append((kind, tt, u * flip_w, v * flip_v))
    left, _ = tracker.run(WearableParams.from_json({"side": "left"}), mirrored)
    for c in tracker.COLUMNS[1:6]:
        np.testing.assert_allclose(left[c], right[c], atol=1e-6)
    np.testing.assert_allclose(left["elbow_y"], -right["elbow_y"], atol=1e-9)
    np.testing.assert_allclose(left["wrist_x"], right["wrist_x"], atol=1e-9)


def test_missing_forearm_is_flagged_and_empty():
    fn = _motion((40, 10, 10, 60, 20), 0.5)
    t, msgs = _session(fn, dur=4.0)
    only_upper = [m for m in msgs if m[0] == "upperarm"]
    rows, st = tracker.run(WearableParams(), only_upper)
    assert len(rows["t"]) == len(t)
    assert np.isnan(rows["elbow_flexion_deg"]).all() and np.isnan(rows["wrist_x"]).all()
    assert np.isfinite(rows["shoulder_flexion_deg"]).all()
    assert (rows["flags"].astype(int) & tracker.FOREARM_MISSING).all()
    assert st.rejected["forearm_missing"] == len(t)


def test_bad_samples_are_counted_not_crashing():
    fn = _motion((40, 10, 10, 60, 20), 0.5)
    _, msgs = _session(fn, dur=3.0)
    kind, tt, u, v = msgs[4]
    u = u.copy()
    u[2] = np.nan
    msgs[4] = (kind, tt, u, v)
    k2, t2, u2, v2 = msgs[8]
    v2 = v2.copy()
    v2[5] = [500.0, 0.0, 0.0]  # 50 g: beyond a body-worn IMU's range, a glitch
    msgs[8] = (k2, t2, u2, v2)
    msgs.insert(6, msgs[2])  # a repeated message: time going backwards
    rows, st = tracker.run(WearableParams(), msgs)
    assert st.rejected[f"nonfinite_{kind}"] == 1
    assert st.rejected[f"out_of_range_{k2}"] == 1
    assert st.rejected[f"time_backwards_{msgs[2][0]}"] == 10
    assert np.isfinite(rows["shoulder_flexion_deg"]).all()
    bad = tracker.feed(
        WearableParams(),
        tracker.initial_state(WearableParams()),
        "upperarm",
        np.zeros(3),
        np.zeros((2, 3)),
        np.zeros((3, 3)),
    )[1]
    assert bad.rejected["shape_upperarm"] == 1


def test_mounting_that_does_not_fit_is_flagged():
    fn = _motion((40, 10, 10, 60, 20), 0.5)
    _, msgs = _session(fn, dur=4.0)
    # the parameters claim the upper-arm IMU's x points forward, the data say down
    wrong = WearableParams.from_json(
        {"upperarm_imu": {"position_m": [0, -0.04, -0.24], "quat": [1.0, 0.0, 0.0, 0.0]}}
    )
    rows, st = tracker.run(wrong, msgs)
    assert st.rejected["mounting_mismatch_upperarm"] == 1
    late = rows["t"] >= 2.0
    assert np.isnan(rows["shoulder_flexion_deg"][late]).all()
    assert (rows["flags"][late].astype(int) & tracker.MOUNTING_MISMATCH).all()


def test_confidence_is_honest_about_the_vertical_without_camera():
    # at rest the gyros' bias about the vertical cannot be told from a slow turn of the arm
    fn = _motion((0, 0, 0, 0, 0), 0.3)
    t, msgs = _session(fn, dur=10.0)
    # the filter's own σ (no systematic floor: compares what the sensors tell)
    rows, _ = tracker.run(
        WearableParams(
            sigma_floor_deg=(0.0,) * 5,
            sigma_share=(0.0,) * 5,
            sigma_doubt=(0.0,) * 5,
            sigma_mounting_gain=0.0,
            sigma_elbow_split_deg=0.0,
        ),
        msgs,
    )
    v = rows["vertical_std_deg"]
    k5 = np.searchsorted(t, 5.0)
    assert np.all(np.diff(v[k5::100]) > 0)  # it only grows, at least as fast as a 0.1 °/s bias
    assert v[-1] - v[k5] > 0.1 * (t[-1] - t[k5])
    assert v[-1] > 5.0 * rows["elbow_flexion_std_deg"][-1]  # gravity keeps the flexion
    # moving, with a camera: the turn is seen, its σ stays far below the camera-less one
    fn = _motion((50, 20, 20, 60, 30), 0.3)
    t, msgs = _session(fn, dur=10.0)
    no_cam, _ = tracker.run(WearableParams(), msgs)
    t, msgs = _session(fn, dur=10.0, camera=True)
    cam, _ = tracker.run(WearableParams(), msgs)
    assert cam["vertical_std_deg"][-1] < 0.5 * no_cam["vertical_std_deg"][-1]


def test_camera_dropout_and_stale_samples():
    fn = _motion((40, 20, 20, 60, 30), 0.5)
    _, msgs = _session(fn, dur=6.0, camera=True)
    late = [m for m in msgs if m[0] != "camera"]
    cams = [m for m in msgs if m[0] == "camera"]
    # camera messages held back 0.5 s: stale when they come
    mixed = late[:60] + cams[:30] + late[60:] + cams[30:]
    rows, st = tracker.run(WearableParams(), mixed)
    assert st.rejected["camera_stale"] > 0
    assert np.isfinite(rows["shoulder_flexion_deg"]).all()
    assert ((rows["flags"].astype(int) & tracker.CAMERA_USED) > 0).sum() > 0


SURE = 7.5  # backend.live.wearable_run.SURE_STD_DEG (estimators' tests import no backend)
ANGLES_ALL = (
    "shoulder_flexion",
    "shoulder_abduction",
    "shoulder_rotation",
    "elbow_flexion",
    "forearm_pronation",
)


def _coverage(move: str, camera: bool, seed: int, dur: float = 30.0, **kw) -> dict[str, float]:
    """Share of the moving phase's rows with |error| <= 2 reported σ, per angle, on a session
    of the project's simulator (every error source on, none known to the filter); and
    (``<angle>_wrong``) the share shown sure (σ <= the dashboard's 7.5°) but wrong by more."""
    from simulator import wearable as w

    sim = w.simulate(w.WearableSimConfig(move=move, duration_s=dur, seed=seed, camera=camera))
    rows, _ = tracker.run(
        WearableParams.from_json(sim.params, **kw), w.tracker_inputs(sim.messages)
    )
    m = sim.t >= (6.0 if move == "shoulder_wheel" else 3.0)
    out = {}
    for j, a in enumerate(ANGLES_ALL):
        e = rows[f"{a}_deg"][m] - sim.theta_deg[m, j]
        s = rows[f"{a}_std_deg"][m]
        ok = np.isfinite(e)
        assert ok.mean() > 0.9
        out[a] = float(np.mean(np.abs(e[ok]) <= 2.0 * s[ok]))
        out[f"{a}_wrong"] = float(np.mean((s[ok] <= SURE) & (np.abs(e[ok]) > SURE)))
    return out


@pytest.mark.parametrize(
    ("move", "camera", "least"),
    [("shoulder_wheel", True, 0.95), ("reaching", False, 0.95), ("rom", False, 0.85)],
)
def test_reported_sigma_covers_the_error(move, camera, least):
    """Issue 19: the dashboard must never show an angle as surer than it is. The reported σ
    covers the error (~95 % within 2σ; here at least 95 % per angle on one 30-s session, 85 %
    on the ROM moves without a camera: 88 % abduction, 85 % elbow on this seed), while
    the filter's own P (the paper's figure, floors off) does not: the camera's offset and lag,
    scale errors and soft tissue are biases, not the white noise of eq. 19."""
    product = _coverage(move, camera, seed=7)
    off = {k: (0.0,) * 5 for k in ("sigma_floor_deg", "sigma_share", "sigma_doubt")}
    unseen = {"sigma_axial_share": 0.0, "pronation_drift_dps": 0.0}
    bare = _coverage(move, camera, seed=7, **off, **unseen, sigma_pronation_vertical_deg=0.0)
    for a in ANGLES_ALL:
        assert product[a] >= least, (a, product)
    assert min(bare.values()) < 0.5, bare  # the check can fail: P alone is over-confident
    # the dashboard never shows pronation as sure when it is off by more than 7.5° (soft
    # tissue, the strap's turn, a straight elbow, a hanging forearm); P alone does
    assert product["forearm_pronation_wrong"] <= 0.02, product
    assert bare["forearm_pronation_wrong"] > 0.05, bare


@pytest.mark.parametrize(
    ("move", "seed", "smaller"), [("reaching", 9, 0.0), ("shoulder_wheel", 410, 4.0)]
)
def test_camera_less_turn_about_the_vertical_is_not_shown_sure(move, seed, smaller):
    """Without a camera the whole arm's turn about the vertical can be off by more than the
    drift bound from the first movement after the rest (this reaching session, seed 9 of the
    sizing seeds: the shoulder's rotation shown sure but off by more than 7.5° on 2.9 % of
    the rows with the bound's start at ``init_sigma_deg``; the wheel's seed 410: 6.9 % with
    the start 4° above it, the default until 2026-12-05): ``vertical_init_deg`` keeps it
    grey (the first-order turn needed 12°, on the wheel's seed 9)."""
    product = _coverage(move, False, seed=seed, dur=60.0)
    bare = _coverage(move, False, seed=seed, dur=60.0, vertical_init_deg=smaller)
    for a in ("shoulder_abduction", "shoulder_rotation"):
        assert product[f"{a}_wrong"] <= 0.02, product
    assert bare["shoulder_rotation_wrong"] > 0.02, bare  # the check can fail


def test_camera_less_split_of_an_angle_and_its_mounting_is_not_shown_sure():
    """Without a camera the elbow and the forearm IMU's turn about the flexion axis are one
    quantity to gravity and the gyros; with the exact turn their split slides in the ROM
    moves (seed 1 of the sizing seeds: the elbow off by more than 7.5° while P says ~0.5°):
    the σ from the mounting states (``sigma_mounting_gain``) keeps it grey (alone: the σ of
    the unseen split, the next test's, holds this seed too)."""
    alone = {"sigma_elbow_split_deg": 0.0}
    product = _coverage("rom", False, seed=1, dur=60.0, **alone)
    bare = _coverage("rom", False, seed=1, dur=60.0, sigma_mounting_gain=0.0, **alone)
    assert product["elbow_flexion_wrong"] <= 0.02, product
    assert bare["elbow_flexion_wrong"] > 0.05, bare  # the check can fail


@pytest.mark.parametrize(
    ("camera", "seed", "angle"),
    [
        (False, 203, "shoulder_abduction"),
        (False, 300, "elbow_flexion"),
        (True, 210, "elbow_flexion"),
    ],
)
def test_a_mounting_state_that_has_just_moved_is_not_shown_sure(camera, seed, angle):
    """After the ROM moves' fast overhead flexion the upper arm's mounting states swing by
    5–25° and back within seconds (abduction 7–10° off meanwhile without a camera, seed 203),
    and the elbow's pair slides in the elbow moves (seed 300; with the camera, seed 210): the
    σ from the states' change from their 20-s average keeps the angle grey (the elbow's with
    a camera too; not the shoulder's there: the camera holds the overhead flexion, whose ROM
    test must record its peak, tests/backend/test_wearable_run.py). The σ of the elbow's
    unseen split is off here: alone, it holds seed 300's camera-less elbow too; so are the
    camera's dropout and disagreement terms (the last test's)."""
    alone = {
        "sigma_elbow_split_deg": 0.0,
        "sigma_dropout_share": 0.0,
        "sigma_camera_disagree_gain": 0.0,
    }
    product = _coverage("rom", camera, seed=seed, dur=60.0, **alone)
    off = {"sigma_mounting_change_gain": 0.0, "sigma_upper_change_gain": 0.0, **alone}
    bare = _coverage("rom", camera, seed=seed, dur=60.0, **off)
    assert product[f"{angle}_wrong"] <= 0.02, product
    assert bare[f"{angle}_wrong"] > 0.02, bare  # the check can fail


def test_exact_turn_keeps_the_start_free_of_a_long_accelerometer():
    """Seed 9's accelerometers read gravity ~2.5 % long (scale factors): the first-order turn
    explains it by the forearm's mounting state at ~14° and the elbow turns the other way at
    the start's rest, camera on; the exact turn keeps a rotation a rotation (both without the
    accelerometer-bias states, which take up part of it too)."""
    from simulator import wearable as w

    sim = w.simulate(w.WearableSimConfig(move="rom", duration_s=60.0, seed=9, camera=True))
    rest = (sim.t > 0.5) & (sim.t < 2.0)
    err = {}
    for turn in ("first_order", "exact"):
        rows, _ = tracker.run(
            WearableParams.from_json(sim.params, mounting_turn=turn, acc_bias=False),
            w.tracker_inputs(sim.messages),
        )
        err[turn] = np.max(np.abs(rows["elbow_flexion_deg"][rest] - sim.theta_deg[rest, 3]))
    assert err["first_order"] > 10.0, err  # the check can fail
    assert err["exact"] < 4.0, err


def test_doubt_after_a_large_rotation_fades_and_ignores_grouping():
    """The doubt term: the rotation's excess over ``doubt_rotation_deg`` held at its peak,
    fading with ``doubt_tau_s`` in sample time; the same numbers in any grouping."""
    p = WearableParams(doubt_rotation_deg=30.0, doubt_tau_s=40.0)
    t = 5.0 + np.arange(300) / 100.0
    rot = np.where(t < 6.0, 10.0 * (t - 5.0) * 6.0, np.nan)  # up to 60° by 6 s, then gone
    rot[200:] = 0.0

    def doubt(state: tracker.TrackerState, t: np.ndarray, rot: np.ndarray) -> np.ndarray:
        h = np.empty(len(t))
        steps.doubt_held(t, rot, state.doubt, p.doubt_rotation_deg, p.doubt_tau_s, h)
        return h

    whole = doubt(tracker.initial_state(p), t, rot)
    want = np.maximum.accumulate(
        np.maximum(np.nan_to_num(np.abs(rot)) - 30.0, 0.0) * np.exp(t / 40.0)
    )
    np.testing.assert_allclose(whole, want * np.exp(-t / 40.0), rtol=1e-12, atol=1e-250)
    assert whole[50] < 1e-250 and whole[-1] == pytest.approx(29.4 * np.exp(-2.0 / 40.0), rel=1e-9)
    state = tracker.initial_state(p)
    parts = [doubt(state, t[i : i + 7], rot[i : i + 7]) for i in range(0, 300, 7)]
    np.testing.assert_array_equal(np.concatenate(parts), whole)


def test_reported_sigma_widening_keeps_missing_angles_missing():
    p = WearableParams(
        sigma_floor_deg=(1.0, 1.0, 1.0, 2.0, 2.0),
        sigma_share=(0.1,) * 5,
        sigma_pronation_vertical_deg=3.0,
    )
    out = np.zeros((19, 2))
    out[9:12, 0] = (0.0, 0.3, -0.4)  # the forearm 0.8 (squared 0.64) vertical
    out[1:6, 0] = [10.0, 0.0, -20.0, 30.0, 0.0]
    out[12:17, 0] = 0.5
    out[4:6, 1] = np.nan
    out[15:17, 1] = np.nan
    tracker._widen(tracker.initial_state(p), out)
    want = np.sqrt(0.25 + np.array([1.0, 1.0, 1.0, 4.0, 4.0]) + (0.1 * out[1:6, 0]) ** 2)
    want[4] = np.sqrt(want[4] ** 2 + (3.0 * 0.64) ** 2)
    np.testing.assert_allclose(out[12:17, 0], want)
    assert np.isnan(out[15:17, 1]).all() and np.isfinite(out[12:15, 1]).all()
    with pytest.raises(WearableParamsError):
        WearableParams(sigma_share=(0.1, -0.1, 0.0, 0.0, 0.0))


def test_compiled_widening_matches_the_array_form_bit_for_bit():
    """The compiled σ widening (per row, any grouping) gives exactly the numbers of its
    array form (the previous numpy code, written out here), NaN angles included."""
    p = WearableParams()
    rng = np.random.default_rng(3)
    n = 400
    out = rng.normal(0.0, 40.0, (19, n))
    out[0] = 1.0 + np.arange(n) / 100.0
    out[6:12] = rng.normal(0.0, 0.3, (6, n))
    out[11, :250] = out[8, :250] - 1.0  # a hanging forearm for 2.5 s (pronation's drift)
    out[12:17] = np.abs(out[12:17]) / 10.0
    out[[3, 4, 5, 15, 16, 9, 10, 11], rng.integers(0, n, 8)] = np.nan
    floor2, share2, doubt2 = (
        np.square(np.array(v))[:, None] for v in (p.sigma_floor_deg, p.sigma_share, p.sigma_doubt)
    )
    g = np.abs(out[3]) - p.doubt_rotation_deg
    x = (out[0] - out[0, 0]) / p.doubt_tau_s
    h = np.exp(np.maximum.accumulate(np.log(np.fmax(g, 1e-300)) + x) - x)
    extra = floor2 + share2 * out[1:6] ** 2 + doubt2 * (h * h)
    d = (out[9:12] - out[6:9]) ** 2
    c2 = np.fmax(d[2] / np.maximum(d[0] + d[1] + d[2], 1e-12), 0.0)
    extra[4] += (p.sigma_pronation_vertical_deg * c2) ** 2
    # what no sensor sees (steps.unobserved), row by row from the previous row
    ax, dr = np.zeros(n), np.zeros(n)
    a = ap = b = 0.0
    axp = np.zeros(n)
    prev = (math.nan, math.nan, math.nan)
    for k in range(n):
        dt = out[0, k] - prev[0] if k else 0.0
        el = out[4, k]
        s = math.cos(math.radians(el)) ** 2 if np.isfinite(el) else 1.0
        mv = 0.0
        if np.isfinite(out[1, k]) and np.isfinite(out[2, k]):
            if np.isfinite(prev[1]):
                mv = abs(out[1, k] - prev[1]) + abs(out[2, k] - prev[2])
            prev = (out[0, k], out[1, k], out[2, k])
        else:
            prev = (out[0, k], prev[1], prev[2])
        a = a * math.exp(-dt * (1.0 - s) / p.axial_tau_s) + p.sigma_axial_share * s * mv
        ap = ap * math.exp(-dt * (1.0 - s) / p.pronation_axial_tau_s) + p.sigma_axial_share * s * mv
        axp[k] = ap
        b = max(0.0, b + dt * p.pronation_drift_dps * (2.0 * c2[k] - 1.0))
        ax[k], dr[k] = a, b
    extra[2] += ax * ax
    extra[4] += axp * axp
    extra[4] += dr * dr
    want = np.sqrt(out[12:17] ** 2 + extra)
    state = tracker.initial_state(p)
    got = out.copy()
    for i in range(0, n, 13):
        part = got[:, i : i + 13].copy()
        tracker._widen(state, part)
        got[:, i : i + 13] = part
    np.testing.assert_array_equal(got[12:17], want)
    assert np.isnan(want).any() and (h > 1.0).any()  # missing angles and the doubt in play
    assert (ax > 1.0).any() and (dr > 0.5).any()  # and what no sensor sees


def test_camera_less_elbow_is_not_sure_until_the_forearm_turns():
    """Without a camera the elbow's flexion and the forearm IMU's turn about the elbow's axis
    are one quantity until the forearm turns about its own axis: the ROM moves' fast shoulder
    tests (the forearm in neutral) split them to second order and left the straight elbow
    7.5° off at σ 4–5° for 8 s (seed 724, never used for sizing before: 13.8 % of the
    trial). The σ of the unseen split keeps it grey until the forearm has turned; then it is
    gone: a reaching session (the forearm turned ~55° after the start) reports the σ it
    reports without the term, and a camera's positions see the flexion from the start."""
    from simulator import wearable as w

    product = _coverage("rom", False, seed=724, dur=60.0)
    bare = _coverage("rom", False, seed=724, dur=60.0, sigma_elbow_split_deg=0.0)
    assert product["elbow_flexion_wrong"] <= 0.02, product
    assert bare["elbow_flexion_wrong"] > 0.05, bare  # the check can fail
    for camera in (False, True):
        sim = w.simulate(
            w.WearableSimConfig(move="reaching", duration_s=20.0, seed=0, camera=camera)
        )
        inputs = w.tracker_inputs(sim.messages)
        sd = {}
        for m in (7.0, 0.0):
            p = WearableParams.from_json(sim.params, sigma_elbow_split_deg=m)
            sd[m] = tracker.run(p, inputs)[0]["elbow_flexion_std_deg"]
        late = sim.t >= 10.0
        np.testing.assert_array_equal(sd[7.0][late], sd[0.0][late])
        start = (sim.t > 0.5) & (sim.t < 2.0)  # the start's rest, the forearm in neutral
        if camera:
            np.testing.assert_array_equal(sd[7.0][start], sd[0.0][start])
        else:
            assert np.all(sd[7.0][start] ** 2 >= sd[0.0][start] ** 2 + 6.9**2 - 1e-6)


def test_a_camera_dropout_is_not_shown_sure():
    """Issue 19's "a camera that drops out": never a silently wrong angle. Seed 935's ROM
    moves (the benchmark's validation seeds 900–999, not sized on): the camera drops out for
    2 s (8.3–10.3 s) as the abducted arm comes down; the elbow slides from 2 to 9° off on the
    IMUs' mountings alone, and the EKF's σ of it, 0.35°, lets the camera, back, pull it in only
    over seconds (still 7.6° off at 13 s). The σ grown with the arm's motion while the camera
    is away and, once it is back, its disagreement with the estimate keep the elbow grey;
    without a camera neither term exists."""
    from simulator import wearable as w

    off = {"sigma_dropout_share": 0.0, "sigma_camera_disagree_gain": 0.0}
    product = _coverage("rom", True, seed=935, dur=60.0)
    bare = _coverage("rom", True, seed=935, dur=60.0, **off)
    assert product["elbow_flexion_wrong"] <= 0.02, product
    assert bare["elbow_flexion_wrong"] > 0.04, bare  # the check can fail
    sim = w.simulate(w.WearableSimConfig(move="reaching", duration_s=10.0, seed=0, camera=False))
    inputs = w.tracker_inputs(sim.messages)
    a = tracker.run(WearableParams.from_json(sim.params), inputs)[0]
    b = tracker.run(WearableParams.from_json(sim.params, **off), inputs)[0]
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_camera_angles_explain_the_camera_by_a_change_of_pose():
    """The disagreement's least squares (``kernel.camera_angles``): positions of a pose a few
    degrees away give those degrees back (to second order), the offsets it is given are taken
    off first, and an angle that does not move the points (rotation with the elbow straight)
    takes none of the residual."""
    lu, lf = 0.30, 0.25
    th = np.radians([30.0, 20.0, 40.0, 60.0, 10.0])
    delta = np.radians([2.0, -1.5, 3.0, -2.5])

    def camera(theta, off):
        _, _, _, elbow, wrist = kernel.pose(theta, lu, lf)
        z = np.zeros((6, 3))
        z[kernel.ELBOW], z[kernel.WRIST] = elbow + off[:3], wrist + off[3:]
        return z

    moved = th.copy()
    moved[:4] += delta
    none = np.zeros(6)
    d = kernel.camera_angles(th, lu, lf, camera(moved, none), True, none, 1e-9)
    np.testing.assert_allclose(np.degrees(d), np.degrees(delta), atol=0.25)
    off = np.array([0.01, -0.02, 0.005, 0.0, 0.015, -0.01])
    d_off = kernel.camera_angles(th, lu, lf, camera(moved, off), True, off, 1e-9)
    np.testing.assert_allclose(d_off, d, atol=1e-12)
    straight = np.zeros(5)
    turned = straight.copy()
    turned[2] = np.radians(5.0)  # rotation alone, elbow extended: the points do not move
    d0 = kernel.camera_angles(straight, lu, lf, camera(turned, none), True, none, 1e-3)
    assert abs(np.degrees(d0[2])) < 1e-6
    bent = straight.copy()
    bent[3] = np.radians(4.0)  # the elbow alone: its own angle, not the shoulder's
    d1 = kernel.camera_angles(straight, lu, lf, camera(bent, none), True, none, 1e-9)
    assert abs(np.degrees(d1[3]) - 4.0) < 0.1 and np.all(np.abs(np.degrees(d1[:3])) < 0.1)
