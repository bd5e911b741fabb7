"""Same seed → identical output; different seeds → different subjects."""

from __future__ import annotations

import json

from simulator import SimConfig, Simulation, simulate


def test_same_seed_same_messages(default_sim: Simulation) -> None:
    again = simulate(SimConfig(seed=1))
    assert json.dumps(again.messages) == json.dumps(default_sim.messages)
    assert again.subject == default_sim.subject


def test_different_seed_differs() -> None:
    a = simulate(SimConfig(seed=21, duration_s=20.0))
    b = simulate(SimConfig(seed=22, duration_s=20.0))
    assert a.subject.upper_arm_m != b.subject.upper_arm_m
    assert json.dumps(a.messages) != json.dumps(b.messages)
