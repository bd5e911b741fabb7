"""Shared fixtures: short simulated sessions (real physics, every error source on)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pytest

from protocol import wire
from simulator import SimConfig, Simulation, simulate

SHORT_LAYOUT = (("rest", 5.0), ("proper", 45.0), ("transition", 10.0), ("compensatory", 40.0))


@dataclass(frozen=True)
class Session:
    sim: Simulation
    raw: list[tuple[str, dict[str, Any]]]
    messages: list[wire.Message]


def make_session(seed: int, duration_s: float = 100.0, **kw: Any) -> Session:
    cfg = SimConfig(seed=seed, duration_s=duration_s, layout=kw.pop("layout", SHORT_LAYOUT), **kw)
    sim = simulate(cfg)
    return Session(sim, sim.messages, [wire.decode(k, p) for k, p in sim.messages])


@pytest.fixture(scope="session")
def short_session() -> Session:
    """100 s: rest, proper, transition, compensatory (seed 7)."""
    return make_session(7)
