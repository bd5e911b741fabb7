"""The fusion grid (:mod:`estimators.grid_stage`): advancing it in any steps gives the grid one
advance gives, and it holds both accelerations for the heading windows."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimators.grid_stage import GridStage
from estimators.imu_stage import ImuStage
from estimators.output import Quality
from estimators.params import PipelineParams
from estimators.robot_stage import RobotStage
from protocol import wire
from tests.conftest import Session

Stages = tuple[ImuStage, RobotStage, float]
_UNTIL = 40.0  # s of the session used


def _messages(session: Session) -> list[wire.Message]:
    return [
        m
        for m in session.messages
        if isinstance(m, (wire.ImuMessage, wire.RobotMessage)) and m.t[0] < _UNTIL
    ]


def _feed(imu: ImuStage, robot: RobotStage, m: wire.Message, q: Quality) -> None:
    if isinstance(m, wire.ImuMessage):
        imu.process(m.t, m.gyr, m.acc, q)
    elif isinstance(m, wire.RobotMessage):
        robot.append(m.t.tolist(), m.elbow if m.elbow is not None else m.wrist, q)


def _reach(imu: ImuStage, robot: RobotStage, grid: GridStage) -> float:
    """How far the grid may go (as the pipeline has it): both streams' newest stamps."""
    return min(imu.tl[-1] - grid.half, robot.tl[-1])


@pytest.fixture(scope="module", params=["improved", "paper"])
def params(request: pytest.FixtureRequest) -> PipelineParams:
    return PipelineParams(method=request.param)


@pytest.fixture(scope="module")
def stages(short_session: Session, params: PipelineParams) -> Stages:
    """Both streams' first 40 s, all fed (the robot's stamps as they come: latency included)."""
    imu, robot, q = ImuStage(params), RobotStage(params), Quality()
    for m in _messages(short_session):
        _feed(imu, robot, m, q)
    return imu, robot, _reach(imu, robot, GridStage(params))


def _grid(g: GridStage) -> bytes:
    return b"".join(
        np.ascontiguousarray(a).tobytes() for a in (g.t, g.a, g.b, g.pos, g.valid, g.seg, g.cl)
    )


@settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(stops=st.one_of(st.just("robot"), st.sets(st.integers(0, 3000), max_size=40)))
def test_streamed_advances_give_the_grid_of_one(
    short_session: Session, params: PipelineParams, stages: Stages, stops: str | set[int]
) -> None:
    """Advancing as the data arrives (after every robot message, the live schedule, or at
    random messages) gives the grid one advance over all of it gives. A step can end on a
    robot stamp where ``k·dt`` rounds past it (1503 × 0.04 = 60.120000000000005 > 60.12)."""
    imu_all, robot_all, until = stages
    one = GridStage(params)
    one.advance(imu_all, robot_all, until)
    imu, robot, q, grid = ImuStage(params), RobotStage(params), Quality(), GridStage(params)
    for i, m in enumerate(_messages(short_session)):
        _feed(imu, robot, m, q)
        step = isinstance(m, wire.RobotMessage) if stops == "robot" else i in stops
        if step and imu.tl and robot.tl:
            grid.advance(imu, robot, _reach(imu, robot, grid))
    grid.advance(imu, robot, until)
    assert _grid(one) == _grid(grid)


def test_grid_is_uniform_and_valid_after_settling(stages: Stages, params: PipelineParams) -> None:
    imu, robot, until = stages
    p = params
    g = GridStage(p)
    g.advance(imu, robot, until)
    dt = 1.0 / p.fusion_rate_hz
    assert np.allclose(np.diff(g.t), dt)
    assert g.t[-1] <= until
    assert g.valid[-100:].all() and not g.valid[: g.settle].any()
    # both sides see the same elbow acceleration (the heading is what turns one into the other)
    na, nb = np.linalg.norm(g.a[g.valid], axis=1), np.linalg.norm(g.b[g.valid], axis=1)
    assert np.corrcoef(na, nb)[0, 1] > 0.5
