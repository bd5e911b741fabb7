"""The IMU stage (:mod:`estimators.imu_stage`): however its samples are split into pieces,
it holds the same numbers (its orientation look-up: tests/estimators/test_rows.py)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimators import quaternion as quat
from estimators.imu_stage import ImuStage
from estimators.output import Quality
from estimators.params import PipelineParams
from tests.estimators.conftest import Arrays


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


def test_buffer_columns(imu: Arrays) -> None:
    """With a tilted mounting: q_IA is q_IS turned by it, ω_A is the gyro turned into A,
    dω_A the backward difference within a segment (0 at its first sample); the improved
    method keeps no eq. 1–2 acceleration."""
    mount = (math.cos(0.3), 0.0, math.sin(0.3), 0.0)
    stage, _ = _fed(imu, list(range(3, len(imu[0]), 5)), PipelineParams(mounting_quat=mount))
    b = stage.buf.view()
    q, qs = b[:, stage.Q : stage.Q + 4], b[:, stage.QS : stage.QS + 4]
    assert np.allclose(q, quat.mul(qs, np.array(mount)), atol=1e-15)
    t, seg, w = b[:, stage.T], b[:, stage.SEG], b[:, stage.W : stage.W + 3]
    dw = b[:, stage.DW : stage.DW + 3]
    first = np.r_[True, seg[1:] != seg[:-1]]
    assert (dw[first] == 0.0).all()
    want = np.diff(w, axis=0) / np.diff(t)[:, None]
    assert np.array_equal(dw[1:][~first[1:]], want[~first[1:]])
    assert np.allclose(w[:50], quat.rotate(quat.conj(np.array(mount)), imu[1][:50]), atol=1e-15)
    assert (b[:, stage.V : stage.V + 3] == 0.0).all()
