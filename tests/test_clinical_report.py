"""`rehab analyze`'s clinical sections: anatomical ROM against the simulator's truth, movement
quality per cycle, key figures."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from backend.cli import main
from estimators import anatomy
from estimators import movement_quality as mq
from protocol import recording
from tests.conftest import Session


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory, short_session: Session) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("clinical")
    recording.write(d / "recording.jsonl.gz", short_session.raw)
    assert main(["analyze", str(d / "recording.jsonl.gz"), "--out", str(d / "out")]) == 0
    rep: dict[str, Any] = json.loads((d / "out" / "report.json").read_text())
    return rep


def test_session_rom_in_isb_angles_matches_the_truth(
    report: dict[str, Any], short_session: Session
) -> None:
    rom = report["anatomical_rom"]
    assert rom["reference_frame"] == "robot" and "stands in for the trunk" in rom["note"]
    truth = short_session.sim.truth
    after = truth.t >= report["heading"]["converged_t"]
    true_angles = anatomy.shoulder_angles(truth.q_ra[after])
    tolerance = {  # degrees; the estimated orientation's error, not the statistics'
        "shoulder_elevation_deg": 2.0,
        "shoulder_plane_of_elevation_deg": 6.0,
        "shoulder_axial_rotation_deg": 4.0,
    }
    for name, tol in tolerance.items():
        est, ref = rom["session"][name], anatomy.rom_stats(true_angles[name])
        for k in ("p5", "p95", "range"):
            assert est[k] == pytest.approx(ref[k], abs=tol), (name, k)
    elbow = rom["session"]["elbow_flexion_deg"]
    assert elbow == report["elbow_flexion_deg"]  # the same rows as the existing section


def test_per_cycle_rom_follows_each_cycle(report: dict[str, Any], short_session: Session) -> None:
    truth = short_session.sim.truth
    cycles = report["anatomical_rom"]["cycles"]
    assert [(c["start"], c["end"]) for c in cycles] == [
        (c["start"], c["end"]) for c in report["cycles"]
    ]
    for c in cycles:
        inside = (truth.t >= c["start"]) & (truth.t < c["end"])
        ref = anatomy.rom_stats(
            anatomy.shoulder_angles(truth.q_ra[inside])["shoulder_elevation_deg"]
        )
        est = c["angles"]["shoulder_elevation_deg"]
        assert est["max"] == pytest.approx(ref["max"], abs=3.0)
        assert est["min"] == pytest.approx(ref["min"], abs=3.0)


def test_movement_quality_per_cycle_and_medians(report: dict[str, Any]) -> None:
    mqs = report["movement_quality"]
    rows = mqs["cycles"]
    assert len(rows) == len(report["cycles"])
    assert mqs["params"]["sparc_fc_hz"] == 10.0 and mqs["params"]["sparc_amp_threshold"] == 0.05
    for r, c in zip(rows, report["cycles"], strict=True):
        assert r["compensatory"] == c["compensatory"]
        assert r["movement_time_s"] == pytest.approx(c["end"] - c["start"], abs=0.1)
        # the simulated task is a rectangle in the horizontal plane: a closed path, so the
        # path is longer than the two straight lines out to the farthest corner and back
        assert 1.2 < r["straightness_ratio"] < 2.0
        assert r["path_length_m"] == pytest.approx(r["mean_speed_m_s"] * r["movement_time_s"])
        assert r["peak_speed_m_s"] > r["mean_speed_m_s"]
        assert r["movement_units"] >= 4  # at least one per side of the rectangle
        assert r["sparc"] < mq.sparc(np.sin(np.linspace(0, np.pi, 100)) ** 2, 25.0)
        assert 2 <= len(r["path_xy"]) <= 41
    for k in mq.QUALITY_FIELDS:
        assert mqs["session_median"][k] == pytest.approx(np.median([r[k] for r in rows]))


def test_key_figures_lead_the_report(report: dict[str, Any]) -> None:
    figures = {f["key"]: f for f in report["key_figures"]}
    s = report["summary"]
    assert figures["compensatory_cycles_pct"]["value"] == pytest.approx(
        100 * s["compensatory_share"]
    )
    elev = report["anatomical_rom"]["session"]["shoulder_elevation_deg"]
    assert figures["shoulder_elevation_range_deg"]["value"] == elev["range"]
    assert figures["sparc_median"]["value"] == report["movement_quality"]["session_median"]["sparc"]


def test_empty_recording_has_empty_sections(tmp_path: Path) -> None:
    (tmp_path / "empty.jsonl").write_text("")
    assert main(["analyze", str(tmp_path / "empty.jsonl"), "--out", str(tmp_path / "out")]) == 0
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert rep["anatomical_rom"]["session"]["shoulder_elevation_deg"]["range"] is None
    assert rep["movement_quality"]["cycles"] == []
    assert all(v is None for v in rep["movement_quality"]["session_median"].values())
    assert rep["key_figures"][0]["value"] is None


def test_session_summary_keeps_rom_and_quality_for_the_history(report: dict[str, Any]) -> None:
    from backend.live.worker import session_summary

    s = session_summary(report)
    assert s["anatomical_rom_deg"] == report["anatomical_rom"]["session"]
    assert s["movement_quality_median"] == report["movement_quality"]["session_median"]
    old = {k: v for k, v in report.items() if k not in ("anatomical_rom", "movement_quality")}
    assert session_summary(old)["anatomical_rom_deg"] is None


def test_live_reports_measure_each_cycle_once(short_session: Session) -> None:
    """A report asked for again and again mid-session (the live service) measures each
    completed cycle once, and says the same as a fresh computation."""
    from backend import clinical
    from backend.analysis import DeviceRun
    from estimators.params import PipelineParams

    run = DeviceRun("sim01", PipelineParams())
    sizes: list[int] = []
    reported = 0
    for m in short_session.messages:
        run.pipeline.feed(m)
        run.take(run.pipeline.poll())
        if len(run.cycles) > reported and len(run.cycles) % 4 == 0:
            reported = len(run.cycles)
            rep = run.report()
            sizes.append(len(run._clinical))
            fresh = clinical.sections(
                {k: np.concatenate(v) for k, v in run._stats.items()}, run.cycles, {}
            )
            assert rep["movement_quality"] == fresh["movement_quality"]
            assert rep["anatomical_rom"]["cycles"] == fresh["anatomical_rom"]["cycles"]
    assert len(sizes) >= 3 and sizes[-1] == 2 * reported  # one ROM, one quality entry each
