"""``rehab evaluate`` of a simulated wearable session: the per-joint tables against truth.csv,
and they see an error that is there."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from evaluation import evaluate_wearable as ew


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("wev")
    run = [sys.executable, "-m", "backend.cli"]
    subprocess.run(
        # the paper's sensors (--ideal): the tables, not a sampled camera offset's tail
        [
            *run,
            "simulate",
            "--mode",
            "wearable",
            "--duration",
            "12",
            "--ideal",
            "--out",
            str(d / "sim"),
        ],
        check=True,
        capture_output=True,
    )
    subprocess.run(
        [
            *run,
            "analyze",
            str(d / "sim" / "recording.jsonl.gz"),
            "--params",
            str(d / "sim" / "params.json"),
            "--out",
            str(d / "an"),
        ],
        check=True,
        capture_output=True,
    )
    return d / "an", d / "sim" / "truth.csv"


def test_tables_of_a_simulated_session(session: tuple[Path, Path]) -> None:
    an, truth = session
    res = ew.evaluate(an, truth)
    assert res["rows"] == 1000  # 12 s at 100 Hz, minus the 2 s rest window
    for c in ("shoulder_flexion_deg", "shoulder_abduction_deg", "elbow_flexion_deg"):
        e = res["angles_deg"][c]
        assert e["n"] == 1000 and e["missing"] == 0
        assert 0.0 < e["rmse"] < 1.0 and e["rmse"] <= e["peak"]
    assert 0.0 < res["positions_m"]["elbow"]["rmse"] < 0.03
    out = subprocess.run(
        [sys.executable, "-m", "backend.cli", "evaluate", str(an), "--truth", str(truth)],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    assert "| shoulder_flexion_deg |" in out and "| wrist |" in out


def test_an_error_shows(session: tuple[Path, Path], tmp_path: Path) -> None:
    """10° added to every flexion value: its RMSE grows by about 10°, empty cells are counted."""
    an, truth = session
    lines = (an / "joints.csv").read_text().splitlines()
    j = lines[0].split(",").index("shoulder_flexion_deg")
    out = [lines[0]]
    for i, line in enumerate(lines[1:]):
        cells = line.split(",")
        cells[j] = "" if i % 10 == 0 else f"{float(cells[j]) + 10.0:.3f}"
        out.append(",".join(cells))
    (tmp_path / "joints.csv").write_text("\n".join(out) + "\n")
    base = ew.evaluate(an, truth)["angles_deg"]["shoulder_flexion_deg"]
    bad = ew.evaluate(tmp_path, truth)["angles_deg"]["shoulder_flexion_deg"]
    assert bad["missing"] == 100
    assert bad["rmse"] == pytest.approx(10.0, abs=base["rmse"] + 0.5)
