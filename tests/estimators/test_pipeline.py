"""The streaming pipeline: batching invariance, accuracy sanity, bad input, gaps."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimators.output import Output
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol import wire
from tests.conftest import Session, make_session


def _run(messages, params=None) -> tuple[Output, Pipeline]:
    p = Pipeline(params or PipelineParams())
    return p.run(messages), p


def _same(a: Output, b: Output) -> None:
    assert a.n == b.n
    for k in a.rows:
        assert np.array_equal(a.rows[k], b.rows[k], equal_nan=True), k
    assert a.feedback == b.feedback
    assert [(c.start, c.end, c.outside_fraction, c.compensatory) for c in a.cycles] == [
        (c.start, c.end, c.outside_fraction, c.compensatory) for c in b.cycles
    ]


@pytest.fixture(scope="module")
def batch(short_session: Session) -> Output:
    return _run(short_session.messages)[0]


def test_one_row_per_robot_sample(short_session: Session, batch: Output) -> None:
    robot_t = np.concatenate(
        [m.t for m in short_session.messages if isinstance(m, wire.RobotMessage)]
    )
    assert np.array_equal(batch.rows["t"], robot_t)


def test_live_schedule_equals_batch(short_session: Session, batch: Output) -> None:
    """Message by message with a poll after each one, as the service does."""
    p = Pipeline(PipelineParams())
    out = Output()
    for m in short_session.messages:
        p.feed(m)
        out.extend(p.poll())
    out.extend(p.finish())
    _same(out, batch)


@settings(
    max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.lists(st.integers(min_value=1, max_value=4000), min_size=1, max_size=8))
def test_any_poll_schedule_equals_batch(
    short_session: Session, batch: Output, cuts: list[int]
) -> None:
    p = Pipeline(PipelineParams())
    out = Output()
    msgs = short_session.messages
    stops = sorted({min(c, len(msgs)) for c in cuts})
    i = 0
    for s in [*stops, len(msgs)]:
        for m in msgs[i:s]:
            p.feed(m)
        out.extend(p.poll())
        i = s
    out.extend(p.finish())
    _same(out, batch)


def _rebatch_imu(msgs: list[wire.Message], k: int) -> list[wire.Message]:
    """Split every IMU message into messages of at most k samples (no seq)."""
    out: list[wire.Message] = []
    for m in msgs:
        if isinstance(m, wire.ImuMessage):
            for i in range(0, len(m.t), k):
                s = slice(i, i + k)
                out.append(wire.ImuMessage(m.device, m.segment, m.t[s], m.gyr[s], m.acc[s]))
        else:
            out.append(m)
    return out


def test_imu_batching_does_not_change_results(short_session: Session) -> None:
    a = _run(_rebatch_imu(short_session.messages, 4))[0]
    b = _run(_rebatch_imu(short_session.messages, 1))[0]
    _same(a, b)


def test_converges_and_tracks_the_shoulder(short_session: Session, batch: Output) -> None:
    tr = short_session.sim.truth
    r = batch.rows
    conv = r["heading_converged"]
    assert conv.any()
    t_conv = r["t"][conv][0]
    motion = tr.t[np.flatnonzero(tr.phase > 0)[0]]
    assert t_conv - motion <= 30.0  # issue: converged within 30 s of the start of motion
    i = np.clip(np.searchsorted(tr.t, r["t"]), 0, len(tr.t) - 1)
    err = np.linalg.norm(r["shoulder"] - tr.shoulder[i], axis=1)[conv]
    assert np.median(err) < 0.03
    ang = np.abs(r["elbow_angle_deg"] - np.interp(r["t"], tr.t, tr.elbow_angle_deg))[conv]
    assert np.median(ang) < 4.0


def test_paper_method_runs_and_is_selectable(short_session: Session) -> None:
    out, p = _run(short_session.messages, PipelineParams(method="paper"))
    assert p.hp.method == "paper" and p.hp.update_interval_s == 5.0
    # the paper's grid is 1°: every heading estimate is a whole degree
    h = out.rows["heading_offset_deg"]
    h = h[np.isfinite(h)]
    assert len(h) and np.allclose(h, np.round(h), atol=1e-6)


@pytest.fixture(scope="module")
def paper_run(short_session: Session) -> tuple[Output, Pipeline, int | None]:
    """The paper's method streamed with a poll after every message; also the counted window
    (1-based) at which it declared convergence."""
    p = Pipeline(PipelineParams(method="paper"))
    out, conv_at = Output(), None
    for m in short_session.messages:
        p.feed(m)
        out.extend(p.poll())
        if conv_at is None and p.status()["heading_converged"]:
            conv_at = p.heading_state.n_counted
    out.extend(p.finish())
    return out, p, conv_at


@pytest.mark.parametrize("seed", [34, 27])
def test_converges_fast_under_fast_drift(seed: int) -> None:
    """Gyro bias 2.5× the simulator's usual (heading drift up to ~2.5 °/s before the 6D
    filter has learnt it): converged within 20 s of the start of motion, the shoulder as
    accurate as usual."""
    s = make_session(seed, gyro_bias_scale=2.5)
    out, p = _run(s.messages)
    tr = s.sim.truth
    motion = tr.t[np.flatnonzero(tr.phase > 0)[0]]
    assert p.convergence_time is not None and p.convergence_time - motion <= 20.0
    r = out.rows
    conv = r["heading_converged"].astype(bool)
    i = np.clip(np.searchsorted(tr.t, r["t"]), 0, len(tr.t) - 1)
    err = np.linalg.norm(r["shoulder"] - tr.shoulder[i], axis=1)[conv]
    assert np.median(err) < 0.02
    assert all(_judged(s, out))


def test_paper_method_is_the_published_one(paper_run) -> None:
    _, p, _ = paper_run
    q = p.params
    assert q.arm_length_mode == "fixed" and q.angle_timing == "paired" and q.predict_s == 0.0
    assert not q.use_antialias and q.highpass == 0.0
    assert p.arm_length_estimate is None  # l_A as given, even with a rope reference


def test_paper_schedule_on_a_noisy_session(paper_run) -> None:
    """§3.2.2 on a simulated session with every error source on: updates every 5 s, the first
    five counted windows two-step, convergence at the first window from the sixth on whose
    last five changes are each ≤ 5°, then the one-step grid (±5° per update)."""
    _, p, conv_at = paper_run
    s = p.heading_state
    est = [math.degrees(d) for d in s.history]
    assert np.allclose(est, np.round(est), atol=1e-9)  # the 1° grid
    changes = [abs((b - a + 180.0) % 360.0 - 180.0) for a, b in zip(est, est[1:], strict=False)]
    expected = next(
        k for k in range(6, len(est) + 1) if all(c <= 5.0 + 1e-9 for c in changes[k - 6 : k - 1])
    )
    assert conv_at == expected
    assert all(c <= 5.0 + 1e-9 for c in changes[conv_at - 1 :])  # eq. 8's grid
    assert p.first_motion_time is not None and p.convergence_time is not None
    # every window counts here (continuous motion): convergence 5 s × (k − 1) after the first
    assert p.convergence_time - p.first_motion_time == pytest.approx(5.0 * (conv_at - 1))


def test_paper_accuracy_and_verdicts_on_a_noisy_session(short_session: Session, paper_run) -> None:
    # bounds from the paper's own results on real data (median shoulder ~4 cm, all p95 below
    # 10 cm; elbow median below 4°, p95 mostly below 10°; every cycle right)
    out, _, _ = paper_run
    tr = short_session.sim.truth
    r = out.rows
    conv = r["heading_converged"].astype(bool)
    i = np.clip(np.searchsorted(tr.t, r["t"]), 0, len(tr.t) - 1)
    err = np.linalg.norm(r["shoulder"] - tr.shoulder[i], axis=1)[conv]
    ang = np.abs(r["elbow_angle_deg"] - np.interp(r["t"], tr.t, tr.elbow_angle_deg))[conv]
    assert np.median(err) < 0.04 and np.percentile(err, 95) < 0.10
    assert np.median(ang) < 4.0 and np.percentile(ang, 95) < 10.0
    judged = _judged(short_session, out)
    assert judged and all(right for right in judged)


def _judged(session: Session, out: Output) -> list[bool]:
    """Whether each judged cycle inside a proper or compensatory phase got its phase's verdict."""
    cyc = session.sim.truth.cycles
    res = []
    for c in out.cycles:
        if c.compensatory is None:
            continue
        mid = 0.5 * (c.start + c.end)
        k = np.flatnonzero((cyc.start <= mid) & (cyc.end > mid))
        if len(k) and cyc.phase[k[0]] in (1, 3):
            res.append(c.compensatory == (cyc.phase[k[0]] == 3))
    return res


