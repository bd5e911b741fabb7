"""The rows' kernel (:func:`estimators.rows.compute`) against independent expectations: the
orientation look-up (a sample's own orientation, the arc's midpoint, the gyro's turn), eqs.
9–12 on a geometry worked out by hand, the automatic nominal shoulder against
``math.fsum``, and rows in one call or many giving the same bits (the pipeline's live = batch
tests: tests/estimators/test_pipeline.py)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest

from estimators import rows
from estimators.imu_stage import ImuStage
from estimators.output import COL, NCOL, ROW_COLUMNS, SPAN
from estimators.params import PipelineParams
from tests.estimators.conftest import Arrays
from tests.estimators.test_imu_stage import _fed

COLS = np.concatenate((ImuStage.LOOKUP, [COL[name] for name in rows.OUT])).astype(np.int64)


def _col(out: np.ndarray, name: str) -> np.ndarray:
    a, w = SPAN[name]
    return out[:, a] if w == 1 else out[:, a : a + w]


def _snap(delta: float, seg: float = 0.0, rate: float = 0.0, latency: float = 0.0) -> np.ndarray:
    """One converged heading update long before every row."""
    return np.array([[-1e6, delta, rate, -1e6, 0.0, 1.0, seg, latency]])


def _call(
    rin: np.ndarray,
    robot: np.ndarray,
    imu: np.ndarray,
    snaps: np.ndarray,
    specs: np.ndarray,
    state: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    out = np.full((len(rin), NCOL), -7.0)
    st, part = state
    rows.compute(rin, robot, imu, snaps, specs, st, part, COLS, out)
    return out


def _state(timing: str = "fresh", auto_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    return rows.new_state(0.0, 0.0, auto_s, "horizontal", timing)


def _rin(t: Sequence[float], asof: float = math.inf, arm: float = 0.3) -> np.ndarray:
    return np.array([[x, 1.0, 0.0, asof, arm] for x in t])


def _robot(n: int, p_e: Sequence[float] = (0.0, 0.0, 0.0), x_c: Sequence[float] = (1, 0, 0)):
    return np.array([[0.5, 0.4, 0.0, *p_e, *x_c]] * n, dtype=np.float64)


NOMINAL = np.array([[0.0, 0.0, 0.0, 0.0]])  # a fixed nominal shoulder at the origin
AUTO = np.array([[math.nan, math.nan, math.nan, 1.0]])


def test_every_column_is_written_by_name() -> None:
    assert sorted(rows.OUT) == sorted(ROW_COLUMNS) and len(set(rows.OUT)) == len(rows.OUT)
    buf = np.zeros((2, ImuStage.WIDTH))
    buf[:, ImuStage.T] = (0.0, 1.0)
    buf[:, ImuStage.Q] = 1.0
    out = _call(_rin([0.5]), _robot(1), buf, _snap(0.0), NOMINAL, _state())
    assert not (out == -7.0).any()  # no column left unwritten


def _q_at(stage: ImuStage, s: float, asof: float = math.inf) -> tuple[bool, np.ndarray]:
    """q_IA at ``s`` through the kernel: with δ = 0 and no latency, q_RA is q_IA."""
    buf = stage.lookup()
    seg = float(buf[min(np.searchsorted(buf[:, 0], s), len(buf) - 1), ImuStage.SEG])
    out = _call(_rin([s], asof), _robot(1), buf, _snap(0.0, seg), NOMINAL, _state())
    return bool(_col(out, "heading_converged")[0]), _col(out, "q_ra")[0]


def test_orientation_at_and_between_samples(imu: Arrays) -> None:
    """A sample's own orientation at its time; half-way between two samples, the unit
    quaternion half-way along the arc; past ``asof``, the newest sample turned by its gyro;
    nothing before the data or across the long gap."""
    stage, _ = _fed(imu, list(range(4, len(imu[0]), 4)))
    t = stage.t
    q = stage.buf.cols(stage.Q, stage.Q + 4)
    for k in (5, 400, 1500, len(t) - 2):
        ok, qk = _q_at(stage, float(t[k]))
        assert ok and np.allclose(qk, q[k], atol=1e-12)
        ok, qm = _q_at(stage, 0.5 * float(t[k] + t[k + 1]))
        a, b = q[k], q[k + 1] * np.sign(q[k] @ q[k + 1])
        assert ok and abs(np.linalg.norm(qm) - 1.0) < 1e-12
        assert abs(abs(np.dot(qm, a)) - abs(np.dot(qm, b))) < 1e-12
    # past asof: the gyro's rotation over the step (small-angle), from the newest sample
    k = 700
    ok, qp = _q_at(stage, float(t[k]) + 0.02, float(t[k]))
    w = stage.buf.cols(stage.W, stage.W + 3)[k]
    turn = 2.0 * math.degrees(math.acos(min(1.0, abs(float(np.dot(qp, q[k]))))))
    assert ok and turn == pytest.approx(math.degrees(np.linalg.norm(w)) * 0.02, rel=0.05, abs=1e-3)
    assert not _q_at(stage, float(t[0]) - 1.0)[0]
    assert not _q_at(stage, 20.5)[0]  # inside the long gap: two segments


def _still_arm(q: Sequence[float], n: int = 2) -> np.ndarray:
    """IMU samples at 0 and 1 s, the arm held still in orientation ``q``."""
    buf = np.zeros((n, ImuStage.WIDTH))
    buf[:, ImuStage.T] = np.arange(n, dtype=np.float64)
    buf[:, ImuStage.Q : ImuStage.Q + 4] = q
    return buf


def test_equations_9_to_12_on_a_worked_geometry() -> None:
    """The upper arm along the IMU's x axis, the IMU frame turned 90° about z against the
    robot's (δ = 90°): x_A = Rz(90°) e_x = e_y (eq. 10); the forearm along e_x: the elbow
    angle is 90° (eq. 11); the shoulder lies l_A behind the elbow along x_A (eq. 12)."""
    p_e, la = (0.1, 0.7, 0.2), 0.3
    out = _call(
        _rin([0.5], arm=la),
        _robot(1, p_e),
        _still_arm((1.0, 0.0, 0.0, 0.0)),
        _snap(math.pi / 2),
        NOMINAL,
        _state(),
    )
    half = math.sqrt(0.5)
    assert _col(out, "q_ra")[0] == pytest.approx([half, 0.0, 0.0, half], abs=1e-15)
    assert _col(out, "elbow_angle_deg")[0] == pytest.approx(90.0, abs=1e-12)
    assert _col(out, "shoulder")[0] == pytest.approx([0.1, 0.7 - la, 0.2], abs=1e-15)
    assert _col(out, "heading_offset_deg")[0] == pytest.approx(90.0, abs=1e-12)
    assert _col(out, "upper_arm_elevation_deg")[0] == pytest.approx(90.0, abs=1e-12)
    assert _col(out, "upper_arm_azimuth_deg")[0] == pytest.approx(0.0, abs=1e-12)  # +y
    # displacement from the nominal shoulder at the origin, horizontal
    assert _col(out, "shoulder_displacement_m")[0] == pytest.approx(math.hypot(0.1, 0.4))
    # the baseline assumes the shoulder at the nominal point: x_A along p_E
    want = math.degrees(math.acos(0.1 / math.dist(p_e, (0, 0, 0))))
    assert _col(out, "conv_elbow_angle_deg")[0] == pytest.approx(want, abs=1e-12)
    # the same row without a converged heading: no orientation, no shoulder
    snap = _snap(math.pi / 2)
    snap[0, 5] = 0.0
    out = _call(_rin([0.5]), _robot(1), _still_arm((1.0, 0, 0, 0)), snap, NOMINAL, _state())
    assert np.isnan(_col(out, "shoulder")).all() and _col(out, "heading_converged")[0] == 0.0


def test_automatic_nominal_is_the_exact_mean() -> None:
    """With l_A = 0 the shoulder is the elbow: the automatic nominal shoulder is the mean
    of the converged rows' over ``auto_nominal_s`` (correctly rounded, as ``math.fsum``
    gives it even for sums that cancel), NaN before, the same point after."""
    rng = np.random.default_rng(5)
    vals = np.concatenate(
        [
            [1e-16, 1.0, 1e16, 0.1, 0.2, 0.3, -1e16, 1e16],  # cancelling, half-even rounding
            rng.normal(size=40) * 10.0 ** rng.integers(-6, 6, size=40),
        ]
    )
    n = len(vals)
    p_e = np.stack([vals, vals[::-1], np.roll(vals, 3)], axis=1)
    robot = _robot(n)
    robot[:, 3:6] = p_e
    t = 0.5 + np.arange(n) * 0.1
    auto_s = float(t[-6] - t[0])  # the window ends at the sixth row from the end
    out = _call(
        _rin(t, arm=0.0),
        robot,
        _still_arm((1.0, 0, 0, 0), 40),
        _snap(0.3),
        AUTO,
        _state(auto_s=auto_s),
    )
    nom = _col(out, "nominal_shoulder")
    m = n - 5
    want = [math.fsum(p_e[:m, c].tolist()) / m for c in range(3)]
    assert np.isnan(nom[: m - 1]).all()
    assert nom[m - 1 :].tolist() == [want] * 6
    assert want != [sum(p_e[:m, c].tolist()) / m for c in range(3)]  # a plain sum would not do


def test_rows_in_one_call_or_many_are_the_same_bits(imu: Arrays) -> None:
    """The carried state (the previous forearm axis, the nominal shoulder's sum) makes rows
    called one by one identical to rows called together, in every timing mode."""
    stage, _ = _fed(imu, [], PipelineParams())
    buf = stage.lookup()
    rng = np.random.default_rng(2)
    t = np.sort(rng.uniform(1.0, 19.0, 80))
    rin = _rin(t, arm=0.31)
    rin[::7, 3] = t[::7] - 0.02  # some rows decided with the IMU behind them
    rin[::11, 1] = 0.0  # some without it
    robot = _robot(80)
    robot[:, 3:6] = rng.normal(size=(80, 3))
    xc = rng.normal(size=(80, 3))
    robot[:, 6:9] = xc / np.linalg.norm(xc, axis=1)[:, None]
    snaps = np.array(
        [
            [-1e6, 0.2, 0.001, -1e6, 0.01, 1.0, 0.0, 0.03],
            [8.0, 0.25, 0.0, 7.9, 0.005, 1.0, 0.0, 0.0],
        ]
    )
    for timing in rows.TIMING:
        whole = _call(rin, robot, buf, snaps, AUTO, _state(timing, 3.0))
        state = _state(timing, 3.0)
        one = np.concatenate(
            [_call(rin[i : i + 1], robot[i : i + 1], buf, snaps, AUTO, state) for i in range(80)]
        )
        assert whole.tobytes() == one.tobytes(), timing
        assert np.isfinite(_col(whole, "nominal_shoulder")[-1]).all()
