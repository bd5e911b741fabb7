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

import numpy as np
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
    """Cuff positions in the robot frame, metres: ``wrist``/``proximal`` (N,3), ``elbow`` optional."""

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
    if isinstance(payload, (bytes, bytearray, memoryview)):
        if len(payload) > MAX_PAYLOAD_BYTES:
            raise WireError("too_large", f"{len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
        try:
            text = bytes(payload).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise WireError("malformed_json", f"not UTF-8: {exc}") from None
    else:
        text = payload
        if len(text) > MAX_PAYLOAD_BYTES:
            raise WireError("too_large", f"{len(text)} characters > {MAX_PAYLOAD_BYTES}")
    try:
        obj = json.loads(text, parse_constant=_reject_constant)
    except WireError:
        raise
    except (ValueError, RecursionError) as exc:
        raise WireError("malformed_json", str(exc)[:200]) from None
    if not isinstance(obj, dict):
        raise WireError("not_object", f"payload is a JSON {type(obj).__name__}, not an object")
    return obj


def _reject_constant(name: str) -> Any:
    # json accepts NaN/Infinity literals, which are not JSON; refuse them at parse time.
    raise WireError("non_finite", f"literal {name} in payload")


def _array(obj: dict[str, Any], name: str, n: int | None, cols: int | None) -> FloatArray:
    if name not in obj:
        raise WireError("missing_field", f"field {name!r} is missing")
    raw = obj[name]
    if not isinstance(raw, list):
        raise WireError("bad_type", f"{name!r} must be an array")
    try:
        arr = np.array(raw, dtype=np.float64)
    except (ValueError, TypeError):
        raise WireError("bad_shape", f"{name!r} is not a regular numeric array") from None
    if cols is None:
        if arr.ndim != 1:
            raise WireError("bad_shape", f"{name!r} must be 1-D, got shape {arr.shape}")
    elif arr.ndim != 2 or arr.shape[1] != cols:
        raise WireError("bad_shape", f"{name!r} must be N×{cols}, got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise WireError("length_mismatch", f"{name!r} has {arr.shape[0]} rows, t has {n}")
    if not np.isfinite(arr).all():
        raise WireError("non_finite", f"{name!r} contains NaN or inf")
    return arr


def _times(obj: dict[str, Any]) -> FloatArray:
    t = _array(obj, "t", None, None)
    n = t.shape[0]
    if n == 0:
        raise WireError("empty", "no samples")
    if n > MAX_SAMPLES:
        raise WireError("too_large", f"{n} samples > {MAX_SAMPLES}")
    if n > 1 and not bool(np.all(np.diff(t) > 0)):
        raise WireError("non_increasing_t", "t is not strictly increasing within the message")
    return t


def _seq(obj: dict[str, Any]) -> int | None:
    seq = obj.get("seq")
    if seq is None:
        return None
    if isinstance(seq, bool) or not isinstance(seq, int) or not (0 <= seq < 2**63):
        raise WireError("bad_type", "seq must be a non-negative integer")
    return seq


def decode(key: str, payload: bytes | str | dict[str, Any], prefix: str = keys.DEFAULT_PREFIX) -> Message:
    """Decode one device→service message. Raises :class:`WireError` on anything invalid."""
    try:
        pk = keys.parse(key, prefix)
    except keys.KeyError_ as exc:
        raise WireError("unknown_key", str(exc)) from None
    obj = _load(payload)
    if pk.kind == "imu":
        t = _times(obj)
        n = t.shape[0]
        return ImuMessage(
            pk.device, pk.segment or "upperarm", t,
            _array(obj, "gyr", n, 3), _array(obj, "acc", n, 3), _seq(obj),
        )
    if pk.kind == "robot":
        t = _times(obj)
        n = t.shape[0]
        elbow = _array(obj, "elbow", n, 3) if obj.get("elbow") is not None else None
        return RobotMessage(
            pk.device, t, _array(obj, "wrist", n, 3), _array(obj, "proximal", n, 3), elbow,
            _seq(obj),
        )
    if pk.kind == "camera":
        t = _times(obj)
        n = t.shape[0]
        sh = _array(obj, "shoulder", n, 3) if obj.get("shoulder") is not None else None
        return CameraMessage(
            pk.device, t, _array(obj, "elbow", n, 3), _array(obj, "wrist", n, 3), sh, _seq(obj)
        )
    if pk.kind == "event":
        return _event(pk.device, obj)
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
        point = _array({"p": [obj["point"]]}, "p", 1, 3)[0]
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


def feedback_cycle(start: float, end: float, outside_fraction: float, compensatory: bool) -> dict[str, Any]:
    return {
        "type": "cycle", "start": start, "end": end,
        "outside_fraction": outside_fraction, "compensatory": compensatory,
    }
