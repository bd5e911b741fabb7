"""Zenoh key expressions of the contract (§1), kept in one place.

Every key the project reads or writes is built or parsed here, so the prefix
(``rehab`` by default, configurable) and the device-name rule live in one module.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

DEFAULT_PREFIX = "rehab"
DEVICE_RE = re.compile(r"[A-Za-z0-9_-]{1,64}")
SEGMENTS = ("upperarm", "forearm", "trunk")

Kind = Literal["imu", "robot", "camera", "event", "estimate", "feedback", "joints"]
INPUT_KINDS: tuple[Kind, ...] = ("imu", "robot", "camera", "event")


@dataclass(frozen=True, slots=True)
class ParsedKey:
    device: str
    kind: Kind
    segment: str | None = None


class KeyError_(ValueError):
    """A key that is not one of the contract's (counted as ``unknown_key``)."""


@lru_cache(maxsize=4096)
def parse(key: str, prefix: str = DEFAULT_PREFIX) -> ParsedKey:
    """Split ``<prefix>/<device>/<kind>[/<segment>]``; raise :class:`KeyError_` otherwise."""
    parts = key.split("/")
    pre = prefix.split("/")
    if parts[: len(pre)] != pre:
        raise KeyError_(f"key {key!r} is outside prefix {prefix!r}")
    rest = parts[len(pre) :]
    if len(rest) < 2 or not DEVICE_RE.fullmatch(rest[0]):
        raise KeyError_(f"key {key!r} has no valid device name")
    device, kind = rest[0], rest[1]
    if kind == "imu":
        if len(rest) != 3 or rest[2] not in SEGMENTS:
            raise KeyError_(f"key {key!r}: imu needs one segment of {SEGMENTS}")
        return ParsedKey(device, "imu", rest[2])
    if kind in ("robot", "camera", "event", "estimate", "feedback", "joints") and len(rest) == 2:
        return ParsedKey(device, kind)  # type: ignore[arg-type]
    raise KeyError_(f"key {key!r} is not a contract key")


def imu(device: str, segment: str = "upperarm", prefix: str = DEFAULT_PREFIX) -> str:
    return f"{prefix}/{device}/imu/{segment}"


def robot(device: str, prefix: str = DEFAULT_PREFIX) -> str:
    return f"{prefix}/{device}/robot"


def camera(device: str, prefix: str = DEFAULT_PREFIX) -> str:
    return f"{prefix}/{device}/camera"


def event(device: str, prefix: str = DEFAULT_PREFIX) -> str:
    return f"{prefix}/{device}/event"


def estimate(device: str, prefix: str = DEFAULT_PREFIX) -> str:
    return f"{prefix}/{device}/estimate"


def feedback(device: str, prefix: str = DEFAULT_PREFIX) -> str:
    return f"{prefix}/{device}/feedback"


def joints(device: str, prefix: str = DEFAULT_PREFIX) -> str:
    """A wearable device's joint angles (contract §8), published by the service."""
    return f"{prefix}/{device}/joints"


def subscription(prefix: str = DEFAULT_PREFIX) -> str:
    """Everything devices publish (the service filters out its own outputs by kind)."""
    return f"{prefix}/*/**"


def device_data(device: str, prefix: str = DEFAULT_PREFIX) -> str:
    """Everything one device publishes: a worker's subscription while it holds the device."""
    return f"{prefix}/{device}/**"


def device_inputs(prefix: str = DEFAULT_PREFIX) -> tuple[str, ...]:
    """Every device's inputs, one expression per kind (not the service's own outputs)."""
    return (
        f"{prefix}/*/robot",
        f"{prefix}/*/imu/*",
        f"{prefix}/*/camera",
        f"{prefix}/*/event",
    )


# The service's own keys between its processes (not §1: "@" is outside a device name, so
# they cannot collide with a device's).


def devices_notice(prefix: str = DEFAULT_PREFIX) -> str:
    """The API node's list of the devices it heard recently."""
    return f"{prefix}/@devices"


def worker_key(prefix: str, holder: str) -> str:
    """A worker's liveliness token."""
    return f"{prefix}/@worker/{holder}"


def control_key(prefix: str, device: str = "*") -> str:
    """The workers' queryable for the API node's session commands."""
    return f"{prefix}/@ctl/{device}"


def feed_key(prefix: str, holder: str = "*") -> str:
    """A worker's dashboard messages for the API node's WebSockets."""
    return f"{prefix}/@feed/{holder}"