def test_cycle_verdicts_follow_the_phases(short_session: Session, batch: Output) -> None:
    cyc = short_session.sim.truth.cycles
    judged = [c for c in batch.cycles if c.compensatory is not None]
    assert judged
    for c in judged:
        mid = 0.5 * (c.start + c.end)
        k = np.flatnonzero((cyc.start <= mid) & (cyc.end > mid))
        if len(k) and cyc.phase[k[0]] in (1, 3):
            assert c.compensatory == (cyc.phase[k[0]] == 3), (c, cyc.phase[k[0]])


# ------------------------------------------------------------------ bad input


def test_time_going_backwards_is_rejected_and_counted(short_session: Session) -> None:
    msgs = list(short_session.messages[:400])
    imu = [m for m in msgs if isinstance(m, wire.ImuMessage)]
    msgs.insert(300, imu[10])  # an old message again: duplicate / backwards
    p = Pipeline()
    accepted = [p.feed(m) for m in msgs]
    assert accepted.count(False) == 1
    assert sum(p.quality.rejected.values()) == 1


def test_sequence_loss_is_counted(short_session: Session) -> None:
    msgs = [m for i, m in enumerate(short_session.messages[:600]) if i not in (100, 101, 102)]
    p = Pipeline()
    for m in msgs:
        p.feed(m)
    assert sum(p.quality.seq_lost.values()) == 3


