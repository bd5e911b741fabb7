"""The live service's cheap paths give exactly what the simple ones give.

A live session formats its CSV rows a poll (one or two rows) at a time and records its raw
messages in buffered, batch-compressed flushes; the files must still equal what ``rehab
analyze`` writes from the recording, and a recording cut by ``kill -9`` must still hold every
line flushed before.
"""

from __future__ import annotations

import gzip
import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from backend import analysis, csv_text
from protocol import recording

SPECIAL = [0.0, -0.0, 0.5, -0.5, 2.5, 0.0005, 2.0005, 0.301475, -0.234775, 9.9999995]
SPECIAL += [999.9995, 1e15, 1e17, 1e300, 5e-324, math.inf, -math.inf, math.nan]

# name → width, in the order of one matrix whose column views the rows are (as the
# pipeline's rows are views of one array)
LAYOUT = [
    ("t", 1),
    ("elbow", 3),
    ("shoulder", 3),
    ("elbow_angle_deg", 1),
    ("heading_offset_deg", 1),
    ("shoulder_displacement_m", 1),
    ("q_ra", 4),
    ("heading_std_deg", 1),
    ("heading_confidence", 1),
    ("upper_arm_elevation_deg", 1),
    ("upper_arm_azimuth_deg", 1),
    ("nominal_shoulder", 3),
    ("conv_elbow_angle_deg", 1),
    ("wrist", 3),
    ("upper_arm_length_m", 1),
]


def random_rows(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    width = sum(w for _, w in LAYOUT)
    pool = np.concatenate(
        [
            rng.normal(size=64) * 10.0 ** rng.integers(-7, 9, size=64),
            rng.integers(-(10**9), 10**9, size=64) / 1e6,
            rng.integers(-(2**20), 2**20, size=64) / 2.0**12,
            SPECIAL,
        ]
    )
    m = rng.choice(pool, size=(n, width))
    m[:, 0] = np.sort(np.abs(m[:, 0]))
    rows: dict[str, np.ndarray] = {}
    a = 0
    for name, w in LAYOUT:
        rows[name] = m[:, a] if w == 1 else m[:, a : a + w]
        a += w
    rows["heading_converged"] = rng.random(n) > 0.5
    rows["state"] = rng.integers(-1, 3, size=n).astype(np.int8)
    return rows


def percent_per_row(rows: dict[str, np.ndarray]) -> tuple[list[str], list[str]]:
    """The files' lines as ``fmt % row``, one column list per cell."""
    el, sh = rows["elbow"], rows["shoulder"]
    est: list[list[Any]] = [
        rows["t"].tolist(),
        *(el[:, j].tolist() for j in range(3)),
        *(sh[:, j].tolist() for j in range(3)),
        rows["elbow_angle_deg"].tolist(),
        rows["heading_offset_deg"].tolist(),
        rows["heading_converged"].astype(np.int64).tolist(),
        rows["shoulder_displacement_m"].tolist(),
        [analysis.STATE_NAMES[int(s)] for s in rows["state"].tolist()],
    ]
    det: list[list[Any]] = []
    for name in (
        "t",
        "q_ra",
        "heading_std_deg",
        "heading_confidence",
        "upper_arm_elevation_deg",
        "upper_arm_azimuth_deg",
        "nominal_shoulder",
        "conv_elbow_angle_deg",
        "wrist",
        "upper_arm_length_m",
    ):
        a = rows[name]
        det += [a.tolist()] if a.ndim == 1 else [a[:, j].tolist() for j in range(a.shape[1])]
    return (
        csv_text.format_rows(analysis._EST_FMT, est),
        csv_text.format_rows(analysis._DET_FMT, det),
    )


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([1, 2, 3, 7, 63, 64, 200]))
def test_csv_lines_are_percent_per_row(seed: int, n: int) -> None:
    rows = random_rows(np.random.default_rng(seed), n)
    est, det = percent_per_row(rows)
    assert analysis.estimate_lines(rows) == est
    assert analysis.detail_lines(rows) == det


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_csv_lines_do_not_depend_on_the_polls(seed: int) -> None:
    """A live session's polls of a row or two give the lines of one offline block."""
    rng = np.random.default_rng(seed)
    rows = random_rows(rng, 150)
    cuts = np.unique(np.concatenate([[0, 150], rng.integers(0, 150, size=40)]))
    est: list[str] = []
    det: list[str] = []
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        part = {k: v[lo:hi] for k, v in rows.items()}
        est += analysis.estimate_lines(part)
        det += analysis.detail_lines(part)
    assert est == analysis.estimate_lines(rows)
    assert det == analysis.detail_lines(rows)


