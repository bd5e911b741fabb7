"""The one wire schema: encode and decode the contract's payloads (contract §2, §7).

Ingest, simulator, recorder, analysis and tests all go through this module.
Decoding validates everything a device can get wrong and raises :class:`WireError`
with a short machine-readable ``reason`` (used as a counter name) and a human
``detail``. Inside the project decoded messages are trusted.

Stateless checks only: ordering *across* messages (time going backwards, sequence
loss) needs per-stream state and is checked by the pipeline (:mod:`estimators.pipeline`).
"""

from __future__ import annotations

import functools
import json
import math
import operator
import struct
from collections.abc import Iterable
from dataclasses import dataclass, fields
from typing import Any, TypeAlias, get_args

import msgspec
import numpy as np
import orjson
from numpy.typing import NDArray

from protocol import keys, recording

FloatArray: TypeAlias = NDArray[np.float64]

MAX_PAYLOAD_BYTES = 1 << 20  # 1 MiB: a 1000 Hz IMU batch of 10 s is ~0.5 MiB
# Samples per stream message: devices send 1..10; 2000 is 20 s of a 100 Hz IMU in one
# message. A message is processed in one go, so this bounds how long one message can hold
# the service (~10 µs a sample: 20 ms); 20 000 held it for a quarter of a second.
MAX_SAMPLES = 2_000
EVENT_TYPES = ("shoulder_reference", "cycle_start", "nominal_reset")
STATES = ("ok", "outside", "warning")


