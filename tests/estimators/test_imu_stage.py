"""The IMU stage (:mod:`estimators.imu_stage`): however its samples are split into pieces,
it holds the same numbers; its orientation look-up."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimators.imu_stage import ImuStage
from estimators.output import Quality
from estimators.params import PipelineParams
from protocol import wire
from tests.conftest import Session

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray]


@pytest.fixture(scope="module")
def imu(short_session: Session) -> Arrays:
    """The session's first 30 s of IMU samples, with a short gap (bridged) and a long one
    (the 6D filter restarts: a new segment)."""
    ms = [m for m in short_session.messages if isinstance(m, wire.ImuMessage)]
    t = np.concatenate([m.t for m in ms])
    gyr = np.concatenate([m.gyr for m in ms])
    acc = np.concatenate([m.acc for m in ms])
    keep = (t < 30.0) & ~((t > 10.0) & (t < 10.05)) & ~((t > 20.0) & (t < 21.0))
    return t[keep], gyr[keep], acc[keep]


def _fed(
    imu: Arrays, cuts: list[int], params: PipelineParams | None = None
) -> tuple[ImuStage, Quality]:
    t, gyr, acc = imu
    stage, q = ImuStage(params or PipelineParams()), Quality()
    # (a message is never empty: cuts at or past the end are not cuts)
    bounds = [0, *sorted({c for c in cuts if c < len(t)}), len(t)]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        stage.process(t[a:b], gyr[a:b], acc[a:b], q)
    return stage, q


def _buffer(stage: ImuStage) -> bytes:
    stage.t  # noqa: B018  # moves the pending pieces into the buffer
    return stage.buf.view().tobytes()


def _bits(x: object) -> bytes:
    return np.asarray(x, dtype=np.float64).tobytes()


def test_gaps_are_bridged_or_start_a_segment(imu: Arrays) -> None:
    stage, q = _fed(imu, [])
    assert q.imu_bridged_gaps == 1 and q.imu_resets == 1
    assert [g["stream"] for g in q.gaps] == ["imu", "imu"]
    seg = stage.segid
    assert set(seg.tolist()) == {0.0, 1.0}
    t0, t1 = stage.t[seg == 0.0], stage.t[seg == 1.0]
    assert t0[-1] < 20.01 and t1[0] >= 21.0  # the segment starts after the long gap
    assert np.diff(t0).max() < 1.5 * (stage.ts or 0)  # the short one is filled in


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    cuts=st.lists(st.integers(1, 2900), max_size=60), method=st.sampled_from(["improved", "paper"])
)
def test_any_split_into_pieces_holds_the_same_numbers(
    imu: Arrays, cuts: list[int], method: str
) -> None:
    p = PipelineParams(method=method)
    (one, q1), (many, q2) = _fed(imu, [], p), _fed(imu, cuts, p)
    assert _buffer(one) == _buffer(many)
    assert q1 == q2
    n = len(one.tl)
    assert _bits(one.channels(0, n)) == _bits(many.channels(0, n))


def test_lookup_at_and_between_samples(imu: Arrays) -> None:
    """``at``: a sample's own orientation at its time; half-way between two samples, the
    unit quaternion half-way along the arc; past ``asof``, the newest sample turned by its
    gyro; nothing before the data or across the long gap."""
    stage, _ = _fed(imu, list(range(4, len(imu[0]), 4)))
    t = stage.t
    q = stage.buf.cols(stage.Q, stage.Q + 4)
    for k in (5, 400, 1500, len(t) - 2):
        ok, qk, _ = stage.at(float(t[k]), math.inf)
        assert ok and np.allclose(qk, q[k], atol=1e-12)
        ok, qm, _ = stage.at(0.5 * float(t[k] + t[k + 1]), math.inf)
        a, b = q[k], q[k + 1] * np.sign(q[k] @ q[k + 1])
        assert ok and abs(np.linalg.norm(qm) - 1.0) < 1e-12
        assert abs(abs(np.dot(qm, a)) - abs(np.dot(qm, b))) < 1e-12
    # past asof: the gyro's rotation over the step (small-angle), from the newest sample
    k = 700
    ok, qp, _ = stage.at(float(t[k]) + 0.02, float(t[k]))
    w = stage.buf.cols(stage.W, stage.W + 3)[k]
    turn = 2.0 * math.degrees(math.acos(min(1.0, abs(float(np.dot(qp, q[k]))))))
    assert ok and turn == pytest.approx(math.degrees(np.linalg.norm(w)) * 0.02, rel=0.05, abs=1e-3)
    assert not stage.at(float(t[0]) - 1.0, math.inf)[0]
    assert not stage.at(20.5, math.inf)[0]  # inside the long gap: two segments
