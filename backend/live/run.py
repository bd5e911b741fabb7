"""One device's current run: the preview (default parameters, nothing kept) or a session
(its parameters, its recording, its files, its report).

A session's :class:`backend.analysis.DeviceRun` sees exactly the lines of its recording, in
order, decoded exactly as ``rehab analyze`` decodes them; that is what makes the live files
identical to an offline analysis of the recording.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.analysis import DeviceRun, admit
from backend.deps import SessionInfo
from backend.live.budget import RecordingBudget
from backend.live.devices import DeviceStats
from backend.live.files import SessionFiles
from backend.live.ingest import RawMessage, recorded_form
from estimators.output import Output
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from estimators.wearable.params import WearableParams
from protocol import keys, wire

log = logging.getLogger(__name__)

SHOULDER_MEMORY = 25  # rows (1 s at 25 Hz) averaged for "nominal from the estimate"
SHOULDER_BATCH = 64  # polled rows filtered at once (per poll, numpy's call overhead dominated)


def session_params(obj: dict[str, Any]) -> PipelineParams | WearableParams:
    """A session's parameters: contract §8's ``"mode": "wearable"`` or the robot mode's."""
    if obj.get("mode") == "wearable":
        return WearableParams.from_json(obj)
    return PipelineParams.from_json(obj)


@dataclass(frozen=True)
class SessionContext:
    info: SessionInfo
    params: PipelineParams | WearableParams  # a wearable session's: contract §8
    patient: str | None
    recording_max_bytes: int = 2 << 30  # Settings.recording_max_bytes


def compact_stats(run: DeviceRun, every: int = 512) -> None:
    """``DeviceRun`` keeps one small array per poll and column for the report (~100 bytes
    of overhead for 8 of data: ~75 MB per device-hour at 25 polls/s); merge them now and
    then. The report concatenates them anyway, so it is unchanged."""
    stats = run._stats
    if stats and len(next(iter(stats.values()))) >= every:
        for k, parts in stats.items():
            stats[k] = [np.concatenate(parts)]


def rows_ready(p: Pipeline) -> bool:
    """Robot samples decided (their IMU is in, or waited for long enough) and not emitted:
    a poll now produces rows. Polling only then halves the polls of a 100/25 Hz device."""
    return p.rows_ready


