"""Wire output: decoding, ordering, sequence numbers, rates, batching and events."""

from __future__ import annotations

import itertools
import json

import numpy as np

from protocol import keys, wire
from simulator import SimConfig, Simulation, simulate
from tests.simulator.conftest import Streams, decode_all


def arrival_order(sim: Simulation) -> list[tuple[float, int]]:
    out = []
    for key, payload in sim.messages:
        kind = keys.parse(key).kind
        t = payload["t"][-1] if kind in ("imu", "robot") else payload["t"]
        out.append((t, {"imu": 0, "robot": 1, "event": 2}[kind]))
    return out


def test_every_message_decodes_from_json_text() -> None:
    sim = simulate(SimConfig(seed=5, duration_s=40.0, cycle_events=True))
    kinds = set()
    for key, payload in sim.messages:
        text = wire.dumps(payload)
        msg = wire.decode(key, text)
        kinds.add(type(msg).__name__)
        assert json.loads(text) == payload
    assert kinds == {"ImuMessage", "RobotMessage", "EventMessage"}


def test_default_streams(default_sim: Simulation, default_streams: Streams) -> None:
    keys_seen = {k for k, _ in default_sim.messages}
    assert keys_seen == {"rehab/sim01/imu/upperarm", "rehab/sim01/robot", "rehab/sim01/event"}
    # Rates, sample counts and one shared clock.
    assert np.allclose(np.diff(default_streams.imu_t), 0.01, atol=1e-9)
    assert np.allclose(np.diff(default_streams.robot_t), 0.04, atol=1e-9)
    assert default_streams.imu_t.shape[0] == 48001 and default_streams.robot_t.shape[0] == 12001
    np.testing.assert_array_equal(default_streams.imu_t, default_sim.truth.t)
    # Batching and seq.
    imu = [p for k, p in default_sim.messages if k.endswith("upperarm")]
    rob = [p for k, p in default_sim.messages if k.endswith("robot")]
    assert [p["seq"] for p in imu] == list(range(len(imu)))
    assert [p["seq"] for p in rob] == list(range(len(rob)))
    assert all(len(p["t"]) == 4 for p in imu[:-1]) and 1 <= len(imu[-1]["t"]) <= 4
    assert all(len(p["t"]) == 1 for p in rob)


def test_messages_in_arrival_order(default_sim: Simulation) -> None:
    order = arrival_order(default_sim)
    assert order == sorted(order)
    # IMU messages arrive with their 4th sample (t = 0.03, 0.07, …), robot ones at their stamp.
    assert order[:4] == [(0.0, 1), (0.03, 0), (0.04, 1), (0.07, 0)]


def test_ties_put_imu_first() -> None:
    sim = simulate(SimConfig(seed=2, duration_s=20.0, imu_batch=1, ideal=True))
    order = arrival_order(sim)
    assert order == sorted(order)
    ties = [(a, b) for a, b in itertools.pairwise(order) if a[0] == b[0]]
    assert all(a[1] < b[1] for a, b in ties)
    assert sum(1 for a, b in ties if (a[1], b[1]) == (0, 1)) == 501  # every robot stamp
    assert ((2.5, 0), (2.5, 2)) in ties  # the reference event after the IMU sample


def test_shoulder_reference_event(default_sim: Simulation, default_streams: Streams) -> None:
    (ev,) = default_streams.events
    assert ev.type == "shoulder_reference" and 0.0 < ev.t < 5.0
    assert ev.point is not None
    err = np.linalg.norm(ev.point - default_sim.truth.nominal_shoulder)
    assert 0.005 <= err <= 0.0101


def test_rates_batches_device_and_cycle_events() -> None:
    cfg = SimConfig(
        seed=6,
        duration_s=30.0,
        imu_rate_hz=250.0,
        robot_rate_hz=40.0,
        imu_batch=10,
        robot_batch=3,
        device="bench-7",
        cycle_events=True,
        t0_s=1000.0,
        ideal=True,
    )
    sim = simulate(cfg)
    s = decode_all(sim)
    assert {k.split("/")[1] for k, _ in sim.messages} == {"bench-7"}
    assert np.allclose(np.diff(s.imu_t), 1 / 250.0, atol=2e-6)
    assert np.allclose(np.diff(s.robot_t), 1 / 40.0, atol=2e-6)
    assert s.imu_t[0] == 1000.0 and s.imu_t[-1] == 1030.0 and s.imu_t.shape[0] == 7501
    imu = [p for k, p in sim.messages if "/imu/" in k]
    rob = [p for k, p in sim.messages if k.endswith("/robot")]
    assert {len(p["t"]) for p in imu[:-1]} == {10}
    assert {len(p["t"]) for p in rob[:-1]} == {3}
    ref = [e for e in s.events if e.type == "shoulder_reference"]
    starts = [e.t for e in s.events if e.type == "cycle_start"]
    assert len(ref) == 1 and ref[0].point is not None
    np.testing.assert_allclose(ref[0].point, sim.truth.nominal_shoulder, atol=1e-6)  # ideal
    cyc = sim.truth.cycles
    assert len(starts) in (len(cyc) + 1, len(cyc) + 2)  # plus the running cycle's start
    np.testing.assert_allclose(starts[: len(cyc)], cyc.start, atol=1e-6)
    assert arrival_order(sim) == sorted(arrival_order(sim))
