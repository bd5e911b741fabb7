"""The live side of the service: implements :class:`backend.deps.LiveHooks`.

Owns the Zenoh session, the device workers, the WebSocket hub and the live database
writes. Opened by the app's lifespan after storage, closed before it (finishing running
sessions, so their files are complete and their report is written).
"""

from __future__ import annotations

import asyncio
import logging
import sys
import time
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.devices import (
    get_device,
    is_removed,
    mark_device_offline,
    registered_devices,
    remove_device,
    touch_devices,
)
from backend.db.engine import Database
from backend.db.models import Cycle, Patient, Session
from backend.db.sessions import get_session, record_cycle, stop_session
from backend.deps import LiveUnavailable, Point, SessionInfo
from backend.live import feed, files, warmup
from backend.live.admission import Admission
from backend.live.budget import IngestBudget
from backend.live.device_audit import EventAuditor
from backend.live.devices import DeviceStats
from backend.live.hub import Client, Hub, dumps
from backend.live.ingest import MAX_PAYLOAD_BYTES, Ingest
from backend.live.memory import TRIM_EVERY_S, release_free_memory
from backend.live.run import LiveRun, SessionContext, session_params
from backend.live.store import DbWriter
from backend.live.wearable_run import WearableLiveRun
from backend.live.worker import (
    Command,
    DeviceWorker,
    RomTestCommand,
    RowsView,
    Scheduler,
    SetNominal,
    StartSession,
    StopSession,
    summary_of,
)
from backend.live.zenoh_io import RawSample, ZenohIO
from backend.schemas.live import OverlayStatusMsg, StatusMsg
from backend.settings import Settings
from estimators.params import PipelineParams
from estimators.pipeline import Pipeline
from protocol.zenoh_config import make_config

log = logging.getLogger(__name__)

MAX_DEVICES = 1000  # a flood of invented device names must not grow memory without bound
# The GIL switch interval of a process whose one loop carries everything (HTTP, ingest and
# every pipeline: `rehab demo`, `--single-process`). There the loop holds the GIL nearly all
# the time, and Zenoh's receive thread waited up to Python's 5 ms for it on every burst (tens
# of milliseconds on p99). A worker and the API node keep Python's default: measured without
# a difference (docs/scaling.md, "What the single loop forced").
SWITCH_INTERVAL_S = 0.0005
TICK_S = 0.25  # the ticker: each session's files flushed to the OS (a kill -9 loses < 1 s)
COMMAND_TIMEOUT_S = 30.0
DEVICE_QUEUE_BYTES = 32 << 20


