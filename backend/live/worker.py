"""One worker per device: its bounded queue, its current run, its outputs.

Isolation: a device's messages wait in its own queue (full: dropped and counted, the
ingest never waits); a turn handles at most ``BATCH`` of them, and the :class:`Scheduler`
gives every device with work a turn before any gets a second, so a flooding device cannot
starve the others; an exception in its pipeline resets that pipeline only. Session
start/stop and therapist events travel through the same queue as the data, so they take
effect at a defined point of the device's message order — the same point in the recording.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from sqlalchemy.ext.asyncio import AsyncSession

from backend import clinical
from backend.db.sessions import record_cycle, store_nominal_shoulder
from backend.deps import LiveUnavailable
from backend.live import feed
from backend.live.budget import POLL_SAMPLES, ROUND_S, TURN_BYTES, IngestBudget, rest_after
from backend.live.devices import DeviceStats
from backend.live.files import SessionFiles
from backend.live.hub import Hub
from backend.live.ingest import RawMessage
from backend.live.run import LiveRun, SessionContext, rows_ready
from backend.live.snapshot import Snapshotter
from backend.live.store import DbWriter
from backend.live.wearable_run import JointsOut, WearableLiveRun
from backend.live.zenoh_io import ZenohIO
from estimators.output import Output
from estimators.verdicts import CycleVerdict
from estimators.wearable.params import WearableParams
from protocol import wire

log = logging.getLogger(__name__)

BATCH = 64  # messages per turn before the other devices get theirs
WAITS_KEPT = 1 << 14  # turns' waits and durations kept for the worker's log (a few seconds)


class RowsView(Protocol):
    """The 3D view (:class:`backend.viz.Viz`): fed the dashboard's rows, never raises."""

    @property
    def selected(self) -> str | None: ...

    def update(self, device: str, rows: feed.Rows) -> None: ...


@dataclass(eq=False)
class Command:
    future: asyncio.Future[Any] = field(init=False)

    def __post_init__(self) -> None:
        self.future = asyncio.get_running_loop().create_future()


@dataclass(eq=False)
class StartSession(Command):
    context: SessionContext
    files: SessionFiles


@dataclass(eq=False)
class StopSession(Command):
    session_id: int


@dataclass(eq=False)
class RomTestCommand(Command):
    """Start (``movement``) or stop (None) a wearable session's ROM test."""

    session_id: int
    movement: str | None


@dataclass(eq=False)
class SetNominal(Command):
    session_id: int
    point: list[float] | None
    from_estimate: bool


def session_summary(report: dict[str, Any]) -> dict[str, Any]:
    """What the sessions table keeps of a report (the report itself is a file)."""
    return {
        **report["summary"],
        # .get: a wearable session's report (contract §8) has no heading nor shoulder
        "heading_converged_t": report.get("heading", {}).get("converged_t"),
        "shoulder_displacement_m": report.get("shoulder_displacement_m"),
        # range of motion, for the patient's history without reading every report
        "elbow_flexion_deg": report.get("elbow_flexion_deg"),
        "upper_arm_elevation_deg": report.get("upper_arm_elevation_deg"),
        "upper_arm_azimuth_deg": report.get("upper_arm_azimuth_deg"),
        "rejected_messages": sum(report["data_quality"]["rejected"].values()),
        **clinical.summary_part(report),  # anatomical ROM, movement quality medians
    }


def summary_of(report: dict[str, Any]) -> dict[str, Any]:
    """:func:`session_summary`, and a wearable session's own keys (:func:`wearable_summary`)."""
    out = session_summary(report)
    if report.get("mode") == "wearable":
        out.update(wearable_summary(report))
    return out


def wearable_summary(report: dict[str, Any]) -> dict[str, Any]:
    """A wearable session's: its range of motion per joint (§8 names), its ROM tests."""
    return {
        "mode": "wearable",
        "rom": report["rom"],
        "rom_tests": report.get("rom_tests", []),
        "rejected_messages": sum(report["data_quality"]["rejected"].values()),
        "flagged_rows": report["data_quality"]["flagged_rows"],
    }


AnyRun = LiveRun | WearableLiveRun


def new_run(
    name: str,
    prefix: str,
    stats: DeviceStats,
    context: SessionContext | None = None,
    files: SessionFiles | None = None,
    wearable: WearableParams | None = None,
) -> AnyRun:
    """The run a device's session (its parameters, contract §8 "mode") or preview
    (``wearable``: the preview of a device that sends wearable streams) needs."""
    if context is not None and isinstance(context.params, WearableParams):
        return WearableLiveRun(name, prefix, stats, context, files)
    if context is None and wearable is not None:
        return WearableLiveRun(name, prefix, stats, params=wearable)
    return LiveRun(name, prefix, stats, context, files)