# --------------------------------------------------------------------------- recording


def messages(n: int) -> list[tuple[str, bytes]]:
    keys = ["rehab/d1/imu/upperarm", "rehab/d1/robot", "rehab/d1/event", 'rehab/"odd"\\/x']
    out = []
    for i in range(n):
        payload = b'{"t":[%d.25],"gyr":[[0.1,-2e-05,%d]],"note":"\\u00e9 \\"q\\""}' % (i, i)
        out.append((keys[i % len(keys)], payload if i % 5 else b'"a string payload"'))
    return out


def read_back(path: Path) -> list[tuple[str | None, bytes]]:
    return [(k, bytes(p)) for k, p in recording.read(path)]


def test_writer_keeps_every_line_in_order(tmp_path: Path) -> None:
    msgs = messages(2000)
    path = tmp_path / "r.jsonl.gz"
    w = recording.Writer(path, "x", compresslevel=1)
    for i, (k, p) in enumerate(msgs):
        w.append_raw(k, p)
        if i % 37 == 36:
            w.flush()
    w.close()
    assert read_back(path) == msgs
    assert w.lines == len(msgs)
    # a standard gzip file: its trailer's CRC and length check out
    assert gzip.decompress(path.read_bytes()) == b"".join(
        b'{"key":' + json.dumps(k).encode() + b',"payload":' + p + b"}\n" for k, p in msgs
    )


def test_writer_appends_and_plain_files(tmp_path: Path) -> None:
    msgs = messages(300)
    for name in ("r.jsonl.gz", "r.jsonl"):
        path = tmp_path / name
        for part in (msgs[:100], msgs[100:]):  # mode "a": a second gzip member
            w = recording.Writer(path, "a")
            for k, p in part:
                w.append_raw(k, p)
            w.close()
        assert read_back(path) == msgs


def test_writer_buffer_bound(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(recording.Writer, "BUFFER_BYTES", 300)
    msgs = messages(500)
    path = tmp_path / "r.jsonl.gz"
    w = recording.Writer(path, "x")
    for k, p in msgs:
        w.append_raw(k, p)
        assert w._pending_bytes < 300 + 200
    w.close()
    assert read_back(path) == msgs


def test_writer_cut_by_a_crash_keeps_what_was_flushed(tmp_path: Path) -> None:
    msgs = messages(900)
    path = tmp_path / "r.jsonl.gz"
    w = recording.Writer(path, "x", compresslevel=1)
    for k, p in msgs[:600]:
        w.append_raw(k, p)
    w.flush()
    for k, p in msgs[600:]:  # appended, not flushed: lost in the crash
        w.append_raw(k, p)
    killed = tmp_path / "killed.jsonl.gz"
    shutil.copy(path, killed)  # the file as kill -9 leaves it: no trailer
    w.close()
    assert read_back(killed) == msgs[:600]
    assert read_back(path) == msgs
    for cut in (len(killed.read_bytes()) // 2, 11):  # and cut anywhere: a prefix of the lines
        part = tmp_path / f"cut{cut}.jsonl.gz"
        part.write_bytes(killed.read_bytes()[:cut])
        got = read_back(part)
        assert got == msgs[: len(got)]


def test_writer_flush_after_the_buffer_overflowed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Lines the buffer bound pushed to the compressor are synced by the next flush."""
    line = b'{"key":"rehab/d/robot","payload":{"t":[1]}}\n'
    monkeypatch.setattr(recording.Writer, "BUFFER_BYTES", 3 * len(line))
    path = tmp_path / "r.jsonl.gz"
    w = recording.Writer(path, "x")
    for _ in range(3):  # the third append reaches the bound: nothing is pending after it
        w.append_raw("rehab/d/robot", b'{"t":[1]}')
    assert not w._pending
    w.flush()
    killed = tmp_path / "killed.jsonl.gz"
    shutil.copy(path, killed)
    w.close()
    w.flush()  # closed: nothing to do, no error
    assert read_back(killed) == [("rehab/d/robot", b'{"t":[1]}')] * 3