class LiveManager:
    # the process answers HTTP: a flood's rounds leave the loop free half the time
    SERVES_HTTP = True
    RUNS_PIPELINES = True  # the API node of the workers mode runs none

    def __init__(
        self, settings: Settings, database: Database, interrupted: Sequence[int] = ()
    ) -> None:
        self.settings = settings
        self.database = database
        self.prefix = settings.key_prefix
        self.hub = Hub(settings.ws_max_rate_hz, settings.ws_queue_size)
        self.db = DbWriter(database)
        self.ingest = Ingest(self.prefix, self._worker_for)
        self.admission = Admission(settings.admit)  # names beyond it cost nothing persistent
        self.budget = IngestBudget(settings.ingest_max_bytes)  # all devices' queues together
        self.audit_events = EventAuditor(self.db, authenticated=settings.zenoh_config is not None)
        self.scheduler = Scheduler(rest=self.SERVES_HTTP)
        self.zio: ZenohIO | None = None
        self.zenoh_error: str | None = None
        self.stats: dict[str, DeviceStats] = {}
        self.workers: dict[str, DeviceWorker] = {}
        self._interrupted = list(interrupted)
        self._tasks: list[asyncio.Task[None]] = []
        self._dropped_logged: dict[str, int] = {}
        self._idle_params = PipelineParams()
        self._idle_status = Pipeline(self._idle_params).status()
        self.viz: Any = None  # the 3D view (backend.viz.Viz), set by the app once created
        # how the Zenoh session is opened (a worker filters keys, an API node takes no data)
        self._zio_accept: Callable[[str], bool] | None = None
        self._zio_subscribe = True
        self._zio_per_device = False  # a worker: a subscription per held device
        self._zio_mode: str | None = None

    # ------------------------------------------------------------------ lifecycle

    async def start(self, require_zenoh: bool = False) -> None:
        if self.RUNS_PIPELINES:
            warmup.load_kernels()  # before any data: not in a device's turn
        self.db.start()
        async with self.database.session() as db:
            for name in await registered_devices(db):
                self.stats[name] = DeviceStats(name)
                self.admission.admit(name)
        s = self.settings
        if s.zenoh_listen or s.zenoh_connect or s.zenoh_config:
            config = make_config(  # a refused set-up raises: the service must not start
                # a router (a worker's, one per machine) listens and joins another router
                listen=s.zenoh_listen
                if self._zio_mode == "router" or not s.zenoh_connect
                else None,
                connect=s.zenoh_connect,
                mode=self._zio_mode,
                file=s.zenoh_config,
                allow_plain=s.zenoh_allow_plain,
            )
            zio = ZenohIO(
                config,
                self.prefix,
                asyncio.get_running_loop(),
                self._on_batch,
                self._on_token,
                MAX_PAYLOAD_BYTES,
                accept=self._zio_accept,
                subscribe=self._zio_subscribe,
                per_device=self._zio_per_device,
            )
            try:
                zio.open()
            except Exception as exc:
                if require_zenoh:
                    raise
                self.zenoh_error = str(exc)
                log.error("Zenoh session not opened, no live data: %s", exc)
            else:
                self.zio = zio
                log.info(
                    "Zenoh: %s %s, keys %s",
                    "connected to" if s.zenoh_connect else "listening on",
                    s.zenoh_connect or s.zenoh_listen,
                    self.prefix,
                )
        self._tasks.append(asyncio.create_task(self._ticker(), name="live-ticker"))
        if self._interrupted:
            self._tasks.append(
                asyncio.create_task(self._recover(self._interrupted), name="live-recover")
            )

        if self.SERVES_HTTP and self.RUNS_PIPELINES:
            sys.setswitchinterval(SWITCH_INTERVAL_S)

    async def close(self) -> None:
        """Finish running sessions (files complete, report written, stored as interrupted:
        the service stopped, not the therapist), then stop everything in reverse."""
        self.viz = None  # closed before us
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        stopped: list[tuple[int, dict[str, Any] | None]] = []
        for w in self.workers.values():
            sid = w.live.session_id
            if sid is not None:
                try:
                    summary = await asyncio.wait_for(w.command(StopSession(sid)), COMMAND_TIMEOUT_S)
                except Exception:
                    log.exception("session %s not finished cleanly", sid)
                    summary = None
                stopped.append((sid, summary))
        for w in self.workers.values():
            w.close()
        self.hub.close_all()
        await self.db.close()
        if stopped:
            async with self.database.transaction() as db:
                for sid, summary in stopped:
                    session = await get_session(db, sid)
                    if session.status == "active":
                        await stop_session(db, session, status="interrupted", summary=summary)
        if self.zio is not None:
            zio, self.zio = self.zio, None
            await asyncio.to_thread(zio.close)

    # ------------------------------------------------------------------ devices

    def _device_stats(self, name: str) -> DeviceStats | None:
        st = self.stats.get(name)
        if st is None:
            if len(self.stats) >= MAX_DEVICES:
                return None
            st = self.stats[name] = DeviceStats(name)
        return st

    def _worker_for(self, name: str) -> DeviceWorker | None:
        w = self.workers.get(name)
        if w is None:
            if not self.admission.allows(name):
                self.admission.refuse(name, time.time())
                return None
            st = self._device_stats(name)
            if st is None:
                self.ingest.count("too_many_devices")
                return None
            w = DeviceWorker(
                name,
                st,
                scheduler=self.scheduler,
                prefix=self.prefix,
                zio=self.zio,
                hub=self.hub,
                db=self.db,
                max_items=self.settings.ingest_queue_size,
                max_bytes=DEVICE_QUEUE_BYTES,
                on_change=self.changed,
                view=self._rows_view,
                budget=self.budget,
                on_event=self.audit_events,
            )
            self.workers[name] = w
            st.last_seen = time.time()
            st.update_online(time.time(), self.settings.device_offline_after_s)
            self._touch([name])  # registered at once: a session can start on it
            self.changed(name)
        return w

    def _on_batch(self, batch: list[RawSample]) -> None:
        """Samples from Zenoh: into their devices' queues, then a turn for each of them in
        the same loop callback."""
        self.ingest.route(batch)
        self.scheduler.run()

    def _rows_view(self) -> RowsView | None:
        viz: RowsView | None = self.viz
        return viz

    def _on_token(self, device: str, alive: bool) -> None:
        if not self.admission.allows(device):
            self.admission.refuse(device, time.time())
            return
        st = self._device_stats(device)
        if st is None:
            self.ingest.count("too_many_devices")
            return
        st.token = alive
        if st.update_online(time.time(), self.settings.device_offline_after_s):
            if st.online:
                self._touch([device])
            else:
                self._mark_offline(device)
            self.changed(device)

    def admit_device(self, name: str) -> None:
        """An administrator admitted ``name``: registered now (a session can start on it)."""
        self.admission.admit(name)
        if self._worker_for(name) is None:
            raise LiveUnavailable(f"device limit ({MAX_DEVICES}) reached")

    def remove_device(self, name: str) -> bool:
        """An administrator removed ``name``: no longer admitted, its live state dropped and
        its registry row deleted (kept, marked removed, if sessions refer to it). False if
        it is running a session. The deletion queues behind the registry's pending writes."""
        w = self.workers.get(name)
        if w is not None and w.live.session_id is not None:
            return False
        self.admission.remove(name)
        if w is not None:
            w.close()
            del self.workers[name]
        self.stats.pop(name, None)

        async def op(db: AsyncSession) -> None:
            await remove_device(db, name)

        self.db.submit(f"removal of device {name}", op)
        return True

    def device_names(self) -> list[str]:
        return sorted(self.stats)

    def _touch(self, names: Sequence[str], offline: bool = False) -> None:
        """Registry rows with their stats snapshot; ``offline``: the last one before the
        device is marked offline (its final counters are kept)."""
        now = time.time()
        snapshot = []
        for n in names:
            st = self.stats[n]
            seen = now if st.token or st.last_seen is None else st.last_seen
            snapshot.append((n, datetime.fromtimestamp(seen, UTC), self._db_stats(n)))

        async def op(db: AsyncSession) -> None:
            await touch_devices(db, snapshot)
            for name, _, _ in snapshot if offline else ():
                await mark_device_offline(db, name)

        self.db.submit(f"registry of {len(names)} device(s)", op)

    def _mark_offline(self, name: str) -> None:
        self._touch([name], offline=True)

    def _db_stats(self, name: str) -> dict[str, Any]:
        st = self.stats[name]
        w = self.workers.get(name)
        out: dict[str, Any] = {"rates_hz": st.rates_hz, "ingest": st.ingest(), "token": st.token}
        out["ingest"]["queued"] = w.queued if w is not None else 0
        if w is not None:
            if isinstance(w.live, WearableLiveRun):
                q = w.live.status()["quality"]
            else:
                q = w.live.pipeline.quality.as_dict()
                q.pop("gaps", None)
            out["quality"] = q
            out["session_id"] = w.live.session_id
        return out

    # ------------------------------------------------------------------ status

    def status(self, name: str) -> tuple[StatusMsg, OverlayStatusMsg, int | None]:
        """(therapist status, overlay status, session id) of one device."""
        st = self.stats[name]
        w = self.workers.get(name)
        sid: int | None = None
        patient: str | None = None
        params = self._idle_params
        run = w.live if w is not None else None
        if w is not None and isinstance(run, WearableLiveRun):
            live_w = run
            pipe = live_w.status()  # its rejections: the decoder's and the tracker's
            sid = live_w.session_id
            patient = live_w.session.patient if live_w.session else None
            ingest = {**st.ingest(), "queued": w.queued}
        elif w is not None and isinstance(run, LiveRun):
            live = run
            params = live.params
            pipe = live.pipeline.status()
            rejected = dict(pipe["quality"]["rejected"])
            for reason, n in live.run.decode_rejected.items():
                rejected[reason] = rejected.get(reason, 0) + n
            pipe["quality"] = {**pipe["quality"], "rejected": dict(sorted(rejected.items()))}
            sid = live.session_id
            patient = live.session.patient if live.session else None
            ingest = {**st.ingest(), "queued": w.queued}
        else:
            pipe = self._idle_status
            ingest = {**st.ingest(), "queued": 0}
        msg = feed.status_message(
            name,
            online=st.online,
            session_id=sid,
            patient=patient,
            pipeline=pipe,
            rates_hz=st.rates_hz,
            ingest=ingest,
            tolerance_m=params.tolerance_m,
            max_outside_fraction=params.max_outside_fraction,
        )
        return msg, feed.overlay_status(msg), sid

    def changed(self, name: str) -> None:
        """Something a dashboard must see now (session, presence, convergence)."""
        if self.hub.clients and name in self.stats:
            msg, omsg, sid = self.status(name)
            self.hub.status(name, sid, msg, omsg)

    def send_initial(self, client: Client) -> None:
        for name in self.device_names():
            msg, omsg, sid = self.status(name)
            if client.wants(name, sid):
                client.send(dumps(omsg if client.overlay is not None else msg))

    async def _ticker(self) -> None:
        n = 0
        while True:
            await asyncio.sleep(TICK_S)
            n += 1
            for w in list(self.workers.values()):
                if w.live.files is not None and w.alive():
                    try:
                        w.live.files.flush()
                    except OSError:
                        log.exception("device %s: session files not flushed", w.name)
            if n % round(1.0 / TICK_S) == 0:
                self._each_second()
            if n % round(TRIM_EVERY_S / TICK_S) == 0:  # a flood's freed payloads, to the OS
                await asyncio.to_thread(release_free_memory)

    def _each_second(self) -> None:
        now, mono = time.time(), time.monotonic()
        online: list[str] = []
        for name, st in self.stats.items():
            st.tick(mono)
            if st.update_online(now, self.settings.device_offline_after_s) and not st.online:
                self._mark_offline(name)
                self.changed(name)
            if st.online:
                online.append(name)
            w = self.workers.get(name)
            if w is not None:
                w.request_poll()
            if self.hub.clients:
                msg, omsg, sid = self.status(name)
                self.hub.status(name, sid, msg, omsg)
        if online:
            self._touch(online)
        dropped = {**self.ingest.counters, "overflow": self.zio.overflow if self.zio else 0}
        if dropped != self._dropped_logged and any(dropped.values()):
            # no device to charge them to: the log is where they show
            log.warning("messages dropped or rejected before any device: %s", dropped)
            self._dropped_logged = dropped

    # ------------------------------------------------------------------ LiveHooks

    async def _patient_code(self, patient_id: int) -> str | None:
        async with self.database.session() as db:
            code = await db.scalar(select(Patient.code).where(Patient.id == patient_id))
        return code

    async def _run(self, worker: DeviceWorker, cmd: Command) -> Any:
        return await asyncio.wait_for(worker.command(cmd), COMMAND_TIMEOUT_S)

    async def session_started(self, session: SessionInfo) -> str | None:
        params = session_params(dict(session.params))
        if not self.admission.allows(session.device):
            # a registry row is an admission (e.g. written by another service instance)
            async with self.database.session() as db:
                row = await get_device(db, session.device)
            if row is None or is_removed(row):
                raise LiveUnavailable("device not admitted")
            self.admission.admit(session.device)
        worker = self._worker_for(session.device)
        if worker is None:
            raise LiveUnavailable("device not admitted, or too many devices")
        context = SessionContext(
            session,
            params,
            await self._patient_code(session.patient_id),
            self.settings.recording_max_bytes,
        )
        session_files = files.SessionFiles(
            self.settings.data_dir, session.id, csv=files.csv_of(params)
        )
        try:
            await self._run(worker, StartSession(context, session_files))
        except BaseException:
            session_files.close(None)
            raise
        if self.viz is not None and isinstance(params, PipelineParams):
            self.viz.configure(
                session.device,
                tolerance_m=params.tolerance_m,
                cuff_to_elbow_m=params.cuff_to_elbow_m,
                imu_to_elbow_m=params.imu_to_elbow_m,
            )
        return session_files.relpath

    async def session_stopped(self, session: SessionInfo) -> dict[str, Any] | None:
        worker = self.workers.get(session.device)
        if worker is None:
            return None
        summary: dict[str, Any] | None = await self._run(worker, StopSession(session.id))
        return summary

    async def set_nominal_shoulder(
        self, session: SessionInfo, point: Point | None, from_estimate: bool
    ) -> Point | None:
        worker = self.workers.get(session.device)
        if worker is None:
            raise LiveUnavailable("no data from the device since the service started")
        pt = None if point is None else [float(x) for x in point]
        result: Point | None = await self._run(worker, SetNominal(session.id, pt, from_estimate))
        return result

    async def rom_test(self, session: SessionInfo, movement: str | None) -> dict[str, Any] | None:
        """Start (``movement``) or stop (None) a ROM test of a running wearable session."""
        worker = self.workers.get(session.device)
        if worker is None:
            raise LiveUnavailable("no data from the device since the service started")
        result: dict[str, Any] | None = await self._run(
            worker, RomTestCommand(session.id, movement)
        )
        return result

    # ------------------------------------------------------------------ exports

    async def session_committed(self, session: SessionInfo) -> None:
        """After the request's commit: nothing more to do here (the start was awaited)."""

    async def live_report(self, session_id: int, device: str) -> dict[str, Any] | None:
        """A running session's report so far (provisional: no final rows, no finish())."""
        w = self.workers.get(device)
        if w is None or w.live.session_id != session_id:
            return None
        if isinstance(w.live, WearableLiveRun):
            return w.live.report()
        report = w.live.run.report()
        report["data_quality"]["other_devices"] = {}
        return report

    def is_running(self, session_id: int, device: str) -> bool:
        w = self.workers.get(device)
        return w is not None and w.live.session_id == session_id

    async def flush_session(self, session_id: int, device: str) -> None:
        w = self.workers.get(device)
        if w is not None and w.live.session_id == session_id and w.live.files is not None:
            if isinstance(w.live, LiveRun):
                w.live.run.format_rows()
            w.live.files.flush()

    # ------------------------------------------------------------------ after a crash

    async def _recover(self, session_ids: Sequence[int]) -> None:
        """Sessions the last run left behind: complete their outputs from the recording,
        then the cycles and summary the database missed."""
        for sid in session_ids:
            try:
                await recover_session(self.database, self.settings.data_dir, sid)
            except Exception:
                log.exception("interrupted session %s not recovered", sid)


async def recover_session(database: Database, data_dir: Path, session_id: int) -> None:
    async with database.session() as db:
        session = await get_session(db, session_id)
        relpath, params, device = session.recording_path, session.params, session.device.name
        have_summary = session.summary is not None
    if relpath is None:
        return
    report = await files.ensure_outputs(files.resolve(data_dir, relpath), params, device)
    if report is None:
        return
    async with database.transaction() as db:
        stored = await db.scalar(
            select(func.count()).select_from(Cycle).where(Cycle.session_id == session_id)
        )
        for index, c in enumerate(report["cycles"]):
            if index >= (stored or 0):
                await record_cycle(
                    db,
                    session_id,
                    start=c["start"],
                    end=c["end"],
                    outside_fraction=c["outside_fraction"],
                    compensatory=bool(c["compensatory"]),
                    coverage=c.get("coverage"),
                    peak_displacement_m=c.get("max_displacement_m"),
                    index=index,
                )
        if not have_summary:
            await db.execute(
                update(Session).where(Session.id == session_id).values(summary=summary_of(report))
            )
    log.info("interrupted session %s: outputs complete", session_id)