class WireError(ValueError):
    """A rejected payload. ``reason`` is a stable counter name."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True, slots=True)
class ImuMessage:
    """IMU samples: ``t`` (N,) s, ``gyr`` (N,3) rad/s, ``acc`` (N,3) m/s² specific force."""

    device: str
    segment: str
    t: FloatArray
    gyr: FloatArray
    acc: FloatArray
    seq: int | None = None


@dataclass(frozen=True, slots=True)
class RobotMessage:
    """Cuff positions in the robot frame, m: ``wrist``, ``proximal`` (N,3); ``elbow`` optional."""

    device: str
    t: FloatArray
    wrist: FloatArray
    proximal: FloatArray
    elbow: FloatArray | None = None
    seq: int | None = None


@dataclass(frozen=True, slots=True)
class CameraMessage:
    """Optical positions, metres (N,3); ``shoulder`` optional."""

    device: str
    t: FloatArray
    elbow: FloatArray
    wrist: FloatArray
    shoulder: FloatArray | None = None
    seq: int | None = None


@dataclass(frozen=True, slots=True)
class EventMessage:
    """A discrete event. ``point`` (3,) metres for ``shoulder_reference``."""

    device: str
    t: float
    type: str
    point: FloatArray | None = None


Message: TypeAlias = ImuMessage | RobotMessage | CameraMessage | EventMessage


# --------------------------------------------------------------------------- decoding


def _load(payload: bytes | str | dict[str, Any]) -> dict[str, Any]:
    if isinstance(payload, dict):
        return payload
    if isinstance(payload, msgspec.Raw):
        payload = bytes(payload)
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise WireError("too_large", f"{len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        obj = orjson.loads(payload)  # strict JSON: no NaN/Infinity literals, UTF-8 only
    except orjson.JSONDecodeError as exc:
        raw = payload.encode("utf-8", "replace") if isinstance(payload, str) else bytes(payload)
        if b"NaN" in raw or b"Infinity" in raw or "infinity" in str(exc):
            raise WireError("non_finite", "NaN or Infinity literal in payload") from None
        raise WireError("malformed_json", str(exc)[:200]) from None
    if not isinstance(obj, dict):
        raise WireError("not_object", f"payload is a JSON {type(obj).__name__}, not an object")
    return obj


Vec3 = tuple[float, float, float]


# gc=False: a decoded payload holds only numbers, never a cycle; untracked, the ~10^4 a
# recording decodes do not set off the cyclic collector
class _Imu(msgspec.Struct, gc=False):
    t: list[float]
    gyr: list[Vec3]
    acc: list[Vec3]
    seq: int | None = None


class _Robot(msgspec.Struct, gc=False):
    t: list[float]
    wrist: list[Vec3]
    proximal: list[Vec3]
    elbow: list[Vec3] | None = None
    seq: int | None = None


class _Camera(msgspec.Struct, gc=False):
    t: list[float]
    elbow: list[Vec3]
    wrist: list[Vec3]
    shoulder: list[Vec3] | None = None
    seq: int | None = None


# Typed decoders validate structure and types in C; unknown fields (e.g. ``mag``) are ignored.
_DECODERS: dict[str, msgspec.json.Decoder[Any]] = {
    "imu": msgspec.json.Decoder(_Imu),
    "robot": msgspec.json.Decoder(_Robot),
    "camera": msgspec.json.Decoder(_Camera),
}
_CONVERT: dict[str, type[msgspec.Struct]] = {"imu": _Imu, "robot": _Robot, "camera": _Camera}


def _structured(kind: str, payload: bytes | str | dict[str, Any]) -> Any:
    try:
        if isinstance(payload, dict):
            return msgspec.convert(payload, _CONVERT[kind])
        if len(payload) > MAX_PAYLOAD_BYTES:
            raise WireError("too_large", f"{len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
        return _DECODERS[kind].decode(payload)
    except msgspec.ValidationError as exc:
        raise WireError(_reason(str(exc)), str(exc)[:200]) from None
    except msgspec.DecodeError as exc:
        text = str(exc)
        raw = payload.encode("utf-8", "replace") if isinstance(payload, str) else bytes(payload)  # type: ignore[arg-type]
        if b"NaN" in raw or b"Infinity" in raw or "inf" in text.lower():
            raise WireError("non_finite", "NaN or Infinity in payload") from None
        raise WireError("malformed_json", text[:200]) from None


def _reason(msg: str) -> str:
    if "out of range" in msg:
        return "non_finite"
    if "missing required field" in msg:
        return "missing_field"
    if msg.startswith("Expected `object`"):
        return "not_object"
    if "length" in msg:
        return "bad_shape"
    if "Expected `array`" in msg and "$." in msg and "[" in msg.split("$.", 1)[1]:
        return "bad_shape"
    return "bad_type"


_STREAMS = ("imu", "robot", "camera")
_VEC_NAMES = {
    "imu": ("gyr", "acc", ""),
    "robot": ("wrist", "proximal", "elbow"),
    "camera": ("elbow", "wrist", "shoulder"),
}


def _validate(
    kind: str, p: Any, from_json: bool
) -> tuple[list[float], list[Vec3], list[Vec3], list[Vec3] | None]:
    """Every per-message check on the decoded lists, before any array exists; returns
    ``t`` and the two required and one optional (N,3) fields.

    Plain Python: for the usual 1..10 samples a message carries, numpy's per-call cost
    would exceed the checks themselves. The order of the checks fixes which reason a
    payload with several faults gets."""
    t: list[float] = p.t
    n = len(t)
    if kind == "imu":
        a, b, c = p.gyr, p.acc, None
    elif kind == "robot":
        a, b, c = p.wrist, p.proximal, p.elbow
    else:
        a, b, c = p.elbow, p.wrist, p.shoulder
    if len(a) != n or len(b) != n or (c is not None and len(c) != n):
        for rows, name in zip((a, b, c), _VEC_NAMES[kind], strict=True):
            if rows is not None and len(rows) != n:
                raise WireError("length_mismatch", f"{name!r} has {len(rows)} rows, t has {n}")
    if n == 0:
        raise WireError("empty", "no samples")
    if n > MAX_SAMPLES:
        raise WireError("too_many_samples", f"{n} samples > {MAX_SAMPLES}")
    # JSON text cannot carry NaN/inf past the typed decoder; Python objects can
    if not from_json and not (
        all(map(math.isfinite, t))
        and all(math.isfinite(x) for rows in (a, b, c) if rows is not None for r in rows for x in r)
    ):
        raise WireError("non_finite", "NaN or inf in payload")
    if n > 1 and not all(map(operator.lt, t, t[1:])):
        raise WireError("non_increasing_t", "t is not strictly increasing within the message")
    seq = p.seq
    if seq is not None and not (0 <= seq < 2**63):
        raise WireError("bad_type", "seq must be a non-negative integer")
    return t, a, b, c


# A frozen dataclass's __init__ sets each field through object.__setattr__: about half of
# what a decoded message costs. decode_many sets the slots directly, all of them.
_FIELDS: dict[type, tuple[str, ...]] = {
    ImuMessage: ("device", "segment", "t", "gyr", "acc", "seq"),
    RobotMessage: ("device", "t", "wrist", "proximal", "elbow", "seq"),
    CameraMessage: ("device", "t", "elbow", "wrist", "shoulder", "seq"),
}
for _cls, _names in _FIELDS.items():
    if tuple(f.name for f in fields(_cls)) != _names:
        raise TypeError(f"{_cls.__name__}'s fields changed: update wire._message")
_SLOTS = {cls: tuple(cls.__dict__[f].__set__ for f in names) for cls, names in _FIELDS.items()}


def _message(
    pk: keys.ParsedKey,
    seq: int | None,
    t: FloatArray,
    a: FloatArray,
    b: FloatArray,
    c: FloatArray | None,
) -> Message:
    """The message of a validated stream payload (what its dataclass would build)."""
    m: Message
    if pk.kind == "imu":
        m = ImuMessage.__new__(ImuMessage)
        s = _SLOTS[ImuMessage]
        s[0](m, pk.device)
        s[1](m, pk.segment or "upperarm")
        s[2](m, t)
        s[3](m, a)
        s[4](m, b)
    else:
        cls: type[RobotMessage | CameraMessage] = (
            RobotMessage if pk.kind == "robot" else CameraMessage
        )
        m = cls.__new__(cls)
        s = _SLOTS[cls]
        s[0](m, pk.device)
        s[1](m, t)
        s[2](m, a)
        s[3](m, b)
        s[4](m, c)
    s[5](m, seq)
    return m


def decode(
    key: str, payload: bytes | str | dict[str, Any], prefix: str = keys.DEFAULT_PREFIX
) -> Message:
    """Decode one device→service message. Raises :class:`WireError` on anything invalid."""
    try:
        pk = keys.parse(key, prefix)
    except keys.KeyError_ as exc:
        raise WireError("unknown_key", str(exc)) from None
    kind = pk.kind
    if kind in _STREAMS:
        p = _structured(kind, payload)
        t, a, b, c = _validate(kind, p, not isinstance(payload, dict))
        n = len(t)
        # one array for all (N,3) fields: each field is a view of n rows
        v = np.array(a + b + (c or []), dtype=np.float64)
        return _message(
            pk,
            p.seq,
            np.array(t, dtype=np.float64),
            v[:n],
            v[n : 2 * n],
            v[2 * n :] if c is not None else None,
        )
    if kind == "event":
        return _event(pk.device, _load(payload))
    raise WireError("unknown_key", f"{key!r} is a service output, not an input")


MALFORMED_LINE = ("malformed_line", "recording line is not {key, payload}")


@dataclass(slots=True)
class Columns:
    """One stream kind's payloads of a decoded batch, end to end: ``t`` (N,) s and the
    kind's (N,3) fields ``a``, ``b`` (IMU: gyr, acc; robot: wrist, proximal; camera: elbow,
    wrist) and optional ``c`` (robot: elbow; camera: shoulder; NaN rows where a message had
    none, None if none had it). ``tl`` is ``t`` as floats. Each message is a :class:`Span`."""

    t: FloatArray
    tl: list[float]
    a: FloatArray
    b: FloatArray
    c: FloatArray | None


class Span(msgspec.Struct, frozen=True, gc=False):
    """A validated stream message as rows ``i0:i1`` of its kind's :class:`Columns` (a
    struct: its C ``__init__`` costs a fraction of a NamedTuple's or a dataclass's)."""

    key: keys.ParsedKey
    seq: int | None
    i0: int
    i1: int
    has_c: bool

    def message(self, cols: dict[str, Columns]) -> Message:
        """The message :func:`decode` would give (its arrays are views of the columns)."""
        k = cols[self.key.kind]
        sl = slice(self.i0, self.i1)
        return _message(
            self.key,
            self.seq,
            k.t[sl],
            k.a[sl],
            k.b[sl],
            k.c[sl] if self.has_c and k.c is not None else None,
        )


Decoded: TypeAlias = tuple[str | None, Message | WireError | Span]
"""A decoded item and its device (None if its key has none)."""


def _without_none(tp: Any) -> Any:
    """``T`` of ``T | None``; any other type as it is."""
    args = get_args(tp)
    if type(None) not in args:
        return tp
    return functools.reduce(operator.or_, (a for a in args if a is not type(None)))


def _any_stream() -> Any:
    """Every stream payload's fields in one struct, each optional, each of its type there."""
    types: dict[str, Any] = {}
    for cls in _CONVERT.values():
        for f in msgspec.structs.fields(cls):
            if types.setdefault(f.name, _without_none(f.type)) != _without_none(f.type):
                raise TypeError(f"{f.name!r} has another type in another stream payload")
    return msgspec.defstruct(
        "_AnyStream", [(name, tp | None, None) for name, tp in types.items()], gc=False
    )