class LiveRun:
    def __init__(
        self,
        device: str,
        prefix: str,
        stats: DeviceStats,
        session: SessionContext | None = None,
        files: SessionFiles | None = None,
    ) -> None:
        self.device = device
        self.prefix = prefix
        self.stats = stats
        self.session = session
        self.files = files
        params = session.params if session else PipelineParams()
        assert isinstance(params, PipelineParams)  # a wearable session: WearableLiveRun
        self.params = params
        self.run = DeviceRun(device, self.params)
        self.run.keep_rows = session is not None  # a preview keeps no rows
        self.budget = RecordingBudget(session.recording_max_bytes if session else 0)
        if files is not None:
            self.run.est_lines = files.estimates
            self.run.det_lines = files.details
        self.latest_t: float | None = None  # newest IMU/robot stamp fed (for therapist events)
        self.fed_since_poll = False
        self.fed_samples = 0  # since the last poll: the worker polls before they pile up
        self.cycle_index = 0
        self.nominal: tuple[float, float, float] | None = None
        # where the next nominal shoulder comes from (for the sessions table)
        self.nominal_source = "params" if self.params.nominal_shoulder_m is not None else "auto"
        # the newest converged shoulder rows, in blocks (a row each was a numpy view per
        # row): at least SHOULDER_MEMORY rows once there are that many; the polls' rows wait
        # unfiltered in _unsorted until SHOULDER_BATCH of them (or a request) are there
        self._shoulders: deque[np.ndarray] = deque()
        self._shoulder_rows = 0
        self._unsorted: list[tuple[np.ndarray, np.ndarray]] = []
        self._unsorted_rows = 0
        self.failures = 0
        self.converged = False  # of the newest row (a change is pushed to dashboards)
        self.pending: list[dict[str, Any]] = []  # therapist events waiting for data

    @property
    def session_id(self) -> int | None:
        return self.session.info.id if self.session else None

    @property
    def pipeline(self) -> Pipeline:
        return self.run.pipeline

    def ingest(self, msg: RawMessage) -> wire.Message | None:
        """Record, decode and feed one message; returns it if the decoder accepted it."""
        assert msg.payload is not None
        line = recorded_form(msg.payload)
        if self.files is not None and not self.budget.take(len(line), self.session_id):
            self.stats.reject("recording_full")  # neither recorded nor fed: live = offline
            return None
        try:
            decoded: wire.Message | None = wire.decode(msg.key, line, self.prefix)
        except wire.WireError as exc:
            decoded, reason = None, exc.reason
        if self.pending and isinstance(decoded, (wire.ImuMessage, wire.RobotMessage)):
            self._release_pending(float(decoded.t[0]))
        if self.files is not None:
            self.files.recorder.append_raw(msg.key, line)
        if decoded is None:
            self.run.reject(reason)
            self.stats.reject(reason)
            return None
        self.stats.accepted += 1
        if isinstance(decoded, wire.EventMessage) and decoded.type != "cycle_start":
            # the device's own reference (the rope on the shoulder) or reset
            self.nominal_source = "event" if decoded.type == "shoulder_reference" else "auto"
        self._feed(decoded)
        return decoded

    def _feed(self, decoded: wire.Message) -> None:
        resets = self.run.clock.resets
        if not admit(self.run, decoded):  # a far jump of the device's clock
            self.stats.accepted -= 1  # the decoder's acceptance, overruled
            self.stats.reject(self.run.clock.reason)
            return
        if self.run.clock.resets != resets:  # counted in the report (clock_reset)
            log.warning("device %s: clock changed for good; pipeline restarted", self.device)
            self.latest_t = None
        try:
            ok = self.run.pipeline.feed(decoded)
        except Exception:
            self.fail("feed")
            return
        self.fed_since_poll = True
        if ok and isinstance(decoded, (wire.ImuMessage, wire.RobotMessage)):
            n = len(decoded.t)
            self.fed_samples += n
            if isinstance(decoded, wire.ImuMessage):
                self.stats.imu_samples += n
            else:
                self.stats.robot_samples += n
            t_last = float(decoded.t[-1])
            if self.latest_t is None or t_last > self.latest_t:
                self.latest_t = t_last

    def event(self, payload: dict[str, Any]) -> bytes | None:
        """A therapist's event, stamped with the newest sample time. Before any data it
        waits and goes in just ahead of the first message, stamped with its first sample
        time (it then applies from the first row). Returns the payload if sent now."""
        if self.latest_t is None:
            self.pending.append(payload)
            return None
        return self._event({**payload, "t": self.latest_t})

    def _event(self, payload: dict[str, Any]) -> bytes:
        data = wire.dumps(payload)
        key = keys.event(self.device, self.prefix)
        if self.files is not None:
            self.files.recorder.append_raw(key, data)
        decoded = wire.decode(key, data, self.prefix)
        self.stats.accepted += 1
        self._feed(decoded)
        return data

    def _release_pending(self, t: float) -> None:
        pending, self.pending = self.pending, []
        for payload in pending:
            self._event({**payload, "t": t})

    def poll(self, final: bool = False) -> Output | None:
        self.fed_since_poll = False
        self.fed_samples = 0
        try:
            out = self.run.pipeline.poll()
            if final:
                out.extend(self.run.pipeline.finish())
        except Exception:
            self.fail("poll")
            return None
        if self.session is not None:
            self.run.take(out)  # rows to the files, cycles and statistics to the report
            compact_stats(self.run)
        if out.n:
            self._keep_shoulders(out.rows["shoulder"], out.rows["heading_converged"])
        return out

    def _keep_shoulders(self, sh: np.ndarray, converged: np.ndarray) -> None:
        self._unsorted.append((sh, converged))
        self._unsorted_rows += len(sh)
        if self._unsorted_rows >= SHOULDER_BATCH:
            self._sort_shoulders()

    def _sort_shoulders(self) -> None:
        """The waiting rows' finite, converged shoulders into the kept blocks: the same
        rows, in the same order, as filtering each poll's block on its own."""
        if not self._unsorted:
            return
        parts, self._unsorted, self._unsorted_rows = self._unsorted, [], 0
        if len(parts) == 1:
            sh, converged = parts[0]
        else:
            sh = np.concatenate([p[0] for p in parts])
            converged = np.concatenate([p[1] for p in parts])
        block = sh[np.isfinite(sh).all(axis=1) & converged.astype(bool)]
        if not len(block):
            return
        kept = self._shoulders
        kept.append(block)
        self._shoulder_rows += len(block)
        while self._shoulder_rows - len(kept[0]) >= SHOULDER_MEMORY:
            self._shoulder_rows -= len(kept.popleft())

    def fail(self, where: str) -> None:
        """A pipeline exception: count, log (not a flood of it), start the pipeline afresh.
        The run keeps what it accumulated (rows written, cycles, statistics)."""
        self.failures += 1
        self.stats.pipeline_errors += 1
        if self.failures <= 3 or self.failures % 100 == 0:
            log.exception(
                "device %s: pipeline %s failed (%d); pipeline reset",
                self.device,
                where,
                self.failures,
            )
        self.run.pipeline = Pipeline(self.params)
        self.fed_since_poll = False

    def shoulder_estimate(self) -> list[float] | None:
        self._sort_shoulders()
        if not self._shoulders:
            return None
        recent = np.concatenate(self._shoulders)[-SHOULDER_MEMORY:]
        return [float(x) for x in np.mean(recent, axis=0)]

    def nominal_change(self, out: Output) -> tuple[float, float, float] | None:
        """The nominal shoulder of the newest row, if it differs from the last one seen."""
        if not out.n:
            return None
        x, y, z = out.rows["nominal_shoulder"][-1].tolist()  # Python floats: cheaper here
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            self.nominal = None
            return None
        point = (x, y, z)
        if point == self.nominal:
            return None
        self.nominal = point
        return point

    def finish(self) -> tuple[Output | None, dict[str, Any]]:
        """End of the session: the last rows, the report (as ``rehab analyze`` makes it)."""
        out = self.poll(final=True)
        report = self.run.report()
        report["data_quality"]["other_devices"] = {}  # analyze adds it; one device here
        return out, report
