"""Robot cuffs: geometry, latency, rope oscillations, noise."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from simulator import SimConfig, Simulation, simulate
from tests.simulator.conftest import Streams, decode_all, elbow_from_cuffs


def best_lag(sim: Simulation, streams: Streams) -> tuple[float, float]:
    """Lag (s, 1 ms grid) that best aligns the cuff elbow with the true elbow, and its rms (m)."""
    elbow = elbow_from_cuffs(streams.wrist, streams.proximal)
    truth = CubicSpline(sim.truth.t, sim.truth.elbow)
    sel = streams.robot_t > 6.0
    lags = np.arange(0.0, 0.1, 0.001)
    rms = [
        np.sqrt(np.mean(np.sum((elbow[sel] - truth(streams.robot_t[sel] - lag)) ** 2, 1)))
        for lag in lags
    ]
    i = int(np.argmin(rms))
    return float(lags[i]), float(rms[i])


def test_ideal_cuffs_give_the_elbow_exactly(ideal_sim: Simulation, ideal_streams: Streams) -> None:
    elbow = elbow_from_cuffs(ideal_streams.wrist, ideal_streams.proximal)
    idx = np.searchsorted(ideal_sim.truth.t, ideal_streams.robot_t)
    np.testing.assert_array_equal(ideal_sim.truth.t[idx], ideal_streams.robot_t)
    assert np.abs(elbow - ideal_sim.truth.elbow[idx]).max() < 1e-5  # µm rounding
    # The wrist cuff is 2 cm proximal of the wrist, on the forearm axis.
    gap = np.linalg.norm(ideal_sim.truth.wrist[idx] - ideal_streams.wrist, axis=1)
    np.testing.assert_allclose(gap, 0.02, atol=2e-6)


def test_latency_is_visible_alone() -> None:
    sim = simulate(SimConfig(seed=8, duration_s=90.0, ideal=True, latency=True))
    lat = sim.subject.latency_s
    assert 0.02 <= lat <= 0.06
    lag, rms = best_lag(sim, decode_all(sim))
    assert abs(lag - lat) <= 0.001 and rms < 2e-4


def test_latency_is_visible_with_all_errors(
    default_sim: Simulation, default_streams: Streams
) -> None:
    lag, rms = best_lag(default_sim, default_streams)
    assert abs(lag - default_sim.subject.latency_s) <= 0.003
    assert 0.002 < rms < 0.006  # noise and rope


def test_rope_oscillates_after_corners() -> None:
    sim = simulate(SimConfig(seed=9, duration_s=90.0, ideal=True, rope=True))
    s, b = decode_all(sim), decode_all(simulate(SimConfig(seed=9, duration_s=90.0, ideal=True)))
    dev = np.linalg.norm(s.wrist - b.wrist, axis=1)
    prox = np.linalg.norm(s.proximal - b.proximal, axis=1)
    # A robot sample stamped t shows t − latency; latency is off here.
    corner_t = sim.truth.corner_t
    assert 60 < corner_t.size < 80  # 4 corners per ~5 s cycle
    last = np.clip(np.searchsorted(corner_t, s.robot_t, side="right") - 1, 0, None)
    since = s.robot_t - corner_t[last]
    early, late = (since >= 0) & (since < 0.5), (since > 0.9) | (s.robot_t < corner_t[0])
    assert 0.008 < dev[early].max() < 0.022
    assert dev[late].max() < 1e-5
    assert 0.3 < prox.max() / dev.max() < 1.2
    hit = np.unique(last[dev > 0.003])  # corners followed by a visible (> 3 mm) oscillation
    assert hit.size > 0.7 * corner_t.size


def test_robot_noise_magnitude() -> None:
    sim = simulate(SimConfig(seed=9, duration_s=60.0, ideal=True, robot_noise=True))
    base = simulate(SimConfig(seed=9, duration_s=60.0, ideal=True))
    d = decode_all(sim).proximal - decode_all(base).proximal
    assert abs(d.std() - 0.0015) < 0.0001
    assert abs(d.mean()) < 2e-4