# A recording line (recording._Line's envelope) and its stream payload in one decode: apart,
# the payload's text was scanned twice. It accepts no more than the kind's own decoder: each
# field has the type it has there, a field of another kind (ignored there) must decode too,
# and a field the kind requires must be there (_REQUIRED). Any other line takes the general
# path: recording.parse, then what decode does.
_RECORDED: msgspec.json.Decoder[Any] = msgspec.json.Decoder(
    msgspec.defstruct(
        "_Recorded",
        [
            (f.name, _any_stream() if f.type is msgspec.Raw else f.type)
            for f in msgspec.structs.fields(recording._Line)
        ],
        gc=False,
    )
)
_REQUIRED = {
    kind: operator.attrgetter(*(f.name for f in msgspec.structs.fields(cls) if f.required))
    for kind, cls in _CONVERT.items()
}
_NAN3 = (math.nan, math.nan, math.nan)


def decode_lines(
    lines: Iterable[bytes], prefix: str = keys.DEFAULT_PREFIX
) -> tuple[list[Decoded], dict[str, Columns]]:
    """Recording lines (:func:`protocol.recording.lines`) as :func:`decode` of what
    :func:`protocol.recording.parse` gives for each, the error returned instead of raised (a
    line that is no ``{key, payload}``: ``malformed_line``), and every valid stream payload
    left as a :class:`Span` of its kind's columns. With each item its device."""
    return _decode_items(lines, prefix)


