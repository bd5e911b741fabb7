"""The WebSocket messages of ``/api/ws/live`` and ``/api/ws/overlay``, defined once.

The feeds build these as plain dicts (:mod:`backend.live.feed`, serialised by orjson, NaN as
null), typed by the ``TypedDict`` models here; the live tests validate every message a real
service sends against them (no key more, none missing). The front end's TypeScript types are
generated from their JSON Schema (``python -m backend.schemas.live`` writes
``frontend/src/lib/live-messages.schema.json``, which the front end's build turns into
``live-messages.ts`` with json-schema-to-typescript; a test keeps the file current).

Floats that may be NaN or unknown are ``float | None`` (JSON null).
"""

from __future__ import annotations

import json
import sys
from typing import (
    Annotated,
    Any,
    Literal,
    NotRequired,  # pydantic needs these before 3.12
)

from pydantic import ConfigDict, Field, TypeAdapter, with_config
from typing_extensions import TypedDict

IndicatorState = Literal["ok", "outside", "warning"]
Num = float | None
_STRICT = ConfigDict(extra="forbid")


@with_config(_STRICT)
class Gap(TypedDict):
    stream: Literal["imu", "robot"]
    t: float
    duration_s: float


@with_config(_STRICT)
class PipelineQuality(TypedDict):
    """The pipeline's data quality (``estimators.output.Quality.as_dict``), the latest 20
    gaps only."""

    rejected: dict[str, int]
    ignored: dict[str, int]
    imu_samples: int
    robot_samples: int
    imu_bridged_gaps: int
    imu_bridged_samples: int
    imu_resets: int
    robot_bridged_gaps: int
    robot_gaps: int
    seq_lost: dict[str, int]
    rows_without_imu: int
    heading_resets: int
    gaps: list[Gap]


@with_config(_STRICT)
class Rates(TypedDict):
    imu: float
    robot: float


@with_config(_STRICT)
class Ingest(TypedDict):
    messages: int
    bytes: int
    accepted: int
    rejected: dict[str, int]
    dropped: int
    pipeline_errors: int
    queued: int


@with_config(_STRICT)
class HelloMsg(TypedDict):
    """First message of the therapists' feed: the devices it covers."""

    type: Literal["hello"]
    devices: list[str]


@with_config(_STRICT)
class StatusMsg(TypedDict):
    """A device's presence, session, heading convergence and data quality (therapists)."""

    type: Literal["status"]
    device: str
    online: bool
    session_id: int | None
    patient: str | None
    heading_converged: bool
    convergence_progress: float
    heading_offset_deg: Num
    heading_std_deg: Num
    heading_confidence: float
    heading_drift_dps: Num
    excitation_m_s2: Num
    first_motion_t: Num
    converged_t: Num
    robot_latency_s: Num
    acc_bias_m_s2: list[Num]
    lever_error_m: list[Num]
    upper_arm_length_m: float
    upper_arm_length_measured: bool
    quality: PipelineQuality
    rates_hz: Rates
    ingest: Ingest
    tolerance_m: float
    max_outside_fraction: float


@with_config(_STRICT)
class RomTest(TypedDict):
    """A ROM test of a wearable session: the extreme of one joint angle among sure rows."""

    movement: str
    joint: str
    start_t: Num
    end_t: Num
    peak_deg: Num
    peak_t: Num
    rows: int
    sure_rows: int


@with_config(_STRICT)
class WearableQuality(TypedDict):
    rejected: dict[str, int]
    flagged_rows: dict[str, int]
    camera_dropouts: int
    gaps: list[Gap]


@with_config(_STRICT)
class WearableStatusMsg(TypedDict):
    """A wearable device's status (contract §8): each joint angle's confidence, what is
    wrong, the ROM tests (therapists)."""

    type: Literal["status"]
    device: str
    online: bool
    session_id: int | None
    patient: str | None
    mode: Literal["wearable"]
    heading_converged: bool  # the robot mode's key: every angle sure
    convergence_progress: float
    angles_std_deg: dict[str, Num]
    angles_sure: dict[str, bool]
    sure_std_deg: float
    vertical_std_deg: Num
    flags: list[str]
    filter: str
    model: str
    side: str
    rom_active: RomTest | None
    rom_tests: list[RomTest]
    messages: list[str]
    quality: WearableQuality
    rates_hz: dict[str, float]
    ingest: Ingest
    tolerance_m: float
    max_outside_fraction: float