def _always() -> bool:
    return True


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


class Scheduler:
    """Gives the device workers their turns on the event loop.

    A worker with work is marked ready; one loop callback gives every ready worker one turn
    (at most ``BATCH`` messages, then one poll), in the order they became ready, and a worker
    with more work waits for the next round, after the loop's other callbacks. One callback
    for all devices rather than a task each: no task switch and event per message, and a
    burst of a device's messages is fed whole and polled once.

    Under a flood (a round cut short: more than ``ROUND_S`` of work waiting) the next round
    waits as long as the cut one ran (:func:`backend.live.budget.rest_after`): the loop is
    then free at least half the time, so a request needing many loop iterations (an HTTP
    request with database round trips takes ~10) is served in one pause, not one round per
    iteration (2-3 s for ``/api/health`` under an admitted-name flood, issue 21).
    """

    def __init__(self, rest: bool = True) -> None:
        """``rest``: pause after a cut round (a process that serves HTTP). A worker process
        (``rehab worker``) serves no requests: it goes on at once, its pipelines get the
        whole loop."""
        self._rest = rest
        self._ready: dict[DeviceWorker, None] = {}  # an ordered set
        self._handle: asyncio.Handle | None = None
        self._cut = False  # the last round ran out of time
        self.rounds = 0  # rounds run
        self.rests = 0  # pauses after a cut round
        # where a sample waits, for the worker's periodic log (bounded: the newest kept):
        # per turn, the oldest message's wait since its arrival (wall) and the turn's loop time
        self.waits: deque[float] = deque(maxlen=WAITS_KEPT)
        self.turns: deque[float] = deque(maxlen=WAITS_KEPT)

    def ready(self, worker: DeviceWorker) -> None:
        self._ready[worker] = None
        if self._handle is None:
            self._handle = asyncio.get_running_loop().call_soon(self._scheduled)

    def _scheduled(self) -> None:
        self._handle = None
        self._cut = False
        self.run()

    def run(self) -> None:
        """One round now (ingest calls it right after routing a batch). A round holds the
        loop ``ROUND_S`` at most: the workers not reached keep their place for the next,
        which is already scheduled; until it has run, ingest's calls add no round (under a
        flood one round per loop iteration, so a request waits ~ROUND_S per await)."""
        if self._cut and self._handle is not None:
            return
        self._cut = False
        self.rounds += 1
        ready, self._ready = self._ready, {}
        start = time.perf_counter()  # loop time, never seen by a pipeline
        end = start + ROUND_S
        workers = iter(ready)
        turns, t0 = self.turns, start
        for worker in workers:
            worker.turn()
            now = time.perf_counter()
            turns.append(now - t0)
            t0 = now
            if now > end:
                rest = dict.fromkeys(workers)
                self._cut = True
                if rest:
                    self._ready = {**rest, **self._ready}
                if self._ready:  # work left (the rest, or a worker's own next turn)
                    if self._handle is not None:
                        self._handle.cancel()
                    self.rests += 1
                    self._handle = asyncio.get_running_loop().call_later(
                        rest_after(now - start) if self._rest else 0.0, self._scheduled
                    )
                break