def decode_columns(
    items: Iterable[tuple[str, Any]], prefix: str = keys.DEFAULT_PREFIX
) -> tuple[list[Message | WireError | Span], dict[str, Columns]]:
    """:func:`decode` of each ``(key, payload)``, the error returned instead of raised, and
    every valid stream payload (JSON bytes) left as a :class:`Span` of its kind's columns."""
    out, cols = _decode_items(items, prefix)
    return [x for _, x in out], cols


def _decode_items(
    items: Iterable[bytes | tuple[str, Any]], prefix: str
) -> tuple[list[Decoded], dict[str, Columns]]:
    """:func:`decode_lines` of lines, :func:`decode_columns` of ``(key, payload)`` pairs.

    The columns come from a few calls per kind and batch: per-message array construction
    dominated an offline analysis.
    """
    out: list[Decoded] = []
    # per kind: every accepted message's t, concatenated, and its rows of a, b and c
    acc: dict[str, tuple[list[float], list[Vec3], list[Vec3], list[Vec3]]] = {}
    limit = MAX_PAYLOAD_BYTES  # the payload is shorter than its line
    for item in items:
        pk: keys.ParsedKey | None = None
        if type(item) is bytes and len(item) <= limit:
            try:
                rec = _RECORDED.decode(item)
            except (msgspec.DecodeError, msgspec.ValidationError):
                pass
            else:
                pk = _stream_key(rec.key, prefix)
                p = rec.payload
                # all(): not None (nor an empty list: rejected on the general path)
                if pk is not None and not all(_REQUIRED[pk.kind](p)):
                    pk = None
        try:
            if pk is None:  # the general path
                key, payload = recording.parse(item) if isinstance(item, bytes) else item
                if key is None:
                    out.append((None, WireError(*MALFORMED_LINE)))
                    continue
                try:
                    pk = keys.parse(key, prefix)
                except keys.KeyError_ as exc:
                    out.append((None, WireError("unknown_key", str(exc))))
                    continue
                if pk.kind not in _STREAMS or isinstance(payload, (dict, str)):
                    out.append((pk.device, decode(key, payload, prefix)))
                    continue
                p = _structured(pk.kind, payload)
            t, a, b, c = _validate(pk.kind, p, True)
        except WireError as exc:
            # returned, not raised: without its traceback, whose frames (this one and its
            # lists) would otherwise wait for the cyclic collector
            out.append((pk.device if pk is not None else None, exc.with_traceback(None)))
            continue
        ts, ra, rb, rc = acc.get(pk.kind) or acc.setdefault(pk.kind, ([], [], [], []))
        i0 = len(ts)
        ts += t
        ra += a
        rb += b
        if c is not None:
            rc += [_NAN3] * (i0 - len(rc))  # NaN rows for the messages without one so far
            rc += c
        elif rc:  # aligned from the first message with one on
            rc += [_NAN3] * len(t)
        out.append((pk.device, Span(pk, p.seq, i0, len(ts), c is not None)))
    cols: dict[str, Columns] = {}
    for name, (ts, ra, rb, rc) in acc.items():
        n = len(ts)
        if rc:
            rc += [_NAN3] * (n - len(rc))
        t_col = np.empty(n, dtype=np.float64)
        struct.pack_into(f"{n}d", t_col.data, 0, *ts)
        cols[name] = Columns(
            t_col, ts, _rows_array(ra), _rows_array(rb), _rows_array(rc) if rc else None
        )
    return out, cols


