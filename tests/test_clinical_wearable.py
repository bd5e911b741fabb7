"""The clinical sections of a wearable session (contract §8): ISB shoulder angles from the
model's joint angles, ROM per session and per movement, movements found from the wrist path,
movement quality, key figures; through ``rehab analyze`` against the simulator's truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from backend import clinical
from backend.cli import main
from estimators import anatomy


def test_wearable_isb_angles_of_known_poses() -> None:
    flex = np.array([90.0, 0.0, 0.0, 45.0, 90.0, np.nan])
    abd = np.array([0.0, 90.0, 0.0, 0.0, 0.0, 0.0])
    rot = np.array([0.0, 0.0, 0.0, 0.0, 30.0, 0.0])
    a = anatomy.wearable_isb_angles(flex, abd, rot)
    plane, elev, axial = (a[k] for k in anatomy.ISB_ANGLES)
    # forward flexion: ISB (90, 90, -90), as the robot mode's (anatomy's docstring)
    assert (plane[0], elev[0], axial[0]) == pytest.approx((90.0, 90.0, -90.0), abs=1e-9)
    # abduction: in the frontal plane, no rotation
    assert (plane[1], elev[1], axial[1]) == pytest.approx((0.0, 90.0, 0.0), abs=1e-9)
    # hanging: elevation 0, plane and axial rotation undefined (gimbal lock)
    assert elev[2] == pytest.approx(0.0) and np.isnan(plane[2]) and np.isnan(axial[2])
    assert elev[3] == pytest.approx(45.0)
    # internal rotation (positive in both conventions) raises ISB's gamma by as much
    assert axial[4] - axial[0] == pytest.approx(30.0)
    assert np.isnan(elev[5])


def _reaching(n_moves: int = 8, period: float = 3.0, hz: float = 100.0) -> dict[str, Any]:
    """Joint angles and a wrist path of ``n_moves`` minimum-jerk reaches out and back."""
    t = np.arange(0.0, n_moves * period, 1.0 / hz)
    s = (t % period) / period
    out_back = np.where(s < 0.5, 2 * s, 2 - 2 * s)
    mj = 10 * out_back**3 - 15 * out_back**4 + 6 * out_back**5
    flexion = 10.0 + 60.0 * mj
    elbow = 90.0 - 70.0 * mj
    return {
        "t": t,
        "shoulder_flexion_deg": flexion,
        "shoulder_abduction_deg": np.full_like(t, 5.0),
        "shoulder_rotation_deg": np.zeros_like(t),
        "elbow_flexion_deg": elbow,
        "forearm_pronation_deg": np.full_like(t, 20.0),
        "wrist_x": 0.15 + 0.30 * mj,
        "wrist_y": np.full_like(t, -0.05),
        "wrist_z": np.full_like(t, -0.3),
    }


def test_wearable_sections_rom_per_session_and_movement() -> None:
    j = _reaching()
    t = j["t"]
    moves = [{"start": 3.0 * i, "end": 3.0 * (i + 1)} for i in range(8)]
    valid = t >= 1.0
    sec = clinical.wearable_sections(t, j, valid, movements=moves)
    assert sec["movements"] == moves
    rom = sec["anatomical_rom"]
    assert rom["reference_frame"].startswith("shoulder frame S") and "trunk" in rom["note"]
    session = rom["session"]
    # the robot mode's ISB names and elbow flexion, then the model's own angles
    assert set(anatomy.ISB_ANGLES) | set(clinical.WEARABLE_ANGLES) == set(session)
    assert session["elbow_flexion_deg"] == anatomy.rom_stats(j["elbow_flexion_deg"][valid])
    assert session["shoulder_flexion_deg"] == anatomy.rom_stats(j["shoulder_flexion_deg"][valid])
    # small abduction: ISB elevation close to the flexion
    assert session["shoulder_elevation_deg"]["max"] == pytest.approx(70.0, abs=1.0)
    assert len(rom["cycles"]) == 8
    c2 = rom["cycles"][2]["angles"]["elbow_flexion_deg"]
    assert c2["max"] == pytest.approx(90.0) and c2["min"] == pytest.approx(20.0, abs=0.01)
    quality = sec["movement_quality"]
    assert quality["source"] == "wrist (wearable model)" and len(quality["cycles"]) == 8
    assert all(c["compensatory"] is None for c in quality["cycles"])
    # seen from above as (right, forward) like the robot mode's: S's y points left
    xy = np.array(quality["cycles"][0]["path_xy"])
    assert np.allclose(xy[:, 0], 0.05) and xy[:, 1].min() == pytest.approx(0.15, abs=0.01)
    assert xy[:, 1].max() == pytest.approx(0.45, abs=0.01)
    med = quality["session_median"]
    assert med["path_length_m"] == pytest.approx(0.60, rel=0.01)  # 0.30 out and back
    assert med["straightness_ratio"] == pytest.approx(1.0, abs=0.01)
    keys = [f["key"] for f in sec["key_figures"]]
    assert keys == ["shoulder_elevation_range_deg", "elbow_flexion_range_deg", "sparc_median"]
    elbow = next(f for f in sec["key_figures"] if f["key"] == "elbow_flexion_range_deg")
    assert elbow["value"] == session["elbow_flexion_deg"]["range"]
    json.dumps(sec, allow_nan=False)  # report.json refuses NaN


def test_wearable_movements_from_the_wrist_path_or_events() -> None:
    j = _reaching(n_moves=10)
    wrist = np.stack([j["wrist_x"], j["wrist_y"], j["wrist_z"]], axis=1)
    found = clinical.wearable_movements(j["t"], wrist)
    assert len(found) >= 7  # the first ones open the detector
    assert all(m["end"] - m["start"] == pytest.approx(3.0, abs=0.2) for m in found)
    wrist[::7] = np.nan  # rows without a wrist (no forearm sample) are skipped
    assert len(clinical.wearable_movements(j["t"], wrist)) == len(found)
    events = [3.0 * i for i in range(11)]
    by_events = clinical.wearable_movements(j["t"], wrist, events)
    assert [m["start"] for m in by_events] == pytest.approx(events[:-1][: len(by_events)])
    assert len(by_events) >= 9
    assert clinical.wearable_movements(np.zeros(0), np.zeros((0, 3))) == []


@pytest.fixture(scope="module")
def wearable_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    d = tmp_path_factory.mktemp("wearable")
    sim = d / "sim"
    assert (
        main(
            [
                *("simulate", "--mode", "wearable", "--move", "reaching", "--duration", "45"),
                *("--seed", "2", "--ideal", "--out", str(sim)),
            ]
        )
        == 0
    )
    rec, params = sim / "recording.jsonl.gz", sim / "params.json"
    assert main(["analyze", str(rec), "--params", str(params), "--out", str(d / "out")]) == 0
    return d, json.loads((d / "out" / "report.json").read_text())


def test_rehab_analyze_wearable_report_matches_the_truth(
    wearable_run: tuple[Path, dict[str, Any]],
) -> None:
    d, rep = wearable_run
    assert rep["mode"] == "wearable" and rep["cycles"] == []
    # the reach detector's first cycle spans the move from the rest pose; it restarts after
    # max_cycle_s (30 s), so movements are found from then on
    assert rep["summary"]["movements"] == len(rep["movements"]) >= 3
    truth = np.genfromtxt(d / "sim" / "truth.csv", delimiter=",", names=True)
    joints = np.genfromtxt(d / "out" / "joints.csv", delimiter=",", names=True)
    assert np.array_equal(truth["t"], joints["t"])
    # the truth's sections over the same rows (after the start's rest window)
    valid = joints["t"] >= rep["summary"]["start"] + 2.0
    cols = {k: truth[k] for k in truth.dtype.names}
    ref = clinical.wearable_sections(truth["t"], cols, valid, movements=rep["movements"])
    got = rep["anatomical_rom"]["session"]
    for name in ("shoulder_elevation_deg", "elbow_flexion_deg", "shoulder_flexion_deg"):
        for stat in ("min", "max", "p5", "p95", "range"):
            assert got[name][stat] == pytest.approx(
                ref["anatomical_rom"]["session"][name][stat], abs=3.0
            ), (name, stat)
    assert len(rep["anatomical_rom"]["cycles"]) == len(rep["movements"])
    assert rep["key_figures"][0]["value"] == got["shoulder_elevation_deg"]["range"]
    med = rep["movement_quality"]["session_median"]
    true_med = ref["movement_quality"]["session_median"]
    assert med["path_length_m"] == pytest.approx(true_med["path_length_m"], rel=0.1)
    assert clinical.summary_part(rep)["anatomical_rom_deg"] == got
