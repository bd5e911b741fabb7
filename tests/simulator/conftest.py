"""Shared simulated sessions (each full 8-minute session takes ~1–2 s)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from protocol import wire
from simulator import SimConfig, Simulation, simulate


@dataclass(frozen=True)
class Streams:
    """Decoded streams of a simulation, concatenated per kind."""

    imu_t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    robot_t: np.ndarray
    wrist: np.ndarray
    proximal: np.ndarray
    events: list[wire.EventMessage]


def decode_all(sim: Simulation) -> Streams:
    imu: list[wire.ImuMessage] = []
    rob: list[wire.RobotMessage] = []
    events: list[wire.EventMessage] = []
    for key, payload in sim.messages:
        msg = wire.decode(key, payload)  # JSON text round trip: see test_messages
        if isinstance(msg, wire.ImuMessage):
            imu.append(msg)
        elif isinstance(msg, wire.RobotMessage):
            rob.append(msg)
        elif isinstance(msg, wire.EventMessage):
            events.append(msg)
        else:  # pragma: no cover - the simulator publishes no camera
            raise AssertionError(type(msg))
    return Streams(
        np.concatenate([m.t for m in imu]),
        np.concatenate([m.gyr for m in imu]),
        np.concatenate([m.acc for m in imu]),
        np.concatenate([m.t for m in rob]),
        np.concatenate([m.wrist for m in rob]),
        np.concatenate([m.proximal for m in rob]),
        events,
    )


@pytest.fixture(scope="session")
def default_sim() -> Simulation:
    return simulate(SimConfig(seed=1))


@pytest.fixture(scope="session")
def default_streams(default_sim: Simulation) -> Streams:
    return decode_all(default_sim)


@pytest.fixture(scope="session")
def ideal_sim() -> Simulation:
    return simulate(SimConfig(seed=3, ideal=True))


@pytest.fixture(scope="session")
def ideal_streams(ideal_sim: Simulation) -> Streams:
    return decode_all(ideal_sim)


def elbow_from_cuffs(
    wrist: np.ndarray, proximal: np.ndarray, cuff_to_elbow: float = 0.06
) -> np.ndarray:
    """Contract eq. 13."""
    d = proximal - wrist
    return np.asarray(proximal + cuff_to_elbow * d / np.linalg.norm(d, axis=1, keepdims=True))
