"""The IMU stage (:mod:`estimators.imu_stage`): however its samples are split into pieces,
it holds the same numbers, and a single-time look-up equals the array path bit for bit."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from backend import wire
from estimators.imu_stage import ImuStage
from estimators.output import Quality
from estimators.params import PipelineParams
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


@settings(
    max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    s=st.floats(-0.5, 31.0),
    asof=st.one_of(
        st.none(),  # the IMU has reached the row
        st.floats(-0.5, 31.0),
        # a segment's first samples (after the long gap), the first after the trim, the
        # bridged gap's ends, the newest few
        st.sampled_from([21.0, 21.005, 21.01, 15.0, 15.005, 10.0, 10.05, 29.98, 29.99]),
    ),
    piece=st.sampled_from([4, 13]),
    # (21.02 keeps the segment's first sample as the oldest: the mirror starts there)
    trim=st.sampled_from([None, 15.0, 21.02]),
)
def test_single_time_lookup_equals_the_array_path(
    imu: Arrays, s: float, asof: float | None, piece: int, trim: float | None
) -> None:
    """``at`` (Python floats, the newest samples from the float mirror, dω worked out there
    when a prediction needs it) against ``interp`` (arrays from the buffer), inside a
    segment, across the gaps, before and after the data, and predicted past ``asof``.
    Pieces of 4 are the live case; 13 leaves only the mirror's newest."""
    t = imu[0]
    stage, _ = _fed(imu, list(range(piece, len(t), piece)))
    if trim is not None:
        stage.trim(trim)
        if trim == 21.02:
            assert stage.tl[0] == 21.0  # the case's premise
    a = math.inf if asof is None else asof
    ok, q, seg = stage.at(s, a)
    oka, qa, sega = stage.interp(np.array([s]), np.array([a]))
    assert ok == bool(oka[0])
    assert seg == float(sega[0])
    assert struct.pack("4d", *q) == struct.pack("4d", *(float(c[0]) for c in qa))
