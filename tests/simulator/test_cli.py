"""``simulate`` sub-command."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from protocol import recording, wire
from simulator import cli
from simulator.subject import Subject
from simulator.truth import Truth, load_subject


def test_writes_recording_truth_and_subject(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    argv = [
        "simulate",
        "--seed",
        "3",
        "--duration",
        "30",
        "--out",
        str(out),
        "--imu-rate",
        "200",
        "--robot-rate",
        "50",
        "--imu-batch",
        "5",
        "--device",
        "d2",
        "--cycle-events",
    ]
    assert cli.main(argv) == 0
    line = capsys.readouterr().out
    assert line.count("\n") == 1 and "seed 3" in line
    lines = list(recording.read(out / "recording.jsonl.gz"))
    msgs = [wire.decode(k, p) for k, p in lines if k is not None]
    assert len(msgs) == len(lines)
    imu = [m for m in msgs if isinstance(m, wire.ImuMessage)]
    assert {m.device for m in msgs} == {"d2"} and len(imu[0].t) == 5
    assert any(isinstance(m, wire.EventMessage) and m.type == "cycle_start" for m in msgs)
    truth = Truth.load(out / "truth.npz")
    assert truth.t.shape == (6001,)
    subject = Subject.from_json((out / "subject.json").read_text())
    assert load_subject(out / "truth.npz") == subject
    first = (out / "recording.jsonl.gz").read_bytes()
    assert cli.main(argv) == 0
    assert (out / "recording.jsonl.gz").read_bytes() == first  # byte-identical (gzip mtime 0)


def test_ideal_flag_and_parser_registration(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser(prog="rehab")
    sub = parser.add_subparsers(dest="command")
    cli.add_parser(sub)
    args = parser.parse_args(["simulate", "--out", str(tmp_path), "--duration", "12", "--ideal"])
    assert args.seed == 0 and args.imu_rate == 100.0 and args.imu_batch == 4
    assert args.func is cli.run
    assert cli.run(args) == 0
    truth = Truth.load(tmp_path / "truth.npz")
    np.testing.assert_array_equal(truth.q_imu, truth.q_ra)  # no misalignment, no wobble


def test_bad_arguments_fail_cleanly(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["simulate", "--out", str(tmp_path), "--device", "bad name"]) == 2
    assert "device" in capsys.readouterr().err