def _stream_key(key: str, prefix: str) -> keys.ParsedKey | None:
    """The key's ParsedKey if it is a stream's, else None (keys.parse remembers keys)."""
    try:
        pk = keys.parse(key, prefix)
    except keys.KeyError_:
        return None
    return pk if pk.kind in _STREAMS else None


def _rows_array(rows: list[Vec3]) -> FloatArray:
    """(N,3) rows as an array: flattened, then packed as doubles (half the cost of numpy's
    conversion from an iterator, a quarter of that from nested sequences)."""
    out = np.empty((len(rows), 3), dtype=np.float64)
    struct.pack_into(
        f"{3 * len(rows)}d", out.data, 0, *functools.reduce(operator.iconcat, rows, [])
    )
    return out


def decode_many(
    items: Iterable[tuple[str, Any]], prefix: str = keys.DEFAULT_PREFIX
) -> list[Message | WireError]:
    """:func:`decode` of each ``(key, payload)``, the error returned instead of raised: the
    spans of :func:`decode_columns` as messages (same messages, same rejections)."""
    out, cols = decode_columns(items, prefix)
    return [x.message(cols) if isinstance(x, Span) else x for x in out]


def _event(device: str, obj: dict[str, Any]) -> EventMessage:
    t = obj.get("t")
    if t is None:
        raise WireError("missing_field", "field 't' is missing")
    if isinstance(t, bool) or not isinstance(t, (int, float)):
        raise WireError("bad_type", "event 't' must be a number")
    if not math.isfinite(t):
        raise WireError("non_finite", "event 't' is not finite")
    etype = obj.get("type")
    if etype is None:
        raise WireError("missing_field", "field 'type' is missing")
    if etype not in EVENT_TYPES:
        raise WireError("unknown_event", f"event type {etype!r} is not one of {EVENT_TYPES}")
    point = None
    if etype == "shoulder_reference":
        if "point" not in obj:
            raise WireError("missing_field", "shoulder_reference needs 'point'")
        pt = obj["point"]
        if not (isinstance(pt, list) and len(pt) == 3):
            raise WireError("bad_shape", "point must be [x, y, z]")
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in pt):
            raise WireError("bad_type", "point must hold numbers")
        point = np.array(pt, dtype=np.float64)
        if not np.isfinite(point).all():
            raise WireError("non_finite", "point contains NaN or inf")
    return EventMessage(device, float(t), etype, point)


