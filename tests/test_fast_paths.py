"""The offline analysis's fast paths give exactly what the simple paths give.

`wire.decode_many` and `analysis.decode_stream` against `wire.decode` message by
message, the column-wise CSV formatter against `%` per row, and the chunked recording
reader against a line reader.
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from backend import analysis, csv_text
from protocol import keys, recording, wire

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
            flags = (a.flags.writeable, a.flags.c_contiguous)
            fields[name] = (a.dtype.str, a.shape, a.tobytes(), flags)
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


# Batches as recordings have them: keys that repeat, payloads mostly valid (so that the
# bulk paths are taken), some with one fault or another.
STREAM_KEYS = ["rehab/d/imu/upperarm", "rehab/d/imu/trunk", "rehab/d/robot", "rehab/d/camera"]
OTHER_KEYS = ["rehab/d/event", "rehab/d/estimate", "rehab/bad key/robot", "other/d/robot"]
FIELDS = {"imu": ("gyr", "acc", None), "robot": ("wrist", "proximal", "elbow")}
FIELDS["camera"] = ("elbow", "wrist", "shoulder")
number = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False, width=64),
    st.integers(-3, 3),
    st.sampled_from([0.0, -0.0, 1e-05, 5e-324, 1.7976931348623157e308, 0.1, 2**53 + 1, 10**20]),
)
FAULTS = [
    "t_reversed", "t_repeated", "t_empty", "t_string", "row_short", "row_string", "rows_extra",
    "field_missing", "field_null", "optional_null", "seq_negative", "seq_huge", "seq_float",
    "extra_field", "spaces", "duplicate_bad_first", "duplicate_good_first", "nan", "cut",
    "not_object", "foreign_field", "foreign_bad", "foreign_null",
]  # fmt: skip
# another stream kind's field: ignored by this kind's decoder, whatever it holds
FOREIGN = {"imu": "wrist", "robot": "gyr", "camera": "acc"}


@st.composite
def stream_payload(draw: st.DrawFn, key: str, n: int) -> bytes:
    """A stream payload of ``key`` with ``n`` samples, one fault now and then."""
    a, b, c = FIELDS[key.split("/")[2]]
    t0 = draw(st.floats(0, 1000))
    p: dict[str, Any] = {"t": [t0 + 0.01 * i for i in range(n)]}
    row = st.lists(number, min_size=3, max_size=3)
    for name in (a, b):
        p[name] = draw(st.lists(row, min_size=n, max_size=n))
    if c is not None and draw(st.booleans()):
        p[c] = draw(st.lists(row, min_size=n, max_size=n))
    if draw(st.integers(0, 3)):
        p["seq"] = draw(st.integers(0, 2**63 - 1))
    fault = draw(st.sampled_from(FAULTS)) if draw(st.integers(0, 4)) == 0 else None
    if fault == "t_reversed":
        p["t"] = p["t"][::-1]
    elif fault == "t_repeated":
        p["t"] = [t0] * n
    elif fault == "t_empty":
        p["t"] = []
    elif fault == "t_string":
        p["t"] = ["x"] * n
    elif fault == "row_short":
        p[a] = [[1.0, 2.0]] * n
    elif fault == "row_string":
        p[b] = [[1.0, "y", 2.0]] * n
    elif fault == "rows_extra":
        p[a] = p[a] + [[0.0, 0.0, 0.0]]
    elif fault == "field_missing":
        del p[b]
    elif fault == "field_null":
        p[a] = None
    elif fault == "optional_null" and c is not None:
        p[c] = None
    elif fault == "seq_negative":
        p["seq"] = -1
    elif fault == "seq_huge":
        p["seq"] = 2**63
    elif fault == "seq_float":
        p["seq"] = 1.5
    elif fault == "extra_field":
        p["mag"] = [[1, 2, 3]] * n
    elif fault == "foreign_field":
        p[FOREIGN[key.split("/")[2]]] = [[1.0, 2.0, 3.0]] * (n + 1)
    elif fault == "foreign_bad":
        p[FOREIGN[key.split("/")[2]]] = [[1.0, "x"]]
    elif fault == "foreign_null":
        p[FOREIGN[key.split("/")[2]]] = None
    raw = json.dumps(p, separators=(",", ":")).encode()
    if fault == "spaces":
        raw = json.dumps(p).encode()
    elif fault == "duplicate_bad_first":
        raw = b'{"%s":"x",' % a.encode() + raw[1:]
    elif fault == "duplicate_good_first":
        raw = raw[:-1] + b',"t":[5.0]}'
    elif fault == "nan":
        raw = raw.replace(b"0.0", b"NaN", 1)
    elif fault == "cut":
        raw = raw[: draw(st.integers(0, len(raw) - 1))]
    elif fault == "not_object":
        raw = b"[" + raw + b"]"
    return raw


@st.composite
def batches(draw: st.DrawFn) -> list[tuple[str, Any]]:
    keys_ = draw(st.lists(st.sampled_from(STREAM_KEYS), min_size=1, max_size=3, unique=True))
    usual_n = {k: draw(st.sampled_from([1, 2, 4])) for k in keys_}
    out = []
    for _ in range(draw(st.integers(1, 24))):
        if draw(st.integers(0, 9)) == 0:
            out.append((draw(st.sampled_from(OTHER_KEYS)), b'{"t":1.0,"type":"cycle_start"}'))
            continue
        key = draw(st.sampled_from(keys_))
        n = usual_n[key] if draw(st.integers(0, 5)) else draw(st.integers(1, 5))
        out.append((key, draw(stream_payload(key, n))))
    return out


@settings(max_examples=150, deadline=None)
@given(batches(), st.sampled_from(["bytes", "raw", "str", "mixed"]), st.booleans())
def test_decode_many_is_decode_on_batches(
    items: list[tuple[str, Any]], form: str, small_limit: bool
) -> None:
    if form == "raw":
        items = [(k, msgspec.Raw(p)) for k, p in items]
    elif form == "str":
        items = [(k, p.decode()) for k, p in items]
    elif form == "mixed":
        items = [(k, p if i % 3 else p.decode()) for i, (k, p) in enumerate(items)]
    limit = wire.MAX_PAYLOAD_BYTES
    if small_limit:  # some payloads over the size limit: too_large, as decode says
        wire.MAX_PAYLOAD_BYTES = 100
    try:
        assert [_outcome(x) for x in wire.decode_many(items)] == [_decode_one(*kp) for kp in items]
    finally:
        wire.MAX_PAYLOAD_BYTES = limit


def _device(key: str) -> str | None:
    try:
        return keys.parse(key).device
    except keys.KeyError_:
        return None


def _parse(line: bytes) -> tuple[str | None, Any]:
    """What the recording reader gives for a non-blank line."""
    try:
        obj = recording._LINE.decode(line)
    except Exception:
        return None, (line + b"\n")[:200].decode("utf-8", "replace")
    return obj.key, obj.payload


def _reference(lines: list[tuple[str | None, Any]]) -> list[Any]:
    """``(device, outcome)`` of each recording line, message by message with decode."""
    out = []
    for key, payload in lines:
        if key is None:
            out.append((None, ("error", *wire.MALFORMED_LINE)))
        else:
            out.append((_device(key), _decode_one(key, payload)))
    return out


def _outcomes(decoded: Any) -> list[Any]:
    return [(dev, _outcome(x)) for dev, x in decoded]


JUNK_LINES = [
    b"", b"   ", b"\t", b"not json", b"[1]", b'{"key": 1}', b'{"key":"rehab/d/robot"}',
    b'{"key":"rehab/d/robot","payload":{"t":[1]}} {"key":"rehab/d/robot","payload":{}}',
    b'{"key":"rehab/d/robot","payload":[1,', b'{"payload":{},"key":"rehab/d/robot"}',
]  # fmt: skip


@st.composite
def recording_lines(draw: st.DrawFn) -> list[bytes]:
    """Lines as the recorder writes them, and some that it does not."""
    lines = []
    for key, payload in draw(batches()):
        form = draw(st.integers(0, 12))
        if form == 0:
            lines.append(draw(st.sampled_from(JUNK_LINES)))
        head = b'{"key":' + json.dumps(key).encode() + b',"payload":'
        if form == 1:  # the key twice, the last one another's
            head = b'{"key":"rehab/d/imu/upperarm","key":' + json.dumps(key).encode()
            head += b',"payload":'
        elif form == 2:  # spelled another way
            head = b'{ "key" : ' + json.dumps(key).encode() + b', "payload" : '
        elif form == 3:  # the payload twice
            head = head + b'{"t":"x"},"payload":'
        elif form == 5:  # the payload twice, the first one valid
            head = head + b'{"t":[0.5],"wrist":[[0,0,1]],"proximal":[[0,0,0]]},"payload":'
        elif form == 6:  # escaped
            head = b'{"key":' + json.dumps(key).replace("/", "\\/").encode() + b',"payload":'
        elif form == 7:  # the key last
            lines.append(b'{"payload":' + payload + b',"key":' + json.dumps(key).encode() + b"}")
            continue
        lines.append(head + payload + (b"}\r" if form == 4 else b"}"))
    return lines


@settings(max_examples=200, deadline=None)
@given(recording_lines(), st.sampled_from([1, 5, analysis._DECODE_BATCH]), st.booleans())
def test_decode_stream_is_line_by_line(raw_lines: list[bytes], batch: int, small: bool) -> None:
    """Lines decoded with their payloads in one go, or line by line: key and payload, then
    the payload with decode."""
    lines = [line for line in raw_lines if line and not line.isspace()]
    old, analysis._DECODE_BATCH = analysis._DECODE_BATCH, batch
    limit = wire.MAX_PAYLOAD_BYTES
    if small:  # lines over the size limit, some with payloads under it
        wire.MAX_PAYLOAD_BYTES = 100
    try:
        expected = _reference([_parse(line) for line in lines])
        assert _outcomes(analysis.decode_stream(lines)) == expected
    finally:
        analysis._DECODE_BATCH = old
        wire.MAX_PAYLOAD_BYTES = limit


def test_stream_lines_are_decoded_in_one_pass(monkeypatch: pytest.MonkeyPatch) -> None:
    """A valid stream line is decoded with its payload at once, not parsed first (the
    general path: events, faults); the results are the same either way (tests above)."""
    parsed: list[bytes] = []
    parse = recording.parse
    monkeypatch.setattr(recording, "parse", lambda line: parsed.append(line) or parse(line))
    rows = [[0.1, 0.2, 0.3], [0.0, 0.0, 1.0]]
    payloads = [
        ("rehab/d/imu/upperarm", {"t": [0.0, 0.01], "gyr": rows, "acc": rows, "seq": 0}),
        ("rehab/d/robot", {"t": [0.0], "wrist": rows[:1], "proximal": rows[1:]}),
        ("rehab/d/robot", {"t": [1.0], "wrist": rows[:1], "proximal": rows[1:], "elbow": None}),
        ("rehab/d/camera", {"t": [0.0], "elbow": rows[:1], "wrist": rows[1:], "mag": 1}),
    ]
    event = ("rehab/d/event", {"t": 1.0, "type": "cycle_start"})
    lines = [json.dumps({"key": k, "payload": p}).encode() for k, p in [*payloads, event]]
    out, _ = wire.decode_lines(lines)
    assert [type(x).__name__ for _, x in out] == ["Span"] * 4 + ["EventMessage"]
    assert parsed == lines[-1:]


def test_decode_stream_of_a_recording_is_line_by_line(tmp_path: Path) -> None:
    """A recording mixing good and bad lines, decoded in batches or message by message."""
    rng = np.random.default_rng(3)
    messages: list[tuple[str, Any]] = []
    for i in range(3000):
        t = [i * 0.04 + 0.01 * j for j in range(4)]
        imu = {
            "t": t,
            "gyr": rng.normal(size=(4, 3)).tolist(),
            "acc": rng.normal(size=(4, 3)).tolist(),
        }
        messages.append(("rehab/sim/imu/upperarm", {**imu, "seq": i}))
        robot = {"t": [t[0]], "wrist": [[0.1, 0.2, 0.3]], "proximal": [[0.0, -0.0, 1e-05]]}
        messages.append(("rehab/sim/robot", robot if i % 7 else {**robot, "elbow": [[1, 2, 3]]}))
        if i % 500 == 250:  # faults now and then
            messages.append(("rehab/sim/robot", {"t": [1.0, 0.5], "wrist": [], "proximal": []}))
            messages.append(("rehab/sim/imu/upperarm", {**imu, "seq": -1}))
            messages.append(("rehab/sim/event", {"t": 1.0, "type": "cycle_start"}))
            messages.append(("rehab/other/estimate", {}))
    path = tmp_path / "r.jsonl.gz"
    recording.write(path, messages)
    data = gzip.decompress(path.read_bytes()).split(b"\n")
    data[1000:1000] = [b"not json", b"", b'{"key": 1}']
    data.insert(5000, data[5000].replace(b'"payload":', b'"payload": '))
    path.write_bytes(gzip.compress(b"\n".join(data), mtime=0))
    lines = gzip.decompress(path.read_bytes()).split(b"\n")
    expected = _reference([_parse(line) for line in lines if line and not line.isspace()])
    assert _outcomes(analysis.decode_stream(recording.lines(path))) == expected


SPECIAL = [0.0, -0.0, 0.5, -0.5, 2.5, 1 / 64, -3 / 128, 0.0005, 2.0005, 0.301475, -0.234775]
SPECIAL += [9.9999995, 999.9995, 1e15, 1e17, 1e300, 5e-324, math.inf, -math.inf, math.nan]


FORMATS = [
    analysis._DET_FMT + ",%d,%s,%.0f,%.1f",  # text columns first and in the middle
    analysis._EST_FMT,  # first and last
    "%s,%.2f,%r",
    "%.3f,%d",  # none
    "%r",
    "%s,%r",
]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(FORMATS))
def test_column_formatter_is_percent_per_row(seed: int, fmt: str) -> None:
    rng = np.random.default_rng(seed)
    n = 3 * csv_text.VECTOR_ROWS
    pool = np.concatenate(
        [
            rng.normal(size=n) * 10.0 ** rng.integers(-7, 9, size=n),
            rng.integers(-(10**9), 10**9, size=n) / 1e6,  # recorded 6-decimal values
            rng.integers(-(2**20), 2**20, size=n) / 2.0**12,  # dyadic: exact ties
            SPECIAL,
        ]
    )
    cols: list[Any] = []
    for spec in fmt.split(","):
        if spec == "%d":
            cols.append(rng.choice(np.array([0, 1, -7, 2**62], np.int64), size=n))
        elif spec == "%s":
            cols.append([str(s) for s in rng.choice(list(analysis.STATE_NAMES.values()), n)])
        else:
            cols.append(rng.choice(pool, size=n))
    expected = csv_text.format_rows(
        fmt, [c.tolist() if isinstance(c, np.ndarray) else c for c in cols]
    )
    assert csv_text.table_lines(fmt, cols) == expected
    head = fmt.split(",")[0]
    if head in ("%r", "%s"):  # the first column's texts made beforehand (both files' t)
        assert csv_text.table_lines(fmt, cols, csv_text.texts(head, cols[0])) == expected


def _line_reader(path: Path) -> tuple[list[tuple[str | None, Any]], str | None]:
    """What the recording reader gave when it read line by line, and the error it ended
    with, if any."""
    out: list[tuple[str | None, Any]] = []
    try:
        with gzip.open(path, "rb") if path.suffix == ".gz" else open(path, "rb") as fh:
            for line in recording._lines(fh):
                if line.strip():
                    try:
                        obj = recording._LINE.decode(line)
                    except Exception:
                        out.append((None, line[:200].decode("utf-8", "replace")))
                        continue
                    out.append((obj.key, bytes(obj.payload)))
    except Exception as exc:
        return out, type(exc).__name__
    return out, None


def _read(path: Path) -> tuple[list[tuple[str | None, Any]], str | None]:
    out: list[tuple[str | None, Any]] = []
    try:
        for k, v in recording.read(path):
            out.append((k, v if k is None else bytes(v)))
    except Exception as exc:
        return out, type(exc).__name__
    return out, None


@pytest.mark.parametrize("chunk", [64, 1 << 24])
def test_chunked_reader_is_a_line_reader(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk: int
) -> None:
    monkeypatch.setattr(recording, "_CHUNK", chunk)
    lines = [json.dumps({"key": "rehab/d/robot", "payload": {"t": [i]}}) for i in range(300)]
    text = ("\n".join(lines[:100]) + "\n\n  \nnot json\n" + "\n".join(lines[100:])).encode()
    whole = gzip.compress(text + b"\n", mtime=0)
    cases = {"whole.jsonl.gz": whole}
    for cut in (len(whole) // 2, len(whole) - 3):  # killed recorder
        cases[f"cut{cut}.jsonl.gz"] = whole[:cut]
    half = len(text) // 2  # members (Writer's "a"): at a line's end, or inside one
    first, second = text[: text.index(b"\n", half) + 1], text[text.index(b"\n", half) + 1 :]
    cases["members.jsonl.gz"] = gzip.compress(first) + gzip.compress(second + b"\n")
    cases["split.jsonl.gz"] = gzip.compress(text[:half]) + gzip.compress(text[half:] + b"\n")
    cases["padded.jsonl.gz"] = whole + b"\0" * 10  # the gzip module reads past zeros
    cases["garbage.jsonl.gz"] = whole + b"garbage"
    crc = bytearray(whole)
    crc[-8] ^= 1
    cases["crc.jsonl.gz"] = bytes(crc)
    corrupt = bytearray(whole)
    corrupt[len(whole) // 3 : len(whole) // 3 + 8] = b"\xff" * 8
    cases["corrupt.jsonl.gz"] = bytes(corrupt)
    cases["empty.jsonl.gz"] = b""
    cases["plain.jsonl"] = text + b'\n{"key": "unterminated"'
    for name, data in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        assert _read(p) == _line_reader(p), name


def test_analyze_feeds_spans_as_it_would_feed_messages(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`rehab analyze` feeds stream messages as rows of their batch's columns
    (`Pipeline.feed_imu_rows`, `feed_robot_rows`); with each span fed as its message
    instead, every output is the same. On a session with faults of every kind."""
    from estimators.params import PipelineParams
    from tests.conftest import make_session

    s = make_session(11, duration_s=60.0)
    raw: list[tuple[str, Any]] = []
    for i, (key, p) in enumerate(s.raw):
        raw.append((key, p))
        if i % 101 == 0 and "robot" in key:  # coincident cuffs
            raw.append((key, {**p, "t": [x + 0.001 for x in p["t"]], "wrist": p["proximal"]}))
        if i % 103 == 0:
            raw.append((key, p))  # a duplicate: time not increasing
        if i % 211 == 0 and "robot" in key:
            raw[-1] = (key, {**p, "elbow": p["proximal"]})  # the robot's own elbow
        if i % 307 == 0:
            raw.append((key.replace("/imu/upperarm", "/imu/trunk"), p))
            raw.append(("rehab/other/robot", p))
            raw.append((key, {"t": [1.0, 0.5], "wrist": [], "proximal": []}))
    path = tmp_path / "r.jsonl.gz"
    recording.write(path, raw)
    data = gzip.decompress(path.read_bytes()).split(b"\n")
    data[700:700] = [b"not json", b'{"key": 1}']
    path.write_bytes(gzip.compress(b"\n".join(data), mtime=0))

    def outputs(out: Path) -> dict[str, str]:
        analysis.analyze(path, PipelineParams(), out)
        return {f.name: f.read_text() for f in sorted(out.iterdir())}

    fast = outputs(tmp_path / "fast")
    monkeypatch.setattr(analysis, "_feed_span", lambda p, sp, cols: p.feed(sp.message(cols)))
    simple = outputs(tmp_path / "simple")
    assert fast == simple
    q = json.loads(fast["report.json"])["data_quality"]
    assert q["rejected"]["coincident_cuffs"] > 0 and q["rejected"]["time_backwards"] > 0
    assert q["other_devices"] and q["ignored"]["imu_trunk"] > 0
