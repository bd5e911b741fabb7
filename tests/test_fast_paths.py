"""The offline analysis's fast paths give exactly what the simple paths give.

`wire.decode_many` against `wire.decode`, the column-wise CSV formatter against `%` per
row, and the chunked recording reader against a line reader.
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from backend import analysis, recording, wire

KEYS = [
    "rehab/d/imu/upperarm",
    "rehab/d/imu/trunk",
    "rehab/d/robot",
    "rehab/d/camera",
    "rehab/d/event",
    "rehab/d/estimate",
    "rehab/bad key/robot",
]


def _outcome(x: Any) -> Any:
    if isinstance(x, wire.WireError):
        return ("error", x.reason, x.detail)
    fields = {}
    for name in ("device", "segment", "seq", "type", "t"):
        v = getattr(x, name, None)
        fields[name] = v if not isinstance(v, np.ndarray) else None
    for name in ("t", "gyr", "acc", "wrist", "proximal", "elbow", "shoulder", "point"):
        a = getattr(x, name, None)
        if isinstance(a, np.ndarray):
            fields[name] = (a.dtype.str, a.shape, a.tobytes())
    return (type(x).__name__, fields)


def _decode_one(key: str, payload: Any) -> Any:
    try:
        return _outcome(wire.decode(key, payload))
    except wire.WireError as exc:
        return _outcome(exc)


numbers = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=64),
    st.integers(-3, 3),
    st.sampled_from([0.0, -0.0, 1e308, 2**63, -1, True, None, "x"]),
)
vec = st.lists(numbers, min_size=2, max_size=4)


@st.composite
def payloads(draw: st.DrawFn) -> tuple[str, Any]:
    key = draw(st.sampled_from(KEYS))
    n = draw(st.integers(0, 4))
    t = sorted(draw(st.lists(st.floats(0, 100), min_size=n, max_size=n)))
    p: dict[str, Any] = {"t": draw(st.sampled_from([t, t[::-1], [*t, "x"]]))}
    for name in draw(st.sets(st.sampled_from(["gyr", "acc", "wrist", "proximal", "elbow"]))):
        m = draw(st.sampled_from([n, n, max(n - 1, 0)]))
        p[name] = draw(st.lists(st.one_of(vec, st.just([1.0, 2.0, 3.0])), min_size=m, max_size=m))
    if draw(st.booleans()):
        p["seq"] = draw(st.sampled_from([0, 7, -1, 2**63, None, 1.5]))
    raw = json.dumps(p).encode()
    form = draw(st.sampled_from(["bytes", "bytes", "str", "dict", "cut", "nan"]))
    if form == "str":
        return key, raw.decode()
    if form == "dict":
        return key, p
    if form == "cut":
        return key, raw[: draw(st.integers(0, len(raw)))]
    if form == "nan":
        return key, raw.replace(b"1.0", b"NaN", 1)
    return key, raw


@settings(max_examples=100, deadline=None)
@given(st.lists(payloads(), max_size=8))
def test_decode_many_is_decode(items: list[tuple[str, Any]]) -> None:
    assert [_outcome(x) for x in wire.decode_many(items)] == [_decode_one(*kp) for kp in items]


def test_decode_many_on_python_objects_with_nan() -> None:
    items = [("rehab/d/robot", {"t": [1.0], "wrist": [[math.nan, 0, 0]], "proximal": [[0, 0, 1]]})]
    assert [_outcome(x) for x in wire.decode_many(items)] == [_decode_one(*items[0])]


SPECIAL = [0.0, -0.0, 0.5, -0.5, 2.5, 1 / 64, -3 / 128, 0.0005, 2.0005, 0.301475, -0.234775]
SPECIAL += [9.9999995, 999.9995, 1e15, 1e17, 1e300, 5e-324, math.inf, -math.inf, math.nan]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_column_formatter_is_percent_per_row(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 3 * analysis._VECTOR_ROWS
    pool = np.concatenate(
        [
            rng.normal(size=n) * 10.0 ** rng.integers(-7, 9, size=n),
            rng.integers(-(10**9), 10**9, size=n) / 1e6,  # recorded 6-decimal values
            rng.integers(-(2**20), 2**20, size=n) / 2.0**12,  # dyadic: exact ties
            SPECIAL,
        ]
    )
    fmt = analysis._DET_FMT + ",%d,%s,%.0f,%.1f"
    cols: list[Any] = []
    for spec in fmt.split(","):
        if spec == "%d":
            cols.append(rng.choice(np.array([0, 1, -7, 2**62], np.int64), size=n))
        elif spec == "%s":
            cols.append([str(s) for s in rng.choice(list(analysis.STATE_NAMES.values()), n)])
        else:
            cols.append(rng.choice(pool, size=n))
    expected = analysis._format_rows(
        fmt, [c.tolist() if isinstance(c, np.ndarray) else c for c in cols]
    )
    assert analysis._table_lines(fmt, cols) == expected


def _line_reader(path: Path) -> list[tuple[str | None, Any]]:
    """What the recording reader gave when it read line by line."""
    out: list[tuple[str | None, Any]] = []
    with gzip.open(path, "rb") if path.suffix == ".gz" else open(path, "rb") as fh:
        for line in recording._lines(fh):
            if line.strip():
                try:
                    obj = recording._LINE.decode(line)
                except Exception:
                    out.append((None, line[:200].decode("utf-8", "replace")))
                    continue
                out.append((obj.key, bytes(obj.payload)))
    return out


@pytest.mark.parametrize("chunk", [64, 1 << 24])
def test_chunked_reader_is_a_line_reader(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk: int
) -> None:
    monkeypatch.setattr(recording, "_CHUNK", chunk)
    lines = [json.dumps({"key": "rehab/d/robot", "payload": {"t": [i]}}) for i in range(300)]
    text = ("\n".join(lines[:100]) + "\n\n  \nnot json\n" + "\n".join(lines[100:])).encode()
    whole = tmp_path / "whole.jsonl.gz"
    whole.write_bytes(gzip.compress(text + b"\n", mtime=0))
    cases = [whole]
    for cut in (len(whole.read_bytes()) // 2, len(whole.read_bytes()) - 3):  # killed recorder
        p = tmp_path / f"cut{cut}.jsonl.gz"
        p.write_bytes(whole.read_bytes()[:cut])
        cases.append(p)
    plain = tmp_path / "plain.jsonl"
    plain.write_bytes(text + b'\n{"key": "unterminated"')
    cases.append(plain)
    for p in cases:
        got = [(k, v if k is None else bytes(v)) for k, v in recording.read(p)]
        assert got == _line_reader(p), p.name
