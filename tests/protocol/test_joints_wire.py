"""Contract §8's joints stream: the key and the payload (parallel arrays, null where a value
is not available), encoded and decoded by the one wire module."""

from __future__ import annotations

import math

import numpy as np
import orjson
import pytest

from protocol import keys, wire


def test_joints_key() -> None:
    assert keys.joints("wear01") == "rehab/wear01/joints"
    assert keys.joints("wear01", "clinic/a") == "clinic/a/wear01/joints"
    assert keys.parse("rehab/wear01/joints") == keys.ParsedKey("wear01", "joints")
    assert "joints" not in keys.INPUT_KINDS  # the service's output, never ingested


def test_joints_payload_round_trip() -> None:
    n = 4
    rows = {c: np.arange(n, dtype=float) + j for j, c in enumerate(wire.JOINT_COLUMNS)}
    rows["elbow_flexion_deg"][1] = math.nan
    rows["shoulder_flexion_std_deg"] = np.array([0.5, 1.0, math.inf, 2.0])
    data = wire.joints_payload(rows, ("shoulder_flexion_std_deg",))
    obj = orjson.loads(data)
    assert list(obj) == [*wire.JOINT_COLUMNS, "shoulder_flexion_std_deg"]
    assert obj["elbow_flexion_deg"][1] is None and obj["shoulder_flexion_std_deg"][2] is None
    back = wire.decode_joints(data)
    for c in wire.JOINT_COLUMNS:
        np.testing.assert_array_equal(back[c], rows[c])


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b'{"t": [1.0]}', "missing_field"),
        (b'{"t": [1.0, 2.0], "shoulder_flexion_deg": [1.0]}', "bad_shape"),
        (b'{"t": ["a"]}', "bad_type"),
        (b'{"t": 1.0}', "bad_type"),
        (b"[1]", "not_object"),
    ],
)
def test_bad_joints_payloads_are_refused(payload: bytes, reason: str) -> None:
    with pytest.raises(wire.WireError) as exc:
        wire.decode_joints(payload)
    assert exc.value.reason == reason