class DeviceWorker:
    def __init__(
        self,
        name: str,
        stats: DeviceStats,
        *,
        scheduler: Scheduler,
        prefix: str,
        zio: ZenohIO | None,
        hub: Hub,
        db: DbWriter,
        max_items: int,
        max_bytes: int,
        on_change: Callable[[str], None],
        view: Callable[[], RowsView | None] = lambda: None,
        budget: IngestBudget | None = None,
        on_event: Callable[[str, int, wire.EventMessage, str], None] | None = None,
    ) -> None:
        self.name = name
        self.stats = stats
        self._scheduler = scheduler
        self.prefix = prefix
        self._zio = zio
        self._hub = hub
        self._db = db
        self._max_items = max_items
        self._max_bytes = max_bytes
        self._on_change = on_change
        self._view = view
        self._budget = budget or IngestBudget(max_bytes)  # shared by all devices
        self._on_event = on_event  # device events during a session: audited
        self.live: AnyRun = LiveRun(name, prefix, stats)
        self._queue: deque[RawMessage | Command] = deque()
        self._bytes = 0
        self.poll_due = False
        self.internal_errors = 0
        self.closed = False
        # a worker process's lease (backend.live.lease): nothing is processed, published or
        # written once ``alive()`` is false; database writes carry (device, holder, epoch)
        self.alive: Callable[[], bool] = _always
        self.fence: tuple[str, str, int] | None = None
        self.paused = False  # a takeover replays the recording first; messages wait
        self._attachment: bytes | None = None  # "<holder>:<epoch>" on each estimate put
        self.snapshots: Snapshotter | None = None  # a worker process's (backend.live.snapshot)

    def set_lease(self, holder: str, epoch: int, alive: Callable[[], bool]) -> None:
        self.alive = alive
        self.fence = (self.name, holder, epoch)
        self._attachment = f"{holder}:{epoch}".encode()

    # ------------------------------------------------------------------ producer side

    def close(self) -> None:
        """No more turns (the service is stopping; sessions were finished before)."""
        self.closed = True

    def offer(self, msg: RawMessage) -> None:
        st = self.stats
        st.messages += 1
        st.bytes += msg.size
        st.last_seen = msg.arrival
        if msg.payload is None:
            st.reject("too_large")  # not kept, not recorded: bounded memory and storage
            return
        if (
            len(self._queue) >= self._max_items
            or self._bytes + msg.size > self._max_bytes
            or not self._budget.take(msg.size, self._bytes)
        ):
            st.dropped += 1
            return
        self._queue.append(msg)
        self._bytes += msg.size
        self._scheduler.ready(self)

    def command(self, cmd: Command) -> asyncio.Future[Any]:
        """Commands bypass the bound (they come from the REST layer, not from devices)."""
        self._queue.append(cmd)
        self._scheduler.ready(self)
        return cmd.future

    def request_poll(self) -> None:
        """Timer: poll what was fed but produced no row (e.g. a device sending IMU only)."""
        if self.live.fed_since_poll:
            self.poll_due = True
            self._scheduler.ready(self)

    @property
    def queued(self) -> int:
        return len(self._queue)

    def queued_messages(self) -> list[RawMessage]:
        return [m for m in self._queue if isinstance(m, RawMessage)]

    def recover(self, msgs: list[RawMessage]) -> None:
        """Messages recovered from the device's publication cache (a takeover's gap), in
        front of the queue: they were published before everything waiting in it."""
        st = self.stats
        for m in reversed(msgs):
            st.messages += 1
            st.bytes += m.size
            if not self._budget.take(m.size, self._bytes):
                st.dropped += 1
                continue
            self._queue.appendleft(m)
            self._bytes += m.size
        self._scheduler.ready(self)

    # ------------------------------------------------------------------ a turn

    def turn(self) -> None:
        if self.closed or self.paused:
            return
        if self._queue:
            head = self._queue[0]
            if type(head) is RawMessage:
                self._scheduler.waits.append(time.time() - head.arrival)
        if not self.alive():  # the lease is no longer surely ours: drop, never process
            kept: deque[RawMessage | Command] = deque(
                c for c in self._queue if isinstance(c, Command)
            )
            if len(kept) < len(self._queue):  # a gap in the recording: counted, never silent
                n = len(self._queue) - len(kept)
                self.stats.rejected["lease_paused"] = self.stats.rejected.get("lease_paused", 0) + n
            self._budget.give(self._bytes)
            self._queue = kept
            self._bytes = 0
            return
        try:
            self._step()
            if self.poll_due:
                self.poll_due = False
                if self.live.fed_since_poll:
                    self._emit(self.live.poll())
        except Exception:  # a bug must not stop the device
            self.internal_errors += 1
            self.stats.reject("internal_error")
            if self.internal_errors <= 3:
                log.exception("device %s: worker error", self.name)
        # snapshots are of robot runs (a wearable takeover replays the whole recording)
        if self.snapshots is not None and self.fence is not None and isinstance(self.live, LiveRun):
            try:
                self.snapshots.after_turn(self.live, self.fence[2], self.alive)
            except Exception:  # never the device's data: counted, logged
                self.snapshots.counts["failed"] += 1
                log.exception("device %s: snapshot failed", self.name)
        if self._queue:
            self._scheduler.ready(self)

    def _step(self) -> None:
        n = nbytes = 0
        while self._queue and n < BATCH and nbytes < TURN_BYTES:
            item = self._queue.popleft()
            n += 1
            if isinstance(item, Command):
                self._poll_if_ready()
                self._command(item)
                continue
            self._bytes -= item.size
            self._budget.give(item.size)
            nbytes += item.size
            self._preview_kind(item)
            try:
                decoded = self.live.ingest(item)
                sid = self.live.session_id
                if type(decoded) is wire.EventMessage and sid is not None and self._on_event:
                    self._on_event(self.name, sid, decoded, item.key)
            except Exception:  # recorder I/O and the like: count, keep the device going
                self.internal_errors += 1
                self.stats.reject("internal_error")
                if self.internal_errors <= 3:
                    log.exception("device %s: message not processed", self.name)
        self._poll_if_ready()

    def _preview_kind(self, msg: RawMessage) -> None:
        """A preview follows the device's streams (contract §8: a forearm IMU or a camera
        and no robot is a wearable device); a session keeps its parameters' mode."""
        live = self.live
        if live.session is not None:
            return
        if isinstance(live, LiveRun) and (msg.kind == "camera" or msg.key.endswith("/forearm")):
            self.live = WearableLiveRun(self.name, self.prefix, self.stats)
            self._on_change(self.name)
        elif isinstance(live, WearableLiveRun) and msg.kind == "robot":
            self.live = LiveRun(self.name, self.prefix, self.stats)
            self._on_change(self.name)

    def _poll_if_ready(self) -> None:
        live = self.live
        if isinstance(live, WearableLiveRun):  # its rows are complete as soon as fed
            if live.fed_since_poll:
                self._emit(live.poll())
            return
        # also when samples pile up without rows (an IMU-only flood): one poll then does a
        # bounded amount of work, never seconds of it (same numbers: polls never change them)
        if live.fed_since_poll and (rows_ready(live.pipeline) or live.fed_samples >= POLL_SAMPLES):
            self._emit(live.poll())

    # ------------------------------------------------------------------ outputs

    def _emit(self, out: Output | JointsOut | None) -> None:
        if out is None:
            return
        if isinstance(out, JointsOut):
            self._emit_joints(out)
            return
        live, dev = self.live, self.name
        assert isinstance(live, LiveRun)
        sid = live.session_id
        pubs = self._zio.publishers(dev) if self._zio is not None else None
        if out.n:
            therapist, overlay = self._hub.interest(dev, sid)
            view = self._view()
            if view is not None and view.selected != dev:
                view = None  # only the device on screen: ~85 µs a row is too much for 50
            # the dashboard's columns only when someone looks (a second block cost as much)
            block = feed.estimate_block(out.rows, display=therapist or view is not None)
            if pubs is not None:
                try:
                    pubs.estimate.put(
                        feed.dumps(block.columns(len(feed.CONTRACT_FLOATS))),
                        attachment=self._attachment,
                    )
                except Exception:
                    log.warning("device %s: estimate not published", dev, exc_info=True)
            if therapist or overlay:
                self._hub.rows(
                    dev,
                    sid,
                    block if therapist else None,
                    feed.overlay_block(out.rows) if overlay else None,
                )
            if view is not None:
                view.update(dev, feed.as_rows(block))
            converged = bool(out.rows["heading_converged"][-1])
            if converged != live.converged:
                live.converged = converged
                self._on_change(dev)
            point = live.nominal_change(out)
            if (
                point is not None
                and sid is not None
                and live.nominal_source
                not in (
                    "params",
                    "therapist",  # stored by the sessions API already
                )
            ):
                self._store_nominal(sid, list(point), live.nominal_source)
        index = live.cycle_index
        for fb in out.feedback:
            if pubs is not None:
                try:
                    pubs.feedback.put(wire.dumps(fb))
                except Exception:
                    log.warning("device %s: feedback not published", dev, exc_info=True)
            if fb["type"] == "state":
                self._hub.event(dev, sid, feed.state_message(dev, fb["t"], fb["state"]))
            elif fb["type"] == "cycle":
                self._hub.event(dev, sid, feed.cycle_message(dev, fb, index))
                index += 1
        for v in out.cycles:
            if v.compensatory is None:
                continue
            if sid is not None:
                self._store_cycle(sid, v, live.cycle_index)
            live.cycle_index += 1

    def _emit_joints(self, out: JointsOut) -> None:
        """A wearable run's rows: on ``rehab/<device>/joints`` and to the dashboards."""
        live, dev = self.live, self.name
        if out.rows is None or not out.n or not isinstance(live, WearableLiveRun):
            return
        sid = live.session_id
        pubs = self._zio.publishers(dev) if self._zio is not None else None
        if pubs is not None:
            try:
                pubs.joints.put(
                    wire.joints_payload(out.rows, feed.JOINTS_EXTRA), attachment=self._attachment
                )
            except Exception:
                log.warning("device %s: joints not published", dev, exc_info=True)
        therapist, _ = self._hub.interest(dev, sid)
        if therapist:
            self._hub.rows(dev, sid, feed.joints_block(out.rows), None, kind="joints")
        view = self._view()
        if view is not None and view.selected == dev:
            # the 3D arm from the joint angles
            view.update(dev, feed.joints_view(feed.as_rows(feed.joints_block(out.rows))))
        converged = all(live.sure().values())
        if converged != live.converged:
            live.converged = converged
            self._on_change(dev)

    def _store_cycle(self, sid: int, v: CycleVerdict, index: int) -> None:
        async def op(db: AsyncSession) -> None:
            await record_cycle(
                db,
                sid,
                start=v.start,
                end=v.end,
                outside_fraction=v.outside_fraction,
                compensatory=bool(v.compensatory),
                coverage=_finite(v.coverage),
                peak_displacement_m=_finite(v.max_displacement_m),
                index=index,
            )

        self._db.submit(f"cycle {index} of session {sid}", op, fence=self.fence)

    def _store_nominal(self, sid: int, point: list[float], source: str) -> None:
        async def op(db: AsyncSession) -> None:
            await store_nominal_shoulder(db, sid, point, source)  # type: ignore[arg-type]

        self._db.submit(f"nominal shoulder of session {sid}", op, fence=self.fence)

    # ------------------------------------------------------------------ commands

    def _command(self, cmd: Command) -> None:
        if cmd.future.done():  # the requester gave up (timeout)
            return
        try:
            result: Any = None
            if isinstance(cmd, StartSession):
                self._start(cmd)
            elif isinstance(cmd, StopSession):
                result = self._stop(cmd.session_id)
            elif isinstance(cmd, SetNominal):
                result = self._nominal(cmd)
            elif isinstance(cmd, RomTestCommand):
                result = self._rom_test(cmd)
            else:  # pragma: no cover
                raise TypeError(type(cmd).__name__)
        except Exception as exc:
            cmd.future.set_exception(exc)
        else:
            cmd.future.set_result(result)

    def _start(self, cmd: StartSession) -> None:
        if self.live.session is not None:  # not after the DB's one-active-session rule
            log.error(
                "device %s: session %s replaced by %s",
                self.name,
                self.live.session_id,
                cmd.context.info.id,
            )
            self._stop(self.live.session.info.id)
        self.live = new_run(self.name, self.prefix, self.stats, cmd.context, cmd.files)
        self._on_change(self.name)

    def _stop(self, session_id: int) -> dict[str, Any] | None:
        live = self.live
        if live.session_id != session_id:
            return None
        out, report = live.finish()
        self._emit(out)
        self._hub.flush(self.name)
        assert live.files is not None
        live.files.close(report)
        # a fresh preview, of the same mode
        wearable = live.params if isinstance(live, WearableLiveRun) else None
        self.live = new_run(self.name, self.prefix, self.stats, wearable=wearable)
        self._hub.end_session(session_id)
        self._on_change(self.name)
        return summary_of(report)

    def _rom_test(self, cmd: RomTestCommand) -> dict[str, Any] | None:
        live = self.live
        if live.session_id != cmd.session_id or not isinstance(live, WearableLiveRun):
            raise LiveUnavailable("the device is not running this wearable session")
        result = live.rom_start(cmd.movement) if cmd.movement else live.rom_stop()
        self._on_change(self.name)
        return result

    def _nominal(self, cmd: SetNominal) -> list[float] | None:
        live = self.live
        if live.session_id != cmd.session_id:
            raise LiveUnavailable("the device is not running this session")
        if isinstance(live, WearableLiveRun):
            raise LiveUnavailable("a wearable session has no nominal shoulder")
        result: list[float] | None
        payload: dict[str, Any]
        if cmd.from_estimate:
            result = live.shoulder_estimate()
            if result is None:
                raise LiveUnavailable("no converged shoulder estimate yet")
            payload, source = {"type": "nominal_reset"}, "estimate"
        elif cmd.point is not None:
            result = [float(x) for x in cmd.point]
            payload, source = {"type": "shoulder_reference", "point": result}, "therapist"
        else:
            result = None
            payload, source = {"type": "nominal_reset"}, "auto"
        # into the recording and the pipeline like any event, so re-analysis reproduces it
        data = live.event(payload)
        live.nominal_source = source
        live.nominal = None
        pubs = self._zio.publishers(self.name) if self._zio is not None else None
        if pubs is not None and data is not None:  # independent recorders see it too
            try:
                pubs.event.put(data)
            except Exception:
                log.warning("device %s: event not published", self.name, exc_info=True)
        return result
