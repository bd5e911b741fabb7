"""``rehab simulate --mode wearable`` and ``rehab analyze`` of its recording (contract §8)."""

from __future__ import annotations

import csv
import gzip
import json

import numpy as np

from backend.cli import main

HEADER = (
    "t,shoulder_flexion_deg,shoulder_abduction_deg,shoulder_rotation_deg,elbow_flexion_deg,"
    "forearm_pronation_deg,elbow_x,elbow_y,elbow_z,wrist_x,wrist_y,wrist_z"
)


def _read(path):
    with open(path) as fh:
        return list(csv.reader(fh))


def test_simulate_then_analyze_writes_joints_csv_and_rom(tmp_path, capsys):
    sim = tmp_path / "sim"
    out = tmp_path / "out"
    assert (
        main(
            [
                "simulate",
                "--mode",
                "wearable",
                "--move",
                "rom",
                "--duration",
                "12",
                "--seed",
                "2",
                "--ideal",
                "--out",
                str(sim),
            ]
        )
        == 0
    )
    params = json.loads((sim / "params.json").read_text())
    assert params["mode"] == "wearable"
    assert (
        main(
            [
                "analyze",
                str(sim / "recording.jsonl.gz"),
                "--params",
                str(sim / "params.json"),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    lines = (out / "joints.csv").read_text().splitlines()
    assert lines[0] == HEADER
    rows = _read(out / "joints.csv")[1:]
    truth = np.loadtxt(sim / "truth.csv", delimiter=",", skiprows=1)
    assert len(rows) == len(truth)  # one row per upper-arm IMU sample
    est = np.array([[float(c) if c else np.nan for c in r] for r in rows])
    np.testing.assert_allclose(est[:, 0], truth[:, 0], atol=1e-6)
    late = truth[:, 0] > 3.0
    for col in (1, 4):  # shoulder and elbow flexion
        err = est[late, col] - truth[late, col]
        assert np.sqrt(np.nanmean(err**2)) < 3.0  # IMU errors off (--ideal): plumbing
    report = json.loads((out / "report.json").read_text())
    assert report["mode"] == "wearable" and report["cycles"] == []
    rom = report["rom"]["shoulder_flexion_deg"]
    assert rom["min"] <= rom["p5"] <= rom["p95"] <= rom["max"]
    assert 120.0 < rom["max"] < 170.0  # the ROM movement raises the arm to 150°


def test_analyze_without_forearm_leaves_cells_empty_and_counts(tmp_path):
    sim = tmp_path / "sim"
    assert (
        main(
            ["simulate", "--mode", "wearable", "--duration", "5", "--no-camera", "--out", str(sim)]
        )
        == 0
    )
    rec = tmp_path / "upper_only.jsonl.gz"
    with gzip.open(sim / "recording.jsonl.gz", "rt") as src, gzip.open(rec, "wt") as dst:
        for line in src:
            if "/imu/forearm" not in line:
                dst.write(line)
        dst.write('{"key": "rehab/wear01/imu/upperarm", "payload": {"t": [1.0], "gyr": [1]}}\n')
        dst.write("not json\n")
    out = tmp_path / "out"
    assert main(["analyze", str(rec), "--params", str(sim / "params.json"), "--out", str(out)]) == 0
    rows = _read(out / "joints.csv")[1:]
    assert rows and all(r[4] == "" and r[9] == "" for r in rows)  # elbow flexion, wrist_x
    assert all(r[1] != "" for r in rows)
    q = json.loads((out / "report.json").read_text())["data_quality"]
    assert q["rejected"]["forearm_missing"] == len(rows)
    assert sum(q["rejected"].values()) >= len(rows) + 2  # the bad payload and the bad line
