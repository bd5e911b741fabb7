"""Poll schedules that end a fusion-grid advance exactly on a robot stamp.

``Pipeline.poll`` advances the fusion grid up to ``until`` (the newest robot stamp when the
robot stream is the one behind). ``floor(until / dt) * dt`` can round above ``until``
(1503 × 0.04 = 60.120000000000005 > 60.12): that grid point lay past the newest robot
sample, was judged invalid, restarted the grid's low-pass and was never revisited, so the
heading windows, and every row after them, depended on when ``poll()`` was called.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from estimators.output import Output
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol import wire
from simulator import SimConfig, simulate

DT = 1.0 / PipelineParams().fusion_rate_hz


def _messages(seed: int, duration_s: float) -> list[Any]:
    sim = simulate(SimConfig(seed=seed, duration_s=duration_s))
    return [wire.decode(k, p) for k, p in sim.messages]


def _robot_lagging(msgs: list[Any], by: int = 4) -> list[Any]:
    """The same messages with each robot message arriving ``by`` IMU messages late."""
    robot = [m for m in msgs if isinstance(m, wire.RobotMessage)]
    imu = [m for m in msgs if not isinstance(m, wire.RobotMessage)]  # and events
    out: list[Any] = []
    j = 0
    for i, m in enumerate(imu):
        out.append(m)
        while j < len(robot) and j <= i - by:
            out.append(robot[j])
            j += 1
    return out + robot[j:]


def _rounds_above(t: float) -> bool:
    """Whether the last grid point at or before ``t`` is computed as a float above ``t``."""
    return math.floor(t / DT) * DT > t


def _polled_on_rounding_stamps(msgs: list[Any], params: PipelineParams) -> Output:
    """Poll only when the robot is the stream behind and its newest stamp rounds above."""
    p = Pipeline(params)
    out = Output()
    imu_t = robot_t = -math.inf  # newest stamp fed of each stream
    for m in msgs:
        p.feed(m)
        if isinstance(m, wire.RobotMessage):
            robot_t = float(m.t[-1])
        elif isinstance(m, wire.ImuMessage):
            imu_t = float(m.t[-1])
        if math.isfinite(robot_t) and imu_t >= robot_t and _rounds_above(robot_t):
            out.extend(p.poll())
    out.extend(p.finish())
    return out


def _assert_same(a: Output, b: Output) -> None:
    assert a.n == b.n
    for k in a.rows:
        x, y = np.asarray(a.rows[k]), np.asarray(b.rows[k])
        same = (x == y) | (np.isnan(x) & np.isnan(y)) if x.dtype.kind == "f" else x == y
        if not np.all(same):
            bad = np.flatnonzero(np.reshape(~same, (len(x), -1)).any(axis=1))
            pytest.fail(f"{k}: {len(bad)} rows differ, first at t = {a.rows['t'][bad[0]]:.2f} s")
    assert a.feedback == b.feedback
    assert [(c.start, c.end, c.outside_fraction, c.compensatory) for c in a.cycles] == [
        (c.start, c.end, c.outside_fraction, c.compensatory) for c in b.cycles
    ]


@pytest.fixture(scope="module")
def short_msgs() -> list[Any]:
    return _messages(seed=1, duration_s=20.0)


def test_paper_method_polled_on_rounding_robot_stamps_equals_batch(short_msgs: list[Any]) -> None:
    params = PipelineParams(method="paper")
    _assert_same(_polled_on_rounding_stamps(short_msgs, params), Pipeline(params).run(short_msgs))


@pytest.mark.parametrize("method", ["paper", "improved"])
def test_lagging_robot_polled_on_rounding_stamps_equals_batch(
    short_msgs: list[Any], method: str
) -> None:
    """With the robot stream behind, ``until`` is a robot stamp for both methods."""
    params = PipelineParams(method=method)  # type: ignore[arg-type]
    msgs = _robot_lagging(short_msgs)
    _assert_same(_polled_on_rounding_stamps(msgs, params), Pipeline(params).run(msgs))
