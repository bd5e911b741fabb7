"""Ground truth: phases, cycles and their verdicts, file round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simulator import COMPENSATORY, PROPER, REST, TRANSITION, SimConfig, Simulation, simulate
from simulator.truth import Truth, load_subject


def check_verdicts(sim: Simulation) -> None:
    c = sim.truth.cycles
    proper, comp = c.phase == PROPER, c.phase == COMPENSATORY
    assert not c.compensatory[proper].any(), c.outside_fraction[proper].max()
    assert c.compensatory[comp].all(), c.outside_fraction[comp].min()
    # Designed margins: proper never leaves the tolerance, compensation is clearly outside.
    assert c.peak_displacement_m[proper].max() < 0.09
    assert c.outside_fraction[comp].min() > 0.35
    assert c.outside_fraction[comp].max() < 0.70
    assert 0.12 < np.median(c.peak_displacement_m[comp]) < 0.17


def test_default_session_verdicts_match_phases(default_sim: Simulation) -> None:
    c = default_sim.truth.cycles
    check_verdicts(default_sim)
    assert (c.phase == PROPER).sum() >= 45
    assert (c.phase == COMPENSATORY).sum() >= 28
    # Proper sway is about 4 cm.
    assert 0.03 < np.median(c.peak_displacement_m[c.phase == PROPER]) < 0.06


@pytest.mark.parametrize("seed", [7])
def test_other_subjects_verdicts_match_phases(seed: int) -> None:
    # A low IMU rate keeps this fast; the cycle truth does not depend on it.
    check_verdicts(simulate(SimConfig(seed=seed, imu_rate_hz=20.0, robot_rate_hz=10.0)))


def test_cycles_start_at_the_front_right_corner(default_sim: Simulation) -> None:
    tr = default_sim.truth
    c = tr.cycles
    idx = np.searchsorted(tr.t, c.start[1:])  # the first starts from the rest posture
    corner = tr.wrist[idx]
    assert np.linalg.norm(corner - corner.mean(axis=0), axis=1).max() < 0.005
    center = tr.wrist[tr.phase != REST].mean(axis=0)
    assert corner[0, 0] > center[0] + 0.1 and corner[0, 1] > center[1] + 0.05
    # Counter-clockwise seen from above: the signed area of the wrist path is positive.
    one = tr.wrist[(tr.t >= c.start[5]) & (tr.t < c.end[5])]
    area = 0.5 * np.sum(one[:-1, 0] * one[1:, 1] - one[1:, 0] * one[:-1, 1])
    assert 0.04 < area < 0.07  # ~0.30 × 0.20 m with rounded corners
    dur = c.end - c.start
    assert dur.min() > 3.8 and dur.max() < 7.0
    assert dur.std() / dur.mean() > 0.05  # cycles really vary
    np.testing.assert_array_equal(c.start[1:], c.end[:-1])


def test_per_sample_fields(default_sim: Simulation) -> None:
    tr = default_sim.truth
    m = tr.t.shape[0]
    assert m == 48001
    for name in ("shoulder", "elbow", "wrist", "imu_position", "gyro_bias"):
        assert getattr(tr, name).shape == (m, 3)
    assert tr.q_ra.shape == tr.q_imu.shape == (m, 4)
    np.testing.assert_allclose(np.linalg.norm(tr.q_imu, axis=1), 1.0, atol=1e-12)
    # Phases follow the default layout.
    assert set(np.unique(tr.phase)) == {REST, PROPER, TRANSITION, COMPENSATORY}
    assert (tr.phase[tr.t < 5.0] == REST).all() and (tr.phase[tr.t >= 5.0] != REST).all()
    assert (tr.phase[(tr.t > 230) & (tr.t < 390)] == COMPENSATORY).all()
    # Cycle index per sample agrees with the cycle table.
    k = 10
    inside = tr.cycle == k
    assert tr.t[inside][0] >= tr.cycles.start[k] and tr.t[inside][-1] < tr.cycles.end[k]
    assert (tr.cycle[tr.t < 5.0] == -1).all() and tr.cycle[-1] == -1  # last cycle incomplete
    disp = np.linalg.norm((tr.shoulder - tr.nominal_shoulder)[:, :2], axis=1)
    np.testing.assert_allclose(tr.shoulder_displacement_m, disp)


def test_custom_layout() -> None:
    layout = (("rest", 4.0), ("proper", 30.0), ("transition", 10.0), ("compensatory", 40.0))
    sim = simulate(SimConfig(seed=4, duration_s=84.0, layout=layout, imu_rate_hz=50.0))
    c = sim.truth.cycles
    assert set(np.unique(c.phase)) == {PROPER, TRANSITION, COMPENSATORY}
    check_verdicts(sim)
    assert (sim.truth.phase[sim.truth.t < 4.0] == REST).all()
    assert sim.truth.t[-1] == 84.0


def test_bad_layout_rejected() -> None:
    with pytest.raises(ValueError):
        SimConfig(layout=(("proper", 10.0),))
    with pytest.raises(ValueError):
        SimConfig(layout=(("rest", 5.0), ("jogging", 10.0)))


def test_truth_file_round_trip(default_sim: Simulation, tmp_path: Path) -> None:
    path = tmp_path / "truth.npz"
    default_sim.truth.save(path, default_sim.subject)
    back = Truth.load(path)
    for name in ("t", "shoulder", "q_imu", "phase", "cycle", "nominal_shoulder"):
        np.testing.assert_array_equal(getattr(back, name), getattr(default_sim.truth, name))
    assert back.cycles.to_list() == default_sim.truth.cycles.to_list()
    assert load_subject(path) == default_sim.subject