def _drop(msgs, t0: float, t1: float, kind) -> list[wire.Message]:
    return [m for m in msgs if not (isinstance(m, kind) and t0 <= m.t[0] < t1)]


def test_short_imu_gap_is_bridged_not_reset(short_session: Session) -> None:
    msgs = _drop(short_session.messages, 60.0, 60.08, wire.ImuMessage)
    out, p = _run(msgs)
    assert p.quality.imu_bridged_gaps == 1 and p.quality.imu_resets == 0
    assert out.rows["heading_converged"][out.rows["t"] > 61].all()


def test_long_imu_gap_resets_heading_and_reconverges(short_session: Session) -> None:
    msgs = _drop(short_session.messages, 40.0, 43.0, wire.ImuMessage)
    out, p = _run(msgs)
    assert p.quality.imu_resets == 1 and p.quality.heading_resets == 1
    t, conv = out.rows["t"], out.rows["heading_converged"]
    last_imu = max(float(m.t[-1]) for m in msgs if isinstance(m, wire.ImuMessage) and m.t[-1] < 41)
    # rows are predicted at most imu_predict_s past the newest IMU sample, never across a gap
    inside = (t > last_imu + p.params.predict_s) & (t < 43.0)
    assert conv[(t > last_imu) & (t < 43.0)].sum() <= 2
    assert not conv[inside].any()  # never silently interpolated across seconds
    assert np.isnan(out.rows["shoulder"][inside]).all()
    assert conv[t > 80].all()  # re-converged


def test_robot_gap_leaves_no_rows_and_resumes(short_session: Session) -> None:
    msgs = _drop(short_session.messages, 50.0, 52.0, wire.RobotMessage)
    out, p = _run(msgs)
    assert p.quality.robot_gaps == 1
    t = out.rows["t"]
    assert not ((t >= 50.0) & (t < 52.0)).any()
    assert out.rows["heading_converged"][t > 53].all()


def test_robot_without_imu_gives_rows_without_orientation(short_session: Session) -> None:
    msgs = [m for m in short_session.messages if not isinstance(m, wire.ImuMessage)]
    out, p = _run(msgs)
    assert out.n == sum(len(m.t) for m in msgs if isinstance(m, wire.RobotMessage))
    assert np.isfinite(out.rows["elbow"]).all()
    assert np.isnan(out.rows["shoulder"]).all() and not out.rows["heading_converged"].any()
    assert p.quality.rows_without_imu == out.n


def test_imu_without_robot_gives_no_rows(short_session: Session) -> None:
    msgs = [m for m in short_session.messages if isinstance(m, wire.ImuMessage)]
    out, p = _run(msgs)
    assert out.n == 0 and p.quality.imu_samples > 0


def test_empty_input() -> None:
    out, p = _run([])
    assert out.n == 0 and p.status()["heading_converged"] is False


finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["imu", "robot", "event"]),
            st.floats(min_value=-5, max_value=50, allow_nan=False),
            st.integers(1, 5),
            finite,
        ),
        max_size=60,
    )
)
def test_arbitrary_valid_messages_never_crash(items) -> None:
    """Valid-by-schema but physically absurd streams: counted, never an exception."""
    p = Pipeline()
    for kind, t0, n, v in items:
        t = t0 + 0.01 * np.arange(n)
        x = np.full((n, 3), v) + np.arange(n)[:, None] * np.array([0.01, -0.02, 0.03])
        if kind == "imu":
            p.feed(wire.ImuMessage("d", "upperarm", t, x * 0.01, x))
        elif kind == "robot":
            p.feed(wire.RobotMessage("d", t, x, x + np.array([0.0, 0.0, 0.2])))
        else:
            p.feed(wire.EventMessage("d", float(t0), "shoulder_reference", x[0]))
        p.poll()
    out = p.finish()
    for v in out.rows.values():
        assert len(v) == out.n


