"""The one wire schema: round trips, every rejection reason, and fuzzing."""

from __future__ import annotations

import contextlib
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import keys, wire

IMU = "rehab/dev-1/imu/upperarm"
ROBOT = "rehab/dev-1/robot"


def _imu(**over):
    p = {
        "t": [0.0, 0.01],
        "gyr": [[0, 0, 0.1], [0, 0, 0.2]],
        "acc": [[0, 0, 9.81], [0, 0.1, 9.8]],
        "seq": 4,
    }
    p.update(over)
    return json.dumps(p).encode()


def test_round_trip_all_kinds():
    msgs = [
        wire.ImuMessage(
            "dev-1", "upperarm", np.array([1.0, 1.01]), np.ones((2, 3)), np.zeros((2, 3)), 7
        ),
        wire.RobotMessage("dev-1", np.array([1.0]), np.ones((1, 3)), np.zeros((1, 3)), None, 0),
        wire.RobotMessage(
            "dev-1", np.array([1.0]), np.ones((1, 3)), np.zeros((1, 3)), np.ones((1, 3))
        ),
        wire.CameraMessage("dev-1", np.array([2.0]), np.ones((1, 3)), np.zeros((1, 3))),
        wire.EventMessage("dev-1", 3.0, "shoulder_reference", np.array([0.1, 0.2, 0.3])),
        wire.EventMessage("dev-1", 4.0, "cycle_start"),
    ]
    for m in msgs:
        key, payload = wire.encode(m)
        back = wire.decode(key, wire.dumps(payload))
        assert type(back) is type(m)
        for f in ("t", "gyr", "acc", "wrist", "proximal", "elbow", "point"):
            a, b = getattr(m, f, None), getattr(back, f, None)
            assert (a is None and b is None) or np.array_equal(a, b)


def test_extra_fields_are_ignored():
    m = wire.decode(IMU, _imu(mag=[[1, 2, 3], [1, 2, 3]]))
    assert isinstance(m, wire.ImuMessage) and m.seq == 4


@pytest.mark.parametrize(
    ("key", "payload", "reason"),
    [
        (IMU, b"{", "malformed_json"),
        (IMU, b"\xff\xfe", "malformed_json"),
        (IMU, b"[1, 2]", "not_object"),
        (IMU, _imu(t=[0.0]), "length_mismatch"),
        (IMU, json.dumps({"t": [0.0], "acc": [[0, 0, 0]]}).encode(), "missing_field"),
        (IMU, _imu(gyr=[[0, 0], [0, 0]]), "bad_shape"),
        (IMU, _imu(gyr=[[0, 0, "x"], [0, 0, 0]]), "bad_type"),
        (IMU, _imu(t=[0.01, 0.0]), "non_increasing_t"),
        (IMU, _imu(t=[0.0, 0.0]), "non_increasing_t"),
        (IMU, _imu(t=[], gyr=[], acc=[]), "empty"),
        (IMU, _imu(seq=-1), "bad_type"),
        (IMU, _imu(t=[True, 0.01]), "bad_type"),
        (IMU, b'{"t":[NaN,1],"gyr":[[0,0,0],[0,0,0]],"acc":[[0,0,0],[0,0,0]]}', "non_finite"),
        (IMU, b'{"t":[1e999,2],"gyr":[[0,0,0],[0,0,0]],"acc":[[0,0,0],[0,0,0]]}', "non_finite"),
        (IMU, b" " * (wire.MAX_PAYLOAD_BYTES + 1), "too_large"),
        ("rehab/dev-1/imu/leg", _imu(), "unknown_key"),
        ("rehab/bad device/robot", b"{}", "unknown_key"),
        ("other/dev-1/robot", b"{}", "unknown_key"),
        ("rehab/dev-1/estimate", b"{}", "unknown_key"),
        ("rehab/dev-1/event", b'{"t": 1, "type": "dance"}', "unknown_event"),
        ("rehab/dev-1/event", b'{"t": 1, "type": "shoulder_reference"}', "missing_field"),
        (
            "rehab/dev-1/event",
            b'{"t": 1, "type": "shoulder_reference", "point": [1, 2]}',
            "bad_shape",
        ),
        ("rehab/dev-1/event", b'{"type": "cycle_start"}', "missing_field"),
    ],
)
def test_rejections_have_clear_reasons(key, payload, reason):
    with pytest.raises(wire.WireError) as exc:
        wire.decode(key, payload)
    assert exc.value.reason == reason
    assert exc.value.detail


def test_python_objects_with_nan_are_rejected():
    with pytest.raises(wire.WireError, match="non_finite"):
        wire.decode(ROBOT, {"t": [1.0], "wrist": [[float("nan"), 0, 0]], "proximal": [[0, 0, 0]]})


def test_keys_module_is_the_single_source():
    assert keys.parse("rehab/a_b-9/imu/trunk") == keys.ParsedKey("a_b-9", "imu", "trunk")
    assert (
        keys.estimate("x") == "rehab/x/estimate"
        and keys.feedback("x", "clinic/r") == "clinic/r/x/feedback"
    )
    assert keys.parse("clinic/r/x/robot", "clinic/r").device == "x"


json_values = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=False) | st.integers() | st.text(max_size=5),
    lambda ch: (
        st.lists(ch, max_size=4)
        | st.dictionaries(
            st.sampled_from(["t", "gyr", "acc", "wrist", "proximal", "seq", "type", "point"]),
            ch,
            max_size=6,
        )
    ),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([IMU, ROBOT, "rehab/dev-1/camera", "rehab/dev-1/event"]), json_values)
def test_fuzz_json_gives_message_or_wire_error(key, value):
    try:
        raw = json.dumps(value).encode()
    except (ValueError, OverflowError):
        return
    try:
        m = wire.decode(key, raw)
    except wire.WireError as exc:
        assert exc.reason
        return
    assert m.device == "dev-1"


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=200))
def test_fuzz_bytes_give_message_or_wire_error(raw):
    for key in (IMU, ROBOT, "rehab/dev-1/event"):
        with contextlib.suppress(wire.WireError):
            wire.decode(key, raw)
