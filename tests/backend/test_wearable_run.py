"""The live service's wearable run (:class:`backend.live.wearable_run.WearableLiveRun`) fed
message by message: ROM tests take the peak of sure rows only, a camera that drops out is a
message and a counted dropout, the counts are rehab analyze's."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from backend import analysis_wearable as aw
from backend.live.devices import DeviceStats
from backend.live.ingest import RawMessage
from backend.live.wearable_run import CAMERA_OUT, SURE_STD_DEG, WearableLiveRun
from estimators.wearable import tracker
from protocol import recording, wire
from simulator import wearable as sw


def raw(key: str, payload: dict[str, Any]) -> RawMessage:
    data = wire.dumps(payload)
    return RawMessage(key, data, len(data), 0.0, key.split("/")[2])


def last_t(payload: dict[str, Any]) -> float:
    t = payload["t"]
    return float(t[-1] if isinstance(t, list) else t)


def feed(run: WearableLiveRun, msgs: Iterable[tuple[str, dict[str, Any]]]) -> list[tracker.Rows]:
    out = []
    for key, payload in msgs:
        run.ingest(raw(key, payload))
        polled = run.poll()
        if polled is not None and polled.rows is not None:
            out.append(polled.rows)
    return out


def make_run(sim: sw.WearableSimulation) -> WearableLiveRun:
    params = aw.load_params(sim.params)
    return WearableLiveRun(
        sim.config.device, "rehab", DeviceStats(sim.config.device), params=params
    )


def test_rom_test_records_the_peak_of_sure_rows() -> None:
    sim = sw.simulate(sw.WearableSimConfig(move="rom", duration_s=8.0, seed=2, device="rom01"))
    run = make_run(sim)
    before = [m for m in sim.messages if last_t(m[1]) < 3.0]
    during = [m for m in sim.messages if 3.0 <= last_t(m[1]) < 7.0]
    feed(run, before)
    started = run.rom_start("shoulder_flexion")
    assert started["start_t"] is not None and started["peak_deg"] is None
    parts = feed(run, during)
    result = run.rom_stop()
    assert result is not None and run.rom_active is None
    rows = tracker.concat(parts)
    t0, t1 = result["start_t"], result["end_t"]
    keep = (
        (rows["t"] >= t0) & (rows["t"] <= t1) & (rows["shoulder_flexion_std_deg"] <= SURE_STD_DEG)
    )
    assert result["peak_deg"] == pytest.approx(
        float(rows["shoulder_flexion_deg"][keep].max()), abs=1e-3
    )
    assert 135.0 < result["peak_deg"] < 165.0  # the simulated movement reaches 150°
    assert result["sure_rows"] == int(keep.sum())
    # into the session's report; an unknown movement is refused
    assert run.report()["rom_tests"] == [result]
    with pytest.raises(ValueError, match="unknown movement"):
        run.rom_start("wiggle")


def test_rom_test_ignores_unsure_rows() -> None:
    """Without a forearm IMU no elbow angle is sure: an elbow test has no peak, not a made-up
    one."""
    sim = sw.simulate(sw.WearableSimConfig(move="rom", duration_s=6.0, seed=2, device="rom02"))
    run = make_run(sim)
    run.rom_start("elbow_flexion")
    feed(run, [m for m in sim.messages if not m[0].endswith("/forearm")])
    result = run.rom_stop()
    assert result is not None and result["rows"] > 0
    assert result["peak_deg"] is None and result["sure_rows"] == 0


def test_camera_dropout_is_a_message_and_counted(tmp_path: Path) -> None:
    cam = sw.CameraErrors(dropouts_per_min=0.0)
    sim = sw.simulate(
        sw.WearableSimConfig(move="reaching", duration_s=14.0, seed=7, device="cam01", cam=cam)
    )
    msgs = [m for m in sim.messages if not (m[0].endswith("/camera") and 6.0 <= last_t(m[1]) < 9.0)]
    run = make_run(sim)
    feed(run, [m for m in msgs if last_t(m[1]) < 5.0])
    st = run.status()
    assert CAMERA_OUT not in st["messages"] and st["quality"]["camera_dropouts"] == 0
    vertical_before = st["vertical_std_deg"]
    feed(run, [m for m in msgs if 5.0 <= last_t(m[1]) < 8.5])
    st = run.status()
    assert CAMERA_OUT in st["messages"]
    assert st["quality"]["camera_dropouts"] == 1
    assert st["vertical_std_deg"] > vertical_before  # less sure while the camera is out
    feed(run, [m for m in msgs if last_t(m[1]) >= 8.5])
    _, report = run.finish()
    assert CAMERA_OUT not in run.status()["messages"]  # back
    # rehab analyze counts the same
    path = tmp_path / "rec.jsonl.gz"
    recording.write(path, msgs)
    want = aw.analyze(path, aw.load_params(sim.params), tmp_path / "out", "cam01")
    assert report["data_quality"] == want["data_quality"]
    assert want["data_quality"]["camera_dropouts"] == 1
    assert np.isfinite(want["rom"]["shoulder_flexion_deg"]["max"])


def test_bad_messages_are_counted_by_reason() -> None:
    sim = sw.simulate(sw.WearableSimConfig(move="reaching", duration_s=3.0, seed=1, device="bad01"))
    run = make_run(sim)
    feed(run, sim.messages[:10])
    run.ingest(RawMessage("rehab/bad01/imu/forearm", b"{nope", 5, 0.0, "imu"))
    run.ingest(
        raw("rehab/bad01/robot", {"t": [1.0], "wrist": [[0, 0, 0]], "proximal": [[0, 0, 0]]})
    )
    assert run.stats.rejected == {"not_object": 1, "ignored_robot": 1}
    assert run.run.rejected == {"not_object": 1, "ignored_robot": 1}
    assert run.status()["quality"]["rejected"]["not_object"] == 1


@pytest.mark.parametrize("n", [3, 500])  # per-row and column-wise formatting
def test_joint_lines_are_the_per_cell_format(n: int) -> None:
    """joints.csv's text is ``f"{v:.{d}f}"`` per cell, empty where NaN or ±inf, whichever
    formatter the row count picks (recorded 6-decimal values and exact ties included)."""
    rng = np.random.default_rng(n)
    pool = np.concatenate(
        [
            rng.normal(size=n) * 10.0 ** rng.integers(-6, 4, size=n),
            rng.integers(-(10**9), 10**9, size=n) / 1e6,
            rng.integers(-(2**20), 2**20, size=n) / 2.0**12,
            [np.nan, np.inf, -np.inf, -0.0, 0.0, -0.0004, 0.0005, 2.0**53],
        ]
    )
    rows = {c: rng.choice(pool, size=n) for c in tracker.COLUMNS}
    digits = (6, *([3] * 5), *([4] * 6))
    expected = [
        ",".join(
            f"{rows[c][i]:.{d}f}" if np.isfinite(rows[c][i]) else ""
            for c, d in zip(tracker.COLUMNS, digits, strict=True)
        )
        for i in range(n)
    ]
    assert aw.joint_lines(rows) == expected  # type: ignore[arg-type]