@with_config(_STRICT)
class JointsMsg(TypedDict):
    """A wearable device's rows: joints.csv's columns (§8), each angle's standard deviation,
    flags (``backend.live.feed.JOINTS_COLUMNS``)."""

    type: Literal["joints"]
    device: str
    rows: dict[str, list[Num]]


@with_config(_STRICT)
class OverlayStatusMsg(TypedDict):
    """The overlay's status: what the game needs to draw its circle and wait."""

    type: Literal["status"]
    device: str
    heading_converged: bool
    convergence_progress: float
    online: bool
    tolerance_m: float


@with_config(_STRICT)
class LiveRows(TypedDict):
    """Estimate rows as parallel columns: contract §7's, then the dashboard's."""

    t: list[float]
    elbow_x: list[Num]
    elbow_y: list[Num]
    elbow_z: list[Num]
    shoulder_x: list[Num]
    shoulder_y: list[Num]
    shoulder_z: list[Num]
    elbow_angle_deg: list[Num]
    heading_offset_deg: list[Num]
    shoulder_displacement_m: list[Num]
    upper_arm_elevation_deg: list[Num]
    upper_arm_azimuth_deg: list[Num]
    heading_confidence: list[Num]
    nominal_x: list[Num]
    nominal_y: list[Num]
    nominal_z: list[Num]
    wrist_x: list[Num]
    wrist_y: list[Num]
    wrist_z: list[Num]
    heading_converged: list[Literal[0, 1]]
    state: list[IndicatorState | None]


@with_config(_STRICT)
class OverlayRows(TypedDict):
    """The game's rows: the hand, the shoulder's displacement and its horizontal offset."""

    t: list[float]
    wrist_x: list[Num]
    wrist_y: list[Num]
    wrist_z: list[Num]
    shoulder_displacement_m: list[Num]
    dx: list[Num]
    dy: list[Num]
    state: list[IndicatorState | None]


@with_config(_STRICT)
class EstimateMsg(TypedDict):
    type: Literal["estimate"]
    device: str
    rows: LiveRows


@with_config(_STRICT)
class OverlayEstimateMsg(TypedDict):
    type: Literal["estimate"]
    device: str
    rows: OverlayRows


@with_config(_STRICT)
class StateMsg(TypedDict):
    """The indicator's state changed (sent at once)."""

    type: Literal["state"]
    device: str
    t: float
    state: IndicatorState


@with_config(_STRICT)
class CycleMsg(TypedDict):
    """A movement cycle ended and was judged."""

    type: Literal["cycle"]
    device: str
    start: float
    end: float
    outside_fraction: float
    compensatory: bool
    index: NotRequired[int]


# two kinds of status (robot, wearable): told apart by their keys, not by "type"
LiveMsg = HelloMsg | StatusMsg | WearableStatusMsg | EstimateMsg | StateMsg | CycleMsg | JointsMsg
OverlayMsg = Annotated[
    OverlayStatusMsg | OverlayEstimateMsg | StateMsg | CycleMsg, Field(discriminator="type")
]
LIVE: TypeAdapter[Any] = TypeAdapter(LiveMsg)
OVERLAY: TypeAdapter[Any] = TypeAdapter(OverlayMsg)


def json_schema() -> dict[str, Any]:
    """Both feeds' messages as one JSON Schema (the front end's types are made from it)."""
    defs: dict[str, Any] = {}
    for name, adapter in (("LiveMsg", LIVE), ("OverlayMsg", OVERLAY)):
        schema = adapter.json_schema()
        defs.update(schema.pop("$defs", {}))
        defs[name] = schema
    defs = _untitled(defs)  # field titles would become type aliases of their own
    props = {name: {"$ref": f"#/$defs/{name}"} for name in sorted(defs)}  # each one exported
    return {
        "title": "LiveMessages",
        "description": "WebSocket messages of /api/ws/live and /api/ws/overlay "
        "(generated from backend/schemas/live.py: do not edit)",
        "type": "object",
        "properties": props,
        "required": sorted(props),
        "additionalProperties": False,
        "$defs": defs,
    }


def _untitled(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _untitled(v) for k, v in x.items() if k != "title" or not isinstance(v, str)}
    if isinstance(x, list):
        return [_untitled(v) for v in x]
    return x


def schema_text() -> str:
    return json.dumps(json_schema(), indent=2, sort_keys=True) + "\n"


if __name__ == "__main__":
    sys.stdout.write(schema_text())
