"""Feeding messages as rows of shared arrays (``feed_imu_rows``/``feed_robot_rows``, what
``rehab analyze`` does) gives exactly what feeding the messages one by one gives."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimators.output import Output
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol import wire
from tests.conftest import Session


def _faulty(s: Session) -> list[wire.Message]:
    """The session with what feeding must reject or count: time going backwards, a
    duplicate, coincident cuffs, sequence gaps, another IMU segment, robot elbows given
    for some messages only."""
    out: list[wire.Message] = []
    n_robot = 0
    for i, m in enumerate(s.messages):
        out.append(m)
        if isinstance(m, wire.RobotMessage):
            n_robot += 1
            if n_robot % 97 == 0:  # coincident cuffs
                w = m.wrist.copy()
                w[-1] = m.proximal[-1]
                out[-1] = replace(m, wrist=w)
            elif n_robot % 53 == 0:  # the robot's own elbow
                out[-1] = replace(m, elbow=m.proximal + 0.01)
            elif n_robot % 71 == 0:  # sequence gap
                out[-1] = replace(m, seq=(m.seq or 0) + 5)
        elif isinstance(m, wire.ImuMessage) and i % 89 == 0:
            out.append(replace(m, t=m.t - m.t[0] + m.t[-1]))  # starts at the last stamp
            out.append(replace(m, segment="trunk"))
        if i % 131 == 0 and i > 10:
            out.append(s.messages[i - 6])  # out of order
    return out


def _columns(msgs: list[wire.Message]) -> dict[type, tuple]:
    """Per message type: the messages' arrays end to end and each message's row range."""
    cols: dict[type, tuple] = {}
    for cls, names in (
        (wire.ImuMessage, ("t", "gyr", "acc")),
        (wire.RobotMessage, ("t", "wrist", "proximal")),
    ):
        sel = [m for m in msgs if type(m) is cls]
        if not sel:
            continue
        arrays = [np.concatenate([getattr(m, k) for m in sel]) for k in names]
        if cls is wire.RobotMessage:
            if any(m.elbow is not None for m in sel):
                arrays.append(
                    np.concatenate(
                        [
                            np.full((len(m.t), 3), np.nan) if m.elbow is None else m.elbow
                            for m in sel
                        ]
                    )
                )
            else:
                arrays.append(None)
        ends = np.cumsum([len(m.t) for m in sel]).tolist()
        spans = {id(m): (e - len(m.t), e) for m, e in zip(sel, ends, strict=True)}
        cols[cls] = (arrays, arrays[0].tolist(), spans)
    return cols


def _feed_as_rows(p: Pipeline, block: list[wire.Message], as_message: list[bool]) -> None:
    cols = _columns(block)
    for m, plain in zip(block, as_message, strict=True):
        if plain or type(m) not in cols:
            p.feed(m)
            continue
        arrays, tl, spans = cols[type(m)]
        i0, i1 = spans[id(m)]
        if isinstance(m, wire.ImuMessage):
            p.feed_imu_rows(arrays[0], tl, arrays[1], arrays[2], i0, i1, m.seq, m.segment)
        else:
            p.feed_robot_rows(arrays[0], tl, arrays[1], arrays[2], arrays[3], i0, i1, m.seq)


def _same(a: Output, b: Output, pa: Pipeline, pb: Pipeline) -> None:
    assert a.n == b.n
    for k in a.rows:
        assert np.array_equal(a.rows[k], b.rows[k], equal_nan=True), k
    assert a.feedback == b.feedback
    assert a.cycles == b.cycles
    assert a.episodes == b.episodes
    assert pa.quality.as_dict() == pb.quality.as_dict()


@pytest.fixture(scope="module")
def faulty(short_session: Session) -> list[wire.Message]:
    return _faulty(short_session)


@pytest.fixture(scope="module")
def by_message(faulty: list[wire.Message]) -> tuple[Output, Pipeline]:
    p = Pipeline(PipelineParams())
    return p.run(faulty), p


def test_the_faults_are_there(by_message: tuple[Output, Pipeline]) -> None:
    q = by_message[1].quality.as_dict()
    assert q["rejected"]["coincident_cuffs"] > 0
    assert q["rejected"]["duplicate_t"] > 0 and q["rejected"]["time_backwards"] > 0
    assert q["seq_lost"]["robot"] > 0 and q["ignored"]["imu_trunk"] > 0


@settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    st.lists(st.integers(1, 700), min_size=1, max_size=6),  # block sizes (messages)
    st.integers(0, 2**32 - 1),
    st.booleans(),  # poll after every block, or only at the end
)
def test_rows_equal_messages(
    faulty: list[wire.Message],
    by_message: tuple[Output, Pipeline],
    sizes: list[int],
    seed: int,
    poll_each: bool,
) -> None:
    rng = np.random.default_rng(seed)
    p = Pipeline(PipelineParams())
    out = Output()
    i = k = 0
    while i < len(faulty):
        block = faulty[i : i + sizes[k % len(sizes)]]
        i, k = i + len(block), k + 1
        # a few messages fed as messages in between: the pieces must stay in feed order
        _feed_as_rows(p, block, (rng.random(len(block)) < 0.05).tolist())
        if poll_each:
            out.extend(p.poll())
    out.extend(p.poll())
    out.extend(p.finish())
    _same(out, by_message[0], p, by_message[1])
