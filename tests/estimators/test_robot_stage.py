"""The robot stage (:mod:`estimators.robot_stage`): gaps split segments, interpolation never
crosses one, and rows appended as floats or as arrays are the same rows."""

from __future__ import annotations

import numpy as np

from estimators.output import Quality
from estimators.params import PipelineParams
from estimators.robot_stage import RobotStage


def _samples() -> tuple[list[float], np.ndarray]:
    """25 Hz with one bridged gap (0.2 s) and one that splits (1 s)."""
    t = np.round(np.arange(0.0, 6.0, 0.04), 10)
    t = t[~((t > 2.0) & (t < 2.2)) & ~((t > 4.0) & (t < 5.0))]
    p_e = np.column_stack((np.sin(t), np.cos(t), 0.1 * t))
    return t.tolist(), p_e


def test_gaps_are_counted_and_split_segments() -> None:
    t, p_e = _samples()
    stage, q = RobotStage(PipelineParams()), Quality()
    stage.append(t, p_e, q)
    assert (q.robot_bridged_gaps, q.robot_gaps) == (1, 1)
    assert [round(g["duration_s"], 6) for g in q.gaps] == [1.0]
    seg = stage.buf.view()[:, 1]
    assert seg[np.array(t) <= 4.0].max() == 0 and seg[np.array(t) >= 5.0].min() == 1


def test_interpolation_within_a_segment_only() -> None:
    t, p_e = _samples()
    stage = RobotStage(PipelineParams())
    stage.append(t, p_e, Quality())
    g = np.array([-0.01, 0.02, 2.1, 4.5, 5.02, 5.97, 6.5])
    ok, p = stage.interp(g)
    assert ok.tolist() == [False, True, True, False, True, False, False]
    # linear between the neighbours (across the bridged gap too)
    i = np.searchsorted(t, g[1])
    w = (g[1] - t[i - 1]) / (t[i] - t[i - 1])
    assert np.allclose(p[1], p_e[i - 1] + w * (p_e[i] - p_e[i - 1]), rtol=0, atol=1e-15)
    j = np.searchsorted(t, 2.1)
    assert t[j - 1] == 2.0 and t[j] == 2.2
    assert np.allclose(p[2], 0.5 * (p_e[j - 1] + p_e[j]), rtol=0, atol=1e-12)


def test_floats_one_by_one_equal_one_array() -> None:
    t, p_e = _samples()
    one, q1 = RobotStage(PipelineParams()), Quality()
    one.append(t, p_e, q1)
    many, q2 = RobotStage(PipelineParams()), Quality()
    for k, x in enumerate(t):
        many.append([x], [tuple(p_e[k].tolist())], q2)
    many.interp(np.array([0.0]))  # moves the waiting float rows into the buffer
    assert one.buf.view().tobytes() == many.buf.view().tobytes()
    assert q1 == q2


def test_trim_keeps_what_interpolation_needs() -> None:
    t, p_e = _samples()
    stage = RobotStage(PipelineParams())
    stage.append(t, p_e, Quality())
    g = np.array([3.0, 3.01, 5.5])
    before = stage.interp(g)
    stage.trim(3.0)
    after = stage.interp(g)
    assert stage.tl[1] < 3.0 <= stage.tl[2]
    assert np.array_equal(before[0], after[0]) and np.array_equal(before[1], after[1])
