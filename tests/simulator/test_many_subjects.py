"""Robustness over many subjects and the extremes of the arm-length ranges (slow)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from simulator import SimConfig, draw_subject, simulate
from simulator.subject import task_placement
from tests.simulator.test_truth import check_verdicts


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(20, 40))
def test_verdicts_and_posture_for_many_seeds(seed: int) -> None:
    sim = simulate(SimConfig(seed=seed, imu_rate_hz=20.0, robot_rate_hz=10.0))
    check_verdicts(sim)
    angle = sim.truth.elbow_angle_deg
    assert angle.min() > 20.0 and angle.max() < 125.0


@pytest.mark.slow
@pytest.mark.parametrize("upper", [0.26, 0.34])
@pytest.mark.parametrize("fore", [0.24, 0.30])
def test_extreme_arms_stay_non_singular(upper: float, fore: float) -> None:
    base = draw_subject(np.random.default_rng(0))
    center, size = task_placement(upper, fore)
    subject = replace(
        base,
        upper_arm_m=upper,
        forearm_m=fore,
        rect_center_m=center,
        rect_size_m=size,
        imu_to_elbow_m=0.19,
    )
    sim = simulate(SimConfig(seed=1, subject=subject, imu_rate_hz=20.0, robot_rate_hz=10.0))
    check_verdicts(sim)
    angle = sim.truth.elbow_angle_deg
    assert angle.min() > 20.0 and angle.max() < 125.0