# --------------------------------------------------------------------------- encoding


def _rows(a: FloatArray) -> list[list[float]]:
    return a.tolist()  # type: ignore[no-any-return]


def encode(msg: Message) -> tuple[str, dict[str, Any]]:
    """Return ``(key, payload object)`` for a device→service message (default prefix)."""
    return encode_with_prefix(msg, keys.DEFAULT_PREFIX)


def encode_with_prefix(msg: Message, prefix: str) -> tuple[str, dict[str, Any]]:
    payload: dict[str, Any]
    if isinstance(msg, ImuMessage):
        payload = {"t": msg.t.tolist(), "gyr": _rows(msg.gyr), "acc": _rows(msg.acc)}
        key = keys.imu(msg.device, msg.segment, prefix)
    elif isinstance(msg, RobotMessage):
        payload = {"t": msg.t.tolist(), "wrist": _rows(msg.wrist), "proximal": _rows(msg.proximal)}
        if msg.elbow is not None:
            payload["elbow"] = _rows(msg.elbow)
        key = keys.robot(msg.device, prefix)
    elif isinstance(msg, CameraMessage):
        payload = {"t": msg.t.tolist(), "elbow": _rows(msg.elbow), "wrist": _rows(msg.wrist)}
        if msg.shoulder is not None:
            payload["shoulder"] = _rows(msg.shoulder)
        key = keys.camera(msg.device, prefix)
    else:
        payload = {"t": msg.t, "type": msg.type}
        if msg.point is not None:
            payload["point"] = msg.point.tolist()
        return keys.event(msg.device, prefix), payload
    if msg.seq is not None:
        payload["seq"] = msg.seq
    return key, payload


def dumps(payload: dict[str, Any]) -> bytes:
    """Compact UTF-8 JSON, refusing NaN (the contract's JSON has none)."""
    return json.dumps(payload, separators=(",", ":"), allow_nan=False).encode("utf-8")


# --------------------------------------------------------------------------- joint angles

# Contract §8: the columns of joints.csv, as parallel arrays on ``rehab/<device>/joints``
JOINT_COLUMNS = (
    "t",
    "shoulder_flexion_deg",
    "shoulder_abduction_deg",
    "shoulder_rotation_deg",
    "elbow_flexion_deg",
    "forearm_pronation_deg",
    "elbow_x",
    "elbow_y",
    "elbow_z",
    "wrist_x",
    "wrist_y",
    "wrist_z",
)


def joints_payload(rows: dict[str, Any], extra: Iterable[str] = ()) -> bytes:
    """The joints payload of some rows (column → (N,) floats): the §8 columns, then the
    ``extra`` ones (an extension, e.g. each angle's confidence), as parallel arrays; a value
    that is not available (NaN) is ``null``."""
    out: dict[str, list[float | None]] = {}
    for c in (*JOINT_COLUMNS, *extra):
        out[c] = [v if math.isfinite(v) else None for v in np.asarray(rows[c], float).tolist()]
    return orjson.dumps(out)


def decode_joints(payload: bytes | str) -> dict[str, FloatArray]:
    """A joints payload back to column → (N,) float64 (``null`` → NaN); :class:`WireError`
    if a §8 column is missing or the arrays are not parallel."""
    obj = _load(payload)
    out: dict[str, FloatArray] = {}
    n: int | None = None
    for c, v in obj.items():
        if not isinstance(v, list):
            raise WireError("bad_type", f"{c!r} must be an array")
        try:
            a = np.array([math.nan if x is None else x for x in v], dtype=np.float64)
        except (TypeError, ValueError):
            raise WireError("bad_type", f"{c!r} must hold numbers or null") from None
        if n is not None and len(a) != n:
            raise WireError("bad_shape", f"{c!r} has {len(a)} values, not {n}")
        n = len(a)
        out[c] = a
    missing = [c for c in JOINT_COLUMNS if c not in out]
    if missing:
        raise WireError("missing_field", f"joints payload lacks {', '.join(missing)}")
    return out