def test_unusable_params_are_refused() -> None:
    from estimators.params import ParamsError

    with pytest.raises(ParamsError, match="unknown"):
        PipelineParams.from_json({"upper_arm_lenght_m": 0.3})
    with pytest.raises(ParamsError):
        PipelineParams.from_json({"tolerance_m": -1})
    p = PipelineParams.from_json({"nominal_shoulder_m": [0, 0, 0.4], "method": "paper"})
    assert p.nominal_shoulder_m == (0.0, 0.0, 0.4) and p.heading_params.update_interval_s == 5.0


def test_nominal_from_parameter_is_used(short_session: Session) -> None:
    # without a shoulder_reference event (a later event would override the parameter)
    nom = tuple(float(x) for x in short_session.sim.truth.nominal_shoulder)
    msgs = [m for m in short_session.messages if not isinstance(m, wire.EventMessage)]
    out, _ = _run(msgs, replace(PipelineParams(), nominal_shoulder_m=nom))
    conv = out.rows["heading_converged"]
    assert np.allclose(out.rows["nominal_shoulder"][conv], nom)
    assert math.isfinite(float(np.nanmedian(out.rows["shoulder_displacement_m"])))


def test_automatic_nominal_without_reference(short_session: Session) -> None:
    msgs = [m for m in short_session.messages if not isinstance(m, wire.EventMessage)]
    out, p = _run(msgs)
    conv = out.rows["heading_converged"]
    nom = out.rows["nominal_shoulder"]
    first = np.flatnonzero(conv)[0]
    # the first auto_nominal_s after convergence build the nominal; then it is fixed
    t0 = out.rows["t"][first]
    later = out.rows["t"] > t0 + p.params.auto_nominal_s + 0.1
    assert np.isnan(nom[first]).all() and np.isfinite(nom[later]).all()
    assert np.ptp(nom[later], axis=0).max() == 0.0
    assert p.arm_length_estimate is None  # no rope reference, no measured length


