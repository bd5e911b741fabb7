"""Takeover without processes: a session's recording cut where its worker died, replayed
by the next worker, which then goes on with what arrives after a gap. The files come out
exactly as ``rehab analyze`` makes them from the final recording."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import orjson
import pytest

from backend.analysis import CSV_HEADER, analyze, dump_report
from backend.deps import SessionInfo
from backend.live.devices import DeviceStats
from backend.live.files import SessionFiles
from backend.live.ingest import RawMessage
from backend.live.node import replay
from backend.live.run import LiveRun, SessionContext, rows_ready
from estimators.params import PipelineParams
from protocol import keys, recording
from simulator import SimConfig, simulate

DEVICE = "tk01"


def _messages(seconds: float) -> list[tuple[str, bytes]]:
    sim = simulate(SimConfig(seed=7, duration_s=seconds, device=DEVICE))
    return [(k, orjson.dumps(p)) for k, p in sim.messages]


def _feed(run: LiveRun, key: str, payload: bytes, timer: bool = False) -> None:
    """As a live worker: poll when rows are ready, or (``timer``) whenever its clock says."""
    run.ingest(RawMessage(key, payload, len(payload), 0.0, keys.parse(key).kind))
    if run.fed_since_poll and (timer or rows_ready(run.pipeline)):
        run.poll()


@pytest.mark.parametrize("gap", [0, 150])
def test_replay_then_continue_equals_analysis(tmp_path: Path, gap: int) -> None:
    msgs = _messages(40.0)
    cut = len(msgs) // 3
    info = SessionInfo(id=1, device=DEVICE, patient_id=1, params={}, started_at=datetime.now(UTC))
    context = SessionContext(info, PipelineParams(), None)

    # the first holder: records and runs up to its death (its last flush)
    first = SessionFiles(tmp_path, 1)
    run = LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), context, first)
    for key, payload in msgs[:cut]:
        _feed(run, key, payload)
    first.flush()  # then SIGKILL: nothing closed

    # the next holder: replay into staged files, promote, go on after the gap
    staged = SessionFiles(tmp_path, 1, staging="epoch2")
    run2 = LiveRun(DEVICE, "rehab", DeviceStats(DEVICE), context, staged)
    replay(run2, first.recording_path, "rehab")
    staged.promote()
    for i, (key, payload) in enumerate(msgs[cut + gap :]):
        _feed(run2, key, payload, timer=i % 7 == 0)  # polls off the rows' rhythm too
    _, report = run2.finish()
    report["data_quality"]["other_devices"] = {}
    staged.close(report)

    rec = tmp_path / "recordings" / "1.jsonl.gz"
    lines = [(k, bytes(p)) for k, p in recording.read(rec)]
    assert lines == msgs[:cut] + msgs[cut + gap :]
    want_run, want = analyze(rec, PipelineParams())
    out = tmp_path / "recordings" / "1"
    assert (out / "estimates.csv").read_text() == CSV_HEADER + "\n" + "".join(
        x + "\n" for x in want_run.est_lines
    )
    assert (out / "report.json").read_text() == dump_report(want)
    assert sorted(p.name for p in (tmp_path / "recordings").iterdir()) == ["1", "1.jsonl.gz"]


def test_a_failed_takeover_attempt_does_not_block_the_next(tmp_path: Path) -> None:
    """A takeover attempt given up (the lease paused while replaying under load) leaves its
    staged files; the next attempt at the same epoch starts them afresh and can promote
    them. (Found in a fresh-clone run: every later attempt failed with FileExistsError and
    the session never resumed.)"""
    first = SessionFiles(tmp_path, 3, staging="epoch2")
    first.recorder.append("rehab/d/event", {"t": 1.0, "type": "cycle_start"})
    first.close(None)
    again = SessionFiles(tmp_path, 3, staging="epoch2")
    again.promote()
    again.close(None)
    assert list(recording.read(again.recording_path)) == []  # not the abandoned attempt's line
    assert (again.out / "estimates.csv").read_text() == CSV_HEADER + "\n"
