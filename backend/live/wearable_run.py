"""A wearable device's current run (contract §8): the preview or a session, beside
:class:`backend.live.run.LiveRun` of the robot devices.

The session's :class:`backend.analysis_wearable.WearableRun` sees exactly the lines of its
recording, in order, decoded exactly as ``rehab analyze`` decodes them: the live joints.csv
is the offline one, by construction. Each poll hands the rows completed since the last one
to the files, the joints publisher and the dashboards.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from backend import analysis_wearable as aw
from backend.live.budget import RecordingBudget
from backend.live.devices import DeviceStats
from backend.live.files import SessionFiles
from backend.live.ingest import RawMessage, recorded_form
from backend.live.run import SessionContext
from estimators.wearable import tracker
from estimators.wearable.params import WearableParams
from protocol import wire

log = logging.getLogger(__name__)

# An angle whose standard deviation is above this is not shown as sure (the dashboard greys
# it and the ROM test ignores it): the vertical turn drifts without a camera (§8 "Start").
# The σ includes the model's errors and what no sensor sees (WearableParams.sigma_floor_deg/
# sigma_share/sigma_doubt/sigma_pronation_vertical_deg/sigma_axial_share/pronation_drift_dps/
# vertical_init_deg:
# it covers the error on ~95 % of samples, and an angle off by more than this is rarely shown
# sure); 7.5° keeps shoulder and elbow flexion sure over their whole range (5.8° at 180° of
# shoulder flexion), within a goniometer's 5-10°, and greys a drifting angle, pronation beyond
# ~30° (or with the elbow straight), where the error grows with the angle, and the flexions
# for 30-40 s after a shoulder rotation to ±60°; without a camera, shoulder abduction and
# rotation most of the time (the turn about the vertical).
SURE_STD_DEG = 7.5
ANGLES = aw.ANGLES
STD_OF = dict(zip(ANGLES, tracker.STD_COLUMNS[:5], strict=True))
# the rows' columns on the joints key and the WebSocket: §8's, then the extensions
EXTRA = (*tracker.STD_COLUMNS, "flags")
ROM_MOVES = {  # a ROM test's movement → (joint angle, sign of its peak)
    "shoulder_flexion": ("shoulder_flexion_deg", 1.0),
    "shoulder_extension": ("shoulder_flexion_deg", -1.0),
    "shoulder_abduction": ("shoulder_abduction_deg", 1.0),
    "shoulder_internal_rotation": ("shoulder_rotation_deg", 1.0),
    "shoulder_external_rotation": ("shoulder_rotation_deg", -1.0),
    "elbow_flexion": ("elbow_flexion_deg", 1.0),
    "elbow_extension": ("elbow_flexion_deg", -1.0),
    "forearm_pronation": ("forearm_pronation_deg", 1.0),
    "forearm_supination": ("forearm_pronation_deg", -1.0),
}


def is_wearable_params(obj: Any) -> bool:
    return aw.is_wearable(obj)


@dataclass
class RomTest:
    """A range-of-motion test: the therapist asks for ``movement``; its peak is the extreme
    of the joint angle, among the sure rows, between start and stop (sample time)."""

    movement: str
    start_t: float | None
    end_t: float | None = None
    peak_deg: float | None = None
    peak_t: float | None = None
    sure_rows: int = 0
    rows: int = 0

    def take(self, rows: tracker.Rows) -> None:
        joint, sign = ROM_MOVES[self.movement]
        t = rows["t"]
        keep = np.ones(len(t), dtype=bool)
        if self.start_t is not None:
            keep &= t >= self.start_t
        v, s = rows[joint][keep], rows[STD_OF[joint]][keep]
        tk = t[keep]
        self.rows += len(v)
        sure = np.isfinite(v) & (s <= SURE_STD_DEG)
        self.sure_rows += int(sure.sum())
        if not sure.any():
            return
        vals = sign * v[sure]
        i = int(np.argmax(vals))
        if self.peak_deg is None or vals[i] > sign * self.peak_deg:
            self.peak_deg = round(float(sign * vals[i]), 3)
            self.peak_t = float(tk[sure][i])

    def as_dict(self) -> dict[str, Any]:
        joint, _ = ROM_MOVES[self.movement]
        return {
            "movement": self.movement,
            "joint": joint,
            "start_t": self.start_t,
            "end_t": self.end_t,
            "peak_deg": self.peak_deg,
            "peak_t": self.peak_t,
            "rows": self.rows,
            "sure_rows": self.sure_rows,
        }


@dataclass
class JointsOut:
    """The rows of one poll (columns of :data:`tracker.COLUMNS`, STD_COLUMNS, ``flags``)."""

    rows: tracker.Rows | None
    n: int = 0
    feedback: list[dict[str, Any]] = field(default_factory=list)


class WearableLiveRun:
    def __init__(
        self,
        device: str,
        prefix: str,
        stats: DeviceStats,
        session: SessionContext | None = None,
        files: SessionFiles | None = None,
        params: WearableParams | None = None,
    ) -> None:
        self.device = device
        self.prefix = prefix
        self.stats = stats
        self.session = session
        self.files = files
        wp = session.params if session is not None else params
        assert wp is None or isinstance(wp, WearableParams)
        self.params: WearableParams = wp or WearableParams()
        self.run = aw.WearableRun(self.params, device, prefix)
        self.budget = RecordingBudget(session.recording_max_bytes if session else 0)
        self.latest_t: float | None = None
        self.fed_since_poll = False
        self.fed_samples = 0
        self.failures = 0
        self.converged = False  # every angle of the newest row is sure
        self.last_row: dict[str, float] = {}
        self.rom_tests: list[RomTest] = []
        self.rom_active: RomTest | None = None
        self.flagged: dict[str, int] = {}  # rows per flag (forearm_missing, camera_stale...)
        self.camera = aw.CameraWatch()

    @property
    def session_id(self) -> int | None:
        return self.session.info.id if self.session else None

    def ingest(self, msg: RawMessage) -> wire.Message | None:
        """Record, decode and feed one message (as ``rehab analyze`` reads its line)."""
        assert msg.payload is not None
        line = recorded_form(msg.payload)
        if self.files is not None and not self.budget.take(len(line), self.session_id):
            self.stats.reject("recording_full")  # neither recorded nor fed: live = offline
            return None
        if self.files is not None:
            self.files.recorder.append_raw(msg.key, line)
        try:
            decoded = self.run.feed_line(msg.key, line)
        except Exception:  # a tracker bug: counted, the run starts afresh
            self.fail()
            return None
        if decoded is None:
            self.stats.reject(self.run.last_reason)
            return None
        self.stats.accepted += 1
        self.fed_since_poll = True
        if isinstance(decoded, wire.ImuMessage):
            n = len(decoded.t)
            self.fed_samples += n
            self.stats.imu_samples += n
            t_last = float(decoded.t[-1])
            if self.latest_t is None or t_last > self.latest_t:
                self.latest_t = t_last
        return decoded

    def fail(self) -> None:
        self.failures += 1
        self.stats.pipeline_errors += 1
        if self.failures <= 3:
            log.exception("device %s: wearable tracker failed; restarted", self.device)
        self.run.state = tracker.initial_state(self.params)

    def poll(self, final: bool = False) -> JointsOut | None:
        self.fed_since_poll = False
        self.fed_samples = 0
        if final:
            self.run.finish()
        rows = self.run.take()
        if rows is None:
            return JointsOut(None)
        if self.files is not None:
            self.files.sinks["joints.csv"].extend(aw.joint_lines(rows))
        n = len(rows["t"])
        if self.rom_active is not None:
            self.rom_active.take(rows)
        flags = rows["flags"].astype(np.int64)
        self.camera.update(rows["t"], flags)
        for bit, name in aw._FLAG_NAMES.items():
            k = int(((flags & bit) > 0).sum())
            if k:
                self.flagged[name] = self.flagged.get(name, 0) + k
        self.last_row = {c: float(rows[c][-1]) for c in (*tracker.COLUMNS, *EXTRA)}
        return JointsOut(rows, n)

    def sure(self) -> dict[str, bool]:
        """Per angle: available and its standard deviation within :data:`SURE_STD_DEG`."""
        r = self.last_row
        return {
            a: math.isfinite(r.get(a, math.nan)) and r.get(STD_OF[a], math.inf) <= SURE_STD_DEG
            for a in ANGLES
        }

    # ------------------------------------------------------------------ ROM tests

    def rom_start(self, movement: str) -> dict[str, Any]:
        if movement not in ROM_MOVES:
            raise ValueError(f"unknown movement {movement!r}; one of {', '.join(ROM_MOVES)}")
        if self.rom_active is not None:
            self.rom_stop()
        self.rom_active = RomTest(movement, self.latest_t)
        return self.rom_active.as_dict()

    def rom_stop(self) -> dict[str, Any] | None:
        test, self.rom_active = self.rom_active, None
        if test is None:
            return None
        test.end_t = self.latest_t
        self.rom_tests.append(test)
        return test.as_dict()

    # ------------------------------------------------------------------ status, report

    def status(self) -> dict[str, Any]:
        """What the dashboard shows beside the rows (``pipeline`` of the status message)."""
        r = self.last_row
        conf = {a: (r[STD_OF[a]] if math.isfinite(r.get(STD_OF[a], math.nan)) else None)
                for a in ANGLES} if r else dict.fromkeys(ANGLES)  # fmt: skip
        flags = int(r.get("flags", 0)) if r else 0
        return {
            "mode": "wearable",
            "heading_converged": self.converged,  # the robot mode's key: all angles sure
            "convergence_progress": 1.0 if self.converged else 0.0,
            "angles_std_deg": conf,
            "angles_sure": self.sure(),
            "sure_std_deg": SURE_STD_DEG,
            "vertical_std_deg": r.get("vertical_std_deg") if r else None,
            "flags": [name for bit, name in aw._FLAG_NAMES.items() if flags & bit],
            "filter": self.params.filter,
            "model": self.params.model,
            "side": self.params.side,
            "rom_active": self.rom_active.as_dict() if self.rom_active else None,
            "rom_tests": [t.as_dict() for t in self.rom_tests],
            "messages": _messages(flags, self.camera.out),
            "quality": {
                "rejected": dict(sorted((self.run.rejected + self.run.state.rejected).items())),
                "flagged_rows": dict(sorted(self.flagged.items())),
                "camera_dropouts": self.camera.dropouts,
            },
        }

    def report(self) -> dict[str, Any]:
        rep = self.run.report()
        if self.rom_tests:  # without any, the report is rehab analyze's to the byte
            rep["rom_tests"] = [t.as_dict() for t in self.rom_tests]
        return rep

    def finish(self) -> tuple[JointsOut | None, dict[str, Any]]:
        """End of the session: the last rows, the report (as ``rehab analyze`` makes it,
        plus the ROM tests of the session)."""
        if self.rom_active is not None:
            self.rom_stop()
        out = self.poll(final=True)
        return out, self.report()


MESSAGES = {  # what a flag of the newest row means, for the therapist
    tracker.FOREARM_MISSING: "No forearm IMU data: elbow and forearm angles are not shown.",
    tracker.CAMERA_STALE: "Camera data stale or dropped: the arm's turn about the vertical "
    "is carried by the gyros alone.",
    tracker.NOT_AT_REST: "The session did not start at rest in the zero pose: angles doubtful.",
    tracker.MOUNTING_MISMATCH: "The IMU mounting does not fit the data (gravity at rest): "
    "check the sensors' placement; angles are not shown.",
    tracker.INCONSISTENT: "Measurements do not fit the arm model: angles doubtful.",
    tracker.RESTARTED: "The filter restarted after a gap in the data.",
    tracker.INITIALISING: "Initialising: keep the arm still in the zero pose.",
}


CAMERA_OUT = (
    "The camera dropped out: the angles are carried by the IMUs alone, and their uncertainty "
    "grows as the arm moves."
)


def _messages(flags: int, camera_out: bool) -> list[str]:
    out = [text for bit, text in MESSAGES.items() if flags & bit]
    return [*out, CAMERA_OUT] if camera_out else out