def test_nominal_specs_stream_as_batch(short_session: Session) -> None:
    """Automatic nominal, a therapist's reset, then a second rope reference: polled after
    every message (rows one by one) and in one batch (rows as arrays, runs of rows whose
    nominal and arm length are settled filled at once) give the same rows."""
    msgs = [m for m in short_session.messages if not isinstance(m, wire.EventMessage)]
    ref = next(m for m in short_session.messages if isinstance(m, wire.EventMessage))
    t_end = float(msgs[-1].t[-1])
    n = len(msgs)
    events = [
        (n // 2, wire.EventMessage("d", 0.5 * t_end, "nominal_reset", None)),
        (3 * n // 4, wire.EventMessage("d", 0.75 * t_end, "shoulder_reference", ref.point)),
    ]
    for i, e in reversed(events):
        msgs.insert(i, e)
    batch, p = _run(msgs)
    live = Pipeline(PipelineParams())
    out = Output()
    for m in msgs:
        live.feed(m)
        out.extend(live.poll())
    out.extend(live.finish())
    _same(out, batch)
    assert live.arm_length_estimate == p.arm_length_estimate
    nom = batch.rows["nominal_shoulder"]
    assert len({tuple(r) for r in nom[np.isfinite(nom).all(axis=1)].tolist()}) >= 2


@pytest.mark.parametrize(("imu_hz", "robot_hz", "batch"), [(400.0, 10.0, 16), (50.0, 100.0, 1)])
def test_other_rates_and_batching(imu_hz: float, robot_hz: float, batch: int) -> None:
    s = make_session(11, imu_rate_hz=imu_hz, robot_rate_hz=robot_hz, imu_batch=batch)
    out, p = _run(s.messages)
    assert p._imu.ts == pytest.approx(1.0 / imu_hz)
    tr = s.sim.truth
    conv = out.rows["heading_converged"]
    assert conv.any() and out.n == sum(
        len(m.t) for m in s.messages if isinstance(m, wire.RobotMessage)
    )
    i = np.clip(np.searchsorted(tr.t, out.rows["t"]), 0, len(tr.t) - 1)
    err = np.linalg.norm(out.rows["shoulder"] - tr.shoulder[i], axis=1)[conv]
    assert np.median(err) < 0.03


def test_camera_and_other_segments_are_counted_not_rejected(short_session: Session) -> None:
    p = Pipeline()
    cam = wire.CameraMessage("sim01", np.array([1.0]), np.zeros((1, 3)), np.ones((1, 3)))
    trunk = wire.ImuMessage("sim01", "trunk", np.array([1.0]), np.zeros((1, 3)), np.ones((1, 3)))
    assert not p.feed(cam) and not p.feed(trunk)
    assert p.quality.rejected == {} and p.quality.ignored == {"CameraMessage": 1, "imu_trunk": 1}


def test_tolerated_time_episodes_for_non_repetitive_tasks(
    short_session: Session, batch: Output
) -> None:
    """Every compensatory episode is an outside run longer than the tolerated time, and
    they happen in the compensatory phase."""
    tr = short_session.sim.truth
    assert batch.episodes
    for e in batch.episodes:
        assert e.duration_s > 0.5
        k = np.clip(np.searchsorted(tr.t, 0.5 * (e.start + e.end)), 0, len(tr.t) - 1)
        assert tr.phase[k] in (2, 3)


def test_rows_do_not_wait_for_the_next_imu_message(short_session: Session) -> None:
    """A robot sample the IMU has not quite reached (the simulated IMU sends 4 samples per
    message, released with the last) is computed on arrival, the upper arm predicted from
    the newest IMU sample by its gyro; waiting for the IMU instead changes next to nothing."""
    msgs = short_session.messages
    now, waits = Pipeline(PipelineParams()), Pipeline(PipelineParams(imu_predict_s=0.0))
    robot = ready_now = ready_waits = 0  # robot messages whose row is out at once
    out_now, out_waits = Output(), Output()
    for m in msgs:
        now.feed(m)
        waits.feed(m)
        if isinstance(m, wire.RobotMessage):
            robot += 1
            o_now, o_waits = now.poll(), waits.poll()
            ready_now += bool(o_now.n) and o_now.rows["t"][-1] == m.t[-1]
            ready_waits += bool(o_waits.n) and o_waits.rows["t"][-1] == m.t[-1]
            out_now.extend(o_now)
            out_waits.extend(o_waits)
    out_now.extend(now.finish())
    out_waits.extend(waits.finish())
    assert ready_now >= 0.99 * robot
    assert ready_waits <= 0.5 * robot
    a, b = out_now.rows, out_waits.rows
    np.testing.assert_array_equal(a["t"], b["t"])
    both = a["heading_converged"] & b["heading_converged"]
    assert both.sum() > 0.5 * len(both)
    sh = np.linalg.norm(a["shoulder"] - b["shoulder"], axis=1)[both]
    assert sh.max() < 1e-3
    el = np.abs(a["elbow_angle_deg"] - b["elbow_angle_deg"])[both]
    assert 0 < el.max() < 0.2


def test_imu_without_robot_is_bounded_and_counted(short_session: Session) -> None:
    """IMU only, polled as the service does: nothing would ever let the pipeline forget it;
    beyond ``imu_lead_max_s`` it is refused, counted, and what is held stays bounded."""
    params = PipelineParams(imu_lead_max_s=5.0)
    imu = [m for m in short_session.messages if isinstance(m, wire.ImuMessage)]
    span = float(imu[-1].t[-1] - imu[0].t[0])
    assert span > 20.0  # the test means something only well beyond the cap
    p = Pipeline(params)
    for m in imu:
        p.feed(m)
        p.poll()
    rate = len(np.concatenate([m.t for m in imu])) / span
    assert len(p._imu.tl) <= (5.0 + 0.5) * rate
    assert p.quality.rejected["imu_without_robot"] > 0
    assert p.quality.imu_samples <= (5.0 + 0.5) * rate


def test_imu_lead_cap_is_the_same_batch_and_streamed(short_session: Session) -> None:
    """The robot stops for 12 s while the IMU goes on (cap 5 s): IMU is refused, then taken
    again when the robot is back, and every schedule gives the batch's numbers."""
    params = PipelineParams(imu_lead_max_s=5.0)
    msgs = _drop(short_session.messages, 30.0, 42.0, wire.RobotMessage)
    batch, pb = _run(msgs, params)
    assert pb.quality.rejected["imu_without_robot"] > 0
    p = Pipeline(params)
    out = Output()
    for m in msgs:
        p.feed(m)
        out.extend(p.poll())
    out.extend(p.finish())
    _same(out, batch)
    t = batch.rows["t"]
    assert batch.rows["heading_converged"][t > t.max() - 5].all()  # the IMU came back
    # without the cap (default 30 s) nothing is refused
    _, pd = _run(msgs)
    assert "imu_without_robot" not in pd.quality.rejected


def test_imu_lead_cap_must_be_usable() -> None:
    with pytest.raises(ValueError):
        PipelineParams.from_json({"imu_lead_max_s": 0.0})
