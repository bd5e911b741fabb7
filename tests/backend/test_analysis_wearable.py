"""``rehab analyze`` of a wearable recording (:mod:`backend.analysis_wearable`): in two
processes (the command's way) the same bytes as in one and as the live run's report, with
every rejection counted where it happened; a failure in the second process is an error
with its cause, never a hang or a half-written report."""

from __future__ import annotations

import gzip
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from backend import analysis_wearable as aw
from backend.report_json import dump_report
from protocol import recording
from simulator import wearable as sw


def _messages(events: bool) -> tuple[list[tuple[str, Any]], dict[str, Any]]:
    """A 45 s reaching session with a camera, spoiled: lines that are not messages, another
    device, a robot message, an unknown key, an upper-arm message back in time (the
    tracker's rejection, not the line's), and ``cycle_start`` events if asked."""
    sim = sw.simulate(sw.WearableSimConfig(move="reaching", duration_s=45.0, seed=4, device="w01"))
    msgs: list[tuple[str, Any]] = list(sim.messages)
    upper = [i for i, (k, _) in enumerate(msgs) if k.endswith("/imu/upperarm")]
    back = dict(msgs[upper[100]][1])
    back["t"] = [float(t) - 2.0 for t in back["t"]]
    msgs.insert(upper[150], ("rehab/w01/imu/upperarm", back))
    msgs.insert(50, ("rehab/w02/imu/upperarm", msgs[upper[10]][1]))
    msgs.insert(
        60, ("rehab/w01/robot", {"t": [1.0], "wrist": [[0, 0, 0]], "proximal": [[0, 0, 0]]})
    )
    msgs.insert(70, ("rehab/w01/bogus", {}))
    if events:
        for t in (4.0, 8.0, 12.0, 16.0):
            i = next(j for j, (k, p) in enumerate(msgs) if k.endswith("/camera") and p["t"][0] > t)
            msgs.insert(i, ("rehab/w01/event", {"t": t, "type": "cycle_start"}))
    return msgs, sim.params


def _write(tmp_path: Path, msgs: list[tuple[str, Any]]) -> Path:
    path = tmp_path / "recording.jsonl.gz"
    recording.write(path, msgs)
    with path.open("ab") as fh:  # lines that are not messages, in a second gzip member
        fh.write(gzip.compress(b'not json\n{"key": 1}\n'))
    return path


@pytest.mark.parametrize("events", [False, True])
def test_two_processes_write_the_bytes_of_one_and_of_the_live_run(
    tmp_path: Path, events: bool
) -> None:
    msgs, params_obj = _messages(events)
    path = _write(tmp_path, msgs)
    params = aw.load_params(params_obj)
    one = aw.analyze(path, params, tmp_path / "one")
    two = aw.analyze(path, params, tmp_path / "two", parallel=True)
    for name in (aw.JOINTS_NAME, aw.REPORT_NAME):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
    assert json.loads(dump_report(one)) == json.loads(dump_report(two))
    rejected = two["data_quality"]["rejected"]
    # the lines' rejections (the second process's) and the tracker's (this one's), merged
    assert rejected["malformed_line"] == 2 and rejected["unknown_key"] == 1
    assert rejected["other_device"] == 1 and rejected["ignored_robot"] == 1
    assert rejected["time_backwards_upperarm"] == 10  # its samples
    assert two["device"] == "w01" and two["summary"]["rows"] > 4000
    if events:  # the movements between the events
        assert [(m["start"], m["end"]) for m in two["movements"]] == [(4, 8), (8, 12), (12, 16)]
    else:  # found from the wrist path as it came, in the second process
        assert two["summary"]["movements"] >= 3
    # the live run (one process, every row kept, the report at the end) writes the same
    run = aw.WearableRun(params)
    for key, payload in recording.read(path):
        run.feed_line(key, payload)
    run.finish()
    assert dump_report(run.report()) == (tmp_path / "one" / aw.REPORT_NAME).read_text()
    assert (
        aw.joint_lines(run.rows())
        == ((tmp_path / "one" / aw.JOINTS_NAME).read_text().splitlines()[1:])
    )


def test_a_failure_in_the_second_process_is_an_error_with_its_cause(tmp_path: Path) -> None:
    msgs, params_obj = _messages(False)
    path = _write(tmp_path, msgs[:400])
    blocked = tmp_path / "file"
    blocked.write_text("a file where the output folder should go")
    with pytest.raises(RuntimeError, match=r"second process failed(.|\n)*FileExistsError"):
        aw.analyze(path, aw.load_params(params_obj), blocked, parallel=True)
    assert blocked.read_text().startswith("a file")


def test_rows_handed_over_in_any_batches_give_the_same_outputs(tmp_path: Path) -> None:
    """The writer's streaming movements and CSV lines do not depend on the blocks' sizes."""
    msgs, params_obj = _messages(False)
    params = aw.load_params(params_obj)
    run = aw.WearableRun(params)
    for key, payload in recording.read(_write(tmp_path, msgs)):
        run.feed_line(key, payload)
    run.finish()
    block = run.rows().block  # type: ignore[attr-defined]
    info = run.info()
    outs, names = [], (aw.JOINTS_NAME, aw.REPORT_NAME)  # type: ignore[var-annotated]
    for k, cuts in enumerate(([], [1, 2, 500], list(range(7, block.shape[1], 613)))):
        w = aw.ReportWriter(params, tmp_path / str(k))
        for part in np.split(block, cuts, axis=1):
            w.add(part)
        w.finish(info)
        outs.append([(tmp_path / str(k) / n).read_bytes() for n in names])
    assert outs[0] == outs[1] == outs[2]
    assert json.loads(outs[0][1])["summary"]["movements"] >= 3


def test_two_processes_from_a_process_with_threads(tmp_path: Path) -> None:
    """With another thread running (a lock it holds would be copied held into a fork) the
    second process is spawned, not forked: the same bytes."""
    import threading

    msgs, params_obj = _messages(False)
    path = _write(tmp_path, msgs[:1500])
    params = aw.load_params(params_obj)
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        two = aw.analyze(path, params, tmp_path / "two", parallel=True)
    finally:
        stop.set()
        other.join()
    one = aw.analyze(path, params, tmp_path / "one")
    for name in (aw.JOINTS_NAME, aw.REPORT_NAME):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes()
    assert two["summary"]["rows"] == one["summary"]["rows"] > 500
