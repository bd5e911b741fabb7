"""The one wire schema: encode and decode the contract's payloads (contract §2, §7).

Ingest, simulator, recorder, analysis and tests all go through this module.
Decoding validates everything a device can get wrong and raises :class:`WireError`
with a short machine-readable ``reason`` (used as a counter name) and a human
``detail``. Inside the project decoded messages are trusted.

Stateless checks only: ordering *across* messages (time going backwards, sequence
loss) needs per-stream state and lives in :mod:`backend.quality`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import msgspec
import numpy as np
import orjson
from numpy.typing import NDArray

from backend import keys

FloatArray: TypeAlias = NDArray[np.float64]

MAX_PAYLOAD_BYTES = 1 << 20  # 1 MiB: a 1000 Hz IMU batch of 10 s is ~0.5 MiB
MAX_SAMPLES = 20_000
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


@dataclass(frozen=True, slots=True)
class EstimateMessage:
    """Service output, one entry per robot sample (contract §7): column name -> values."""

    device: str
    columns: dict[str, list[Any]] = field(default_factory=dict)


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


class _Imu(msgspec.Struct):
    t: list[float]
    gyr: list[Vec3]
    acc: list[Vec3]
    seq: int | None = None


class _Robot(msgspec.Struct):
    t: list[float]
    wrist: list[Vec3]
    proximal: list[Vec3]
    elbow: list[Vec3] | None = None
    seq: int | None = None


class _Camera(msgspec.Struct):
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
_CONVERT = {"imu": _Imu, "robot": _Robot, "camera": _Camera}


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


def _arr(rows: list[Any], name: str, n: int) -> FloatArray:
    if len(rows) != n:
        raise WireError("length_mismatch", f"{name!r} has {len(rows)} rows, t has {n}")
    return np.array(rows, dtype=np.float64).reshape(n, 3)


def _check(t: list[float], seq: int | None, from_json: bool, *arrays: FloatArray) -> FloatArray:
    n = len(t)
    if n == 0:
        raise WireError("empty", "no samples")
    if n > MAX_SAMPLES:
        raise WireError("too_large", f"{n} samples > {MAX_SAMPLES}")
    ta = np.array(t, dtype=np.float64)
    # JSON text cannot carry NaN/inf past the typed decoder; Python objects can
    if not from_json and not (np.isfinite(ta).all() and all(np.isfinite(a).all() for a in arrays)):
        raise WireError("non_finite", "NaN or inf in payload")
    if n > 1 and not all(a < b for a, b in zip(t, t[1:], strict=False)):
        raise WireError("non_increasing_t", "t is not strictly increasing within the message")
    if seq is not None and not (0 <= seq < 2**63):
        raise WireError("bad_type", "seq must be a non-negative integer")
    return ta


def decode(
    key: str, payload: bytes | str | dict[str, Any], prefix: str = keys.DEFAULT_PREFIX
) -> Message:
    """Decode one device→service message. Raises :class:`WireError` on anything invalid."""
    try:
        pk = keys.parse(key, prefix)
    except keys.KeyError_ as exc:
        raise WireError("unknown_key", str(exc)) from None
    if pk.kind == "imu":
        p = _structured("imu", payload)
        n = len(p.t)
        gyr, acc = _arr(p.gyr, "gyr", n), _arr(p.acc, "acc", n)
        t = _check(p.t, p.seq, not isinstance(payload, dict), gyr, acc)
        return ImuMessage(pk.device, pk.segment or "upperarm", t, gyr, acc, p.seq)
    if pk.kind == "robot":
        r = _structured("robot", payload)
        n = len(r.t)
        wrist, prox = _arr(r.wrist, "wrist", n), _arr(r.proximal, "proximal", n)
        elbow = _arr(r.elbow, "elbow", n) if r.elbow is not None else None
        extra = () if elbow is None else (elbow,)
        t = _check(r.t, r.seq, not isinstance(payload, dict), wrist, prox, *extra)
        return RobotMessage(pk.device, t, wrist, prox, elbow, r.seq)
    if pk.kind == "camera":
        c = _structured("camera", payload)
        n = len(c.t)
        el, wr = _arr(c.elbow, "elbow", n), _arr(c.wrist, "wrist", n)
        sh = _arr(c.shoulder, "shoulder", n) if c.shoulder is not None else None
        t = _check(
            c.t, c.seq, not isinstance(payload, dict), el, wr, *(() if sh is None else (sh,))
        )
        return CameraMessage(pk.device, t, el, wr, sh, c.seq)
    if pk.kind == "event":
        return _event(pk.device, _load(payload))
    raise WireError("unknown_key", f"{key!r} is a service output, not an input")


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


def feedback_state(t: float, state: str) -> dict[str, Any]:
    return {"t": t, "type": "state", "state": state}


def feedback_cycle(
    start: float, end: float, outside_fraction: float, compensatory: bool
) -> dict[str, Any]:
    return {
        "type": "cycle",
        "start": start,
        "end": end,
        "outside_fraction": outside_fraction,
        "compensatory": compensatory,
    }
