"""``rehab worker``: runs the pipelines of the devices it holds a lease on.

A :class:`WorkerNode` is the live manager restricted to its leased devices:

- Zenoh: a subscription to each held device's keys, declared with its lease and undeclared
  when it goes (devices are discovered from the API node's notices on ``<prefix>/@devices``,
  their liveliness tokens, and leases that expired lately); estimates and feedback published
  as before; a liveliness token ``<prefix>/@worker/<id>``; a queryable ``<prefix>/@ctl/*``
  answering the API node's session commands for the devices held (others stay silent); the
  dashboard's messages on ``<prefix>/@feed/<id>`` for the API node's WebSockets.
- Leases (:mod:`backend.live.lease`), renewed every ``RENEW_S``; a device whose lease is
  not surely held stops at once (no processing, publishing or writing).
- The database is the truth about sessions: on taking a device, and every second, the
  worker runs the session the database says is active on it. A session that already has a
  recording is *taken over*: its complete lines are replayed (in a thread) through a fresh
  pipeline into new files, which then replace the old ones; new messages wait meanwhile.
- Back-pressure: a worker whose devices' queues or loop lag show it falling behind, or
  holding ``max_devices``, takes no new lease (its devices stay; others take the new ones).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Iterator, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import zenoh
from sqlalchemy import Engine, func, select
from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.devices import get_device, is_removed
from backend.db.engine import Database
from backend.db.models import Cycle, Device, Patient, Session
from backend.db.sessions import record_cycle
from backend.deps import LiveUnavailable, SessionInfo
from backend.live import files, lease, recovery, snapshot
from backend.live.devices import DeviceStats
from backend.live.ingest import RawMessage
from backend.live.manager import COMMAND_TIMEOUT_S, LiveManager
from backend.live.run import LiveRun, SessionContext, rows_ready, session_params
from backend.live.wearable_run import JointsOut, WearableLiveRun
from backend.live.worker import (
    AnyRun,
    DeviceWorker,
    RomTestCommand,
    SetNominal,
    StartSession,
    StopSession,
    new_run,
)
from backend.settings import Settings
from estimators.output import Output
from estimators.verdicts import CycleVerdict
from estimators.wearable.params import WearableParams
from protocol import keys, recording

log = logging.getLogger(__name__)

RECONCILE_S = 1.0  # sessions of the held devices compared with the database this often
SEEN_S = 2.0  # a device not heard from for this long is no candidate for a lease
LAG_LIMIT_S = 0.1  # the loop this late: falling behind, no new leases
QUEUE_LIMIT = 0.5  # a device queue this full (fraction): falling behind
RECOVER_LINES = 8192  # the recording's newest lines compared with a device's cache
RECOVER_MAX_AGE_S = 30.0  # a device's cached messages older than this are not asked for
FRESH_START_S = 5.0  # a session started by query this recently may not be committed yet
WAITS_LOG_S = 10.0  # the samples' waits are logged this often
# dashboard messages gathered into one put per loop iteration (a scheduler round's rows):
# a timer of 30 ms (the WebSockets' frame) gave the browser frames without news (18
# updates/s, target 20), 5 ms 19-26
FEED_TICK_S = 0.0
TAKE_PER_STEP = 8  # new leases per lease step at most (back-pressure is checked between steps)


# A session start (the API node's body begins so: orjson keeps the dict's order)
START_QUERY = b'{"op":"start"'


class FeedForwarder:
    """Stands in the worker's hub as one dashboard client: the therapist messages of all the
    worker's devices go on Zenoh to the API nodes (which fan them out to their WebSockets),
    gathered for ``FEED_TICK_S`` into one put (messages joined by newlines, which orjson's
    compact JSON never contains). One put per device and row cost the API node a callback,
    a loop wake-up and a decode each (~750 a second per worker at 25 devices)."""

    overlay: tuple[str, int] | None = None
    dropped = 0

    def __init__(self, publisher: zenoh.Publisher) -> None:
        self._pub = publisher
        self._texts: list[bytes] = []
        self._timer: asyncio.TimerHandle | None = None

    def wants(self, device: str, session_id: int | None) -> bool:
        return True

    def send(self, text: str | None) -> None:
        if text is None:
            return
        self._texts.append(text.encode("utf-8"))
        if self._timer is None:
            self._timer = asyncio.get_running_loop().call_later(FEED_TICK_S, self.flush)

    def flush(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        texts, self._texts = self._texts, []
        if texts:
            try:
                self._pub.put(b"\n".join(texts))
            except Exception:
                self.dropped += len(texts)


def _replay_lines(
    path: Path, skip: int = 0, last: deque[bytes] | None = None
) -> Iterator[tuple[str, bytes]]:
    lines: Iterator[bytes] = recording.lines(path)
    if last is not None:  # every line (skipped too) passes through it: the newest stay
        lines = _kept(lines, last)
    for line in itertools.islice(lines, skip, None):
        key, payload = recording.parse(line)
        if key is not None:
            yield key, bytes(payload)


def _kept(lines: Iterator[bytes], last: deque[bytes]) -> Iterator[bytes]:
    for line in lines:
        last.append(line)
        yield line


def replay(
    run: AnyRun, path: Path, prefix: str, skip: int = 0, last: deque[bytes] | None = None
) -> list[tuple[int, CycleVerdict]]:
    """The recording's complete lines through ``run`` (into its files, as received), with
    the bookkeeping a live worker does on its outputs; returns the cycles (index, verdict).
    ``skip``: lines ``run`` has seen already (restored from a snapshot); ``last``: gets the
    recording's newest lines (as many as it holds)."""
    cycles: list[tuple[int, CycleVerdict]] = []

    def absorb(out: Output | None) -> None:
        if out is None or not isinstance(run, LiveRun):
            return
        if out.n:
            run.converged = bool(out.rows["heading_converged"][-1])
            run.nominal_change(out)
        for v in out.cycles:
            if v.compensatory is not None:
                cycles.append((run.cycle_index, v))
                run.cycle_index += 1

    for key, payload in _replay_lines(path, skip, last):
        try:
            kind: str = keys.parse(key, prefix).kind
        except keys.KeyError_:
            kind = "unknown"
        run.ingest(RawMessage(key, payload, len(payload), 0.0, kind))
        if isinstance(run, WearableLiveRun):
            run.poll()  # its rows into the staged joints.csv
        elif run.fed_since_poll and rows_ready(run.pipeline):
            absorb(run.poll())
    if run.fed_since_poll:
        out = run.poll()
        absorb(out if not isinstance(out, JointsOut) else None)
    return cycles


def _cycles_before(run: AnyRun, skip: int) -> list[tuple[int, CycleVerdict]]:
    """The judged cycles a run restored from a snapshot had (index, verdict), rebuilt from
    its report's list, for the database rows its previous holder may not have written."""
    if not skip or not isinstance(run, LiveRun):
        return []
    out = []
    nan = float("nan")
    for i, c in enumerate(run.run.cycles[: run.cycle_index]):
        v = CycleVerdict(
            start=c["start"],
            end=c["end"],
            outside_fraction=c["outside_fraction"],
            compensatory=c["compensatory"],
            coverage=c["coverage"],
            outside_s=nan,
            max_displacement_m=nan if c["max_displacement_m"] is None else c["max_displacement_m"],
            mean_displacement_m=nan
            if c["mean_displacement_m"] is None
            else c["mean_displacement_m"],
        )
        out.append((i, v))
    return out


class WorkerNode(LiveManager):
    SERVES_HTTP = False  # its pipelines get the whole loop (Scheduler)

    def __init__(
        self, settings: Settings, database: Database, max_devices: int = 0, router: bool = False
    ) -> None:
        super().__init__(settings, database)
        if router:  # this machine's router, joined to --zenoh-connect's (router to router)
            self._zio_mode = "router"
        self.held = lease.Held()
        self.max_devices = max_devices  # 0: no limit
        self.seen: dict[str, float] = {}  # device → monotonic time of its last sample
        self.announced: set[str] = set()  # devices with a liveliness token
        self._first_unheld: dict[str, float] = {}
        self.workers_alive: set[str] = set()
        self._stopped: set[int] = set()  # sessions stopped here: never resumed
        self._started_at: dict[int, float] = {}
        self._resuming: dict[str, asyncio.Lock] = {}  # device → its start/takeover
        self._claiming: set[str] = set()  # leases being taken on a session start
        self.lag_s = 0.0
        self.paused_steps = 0  # lease steps that found devices past their local deadline
        self.late_renewals = 0  # renewals answered late or sent late (logged with both)
        self._last_renewal = time.monotonic()
        self.behind = False
        self.takeovers: list[dict[str, Any]] = []  # (device, session, replay seconds)
        self.snapshots = snapshot.Snapshotter(settings.snapshot_every_s)
        self.snapshots_rejected: Counter[str] = Counter()  # skipped at takeovers, by reason
        self.recovered: Counter[str] = Counter()  # messages recovered from devices' caches
        self._token: Any = None
        self._extra: list[Any] = []
        self._feed_pub: zenoh.Publisher | None = None
        self._feed: FeedForwarder | None = None
        self._stop_leases = threading.Event()
        self._lease_thread: threading.Thread | None = None

    # ------------------------------------------------------------------ Zenoh

    def _accept(self, key: str) -> bool:
        """Zenoh's receiving thread: only the held devices' inputs go further (what was
        still in a dropped device's channel stops here)."""
        try:
            pk = keys.parse(key, self.prefix)
        except keys.KeyError_:
            return True  # counted as unknown by the ingest
        return pk.kind in keys.INPUT_KINDS and pk.device in self.held.epochs

    def _noticed(self, payload: bytes) -> None:
        """The API node's list of the devices it heard: candidates for a lease."""
        try:
            names = orjson.loads(payload)
        except orjson.JSONDecodeError:
            return
        if not isinstance(names, list):
            return
        now = time.monotonic()
        for name in names:
            if isinstance(name, str) and keys.DEVICE_RE.fullmatch(name):
                self.seen[name] = now

    async def start(self, require_zenoh: bool = True) -> None:
        self._zio_accept = self._accept
        self._zio_per_device = True  # subscribed to a device's keys while holding it
        await super().start(require_zenoh=require_zenoh)
        self.stats.clear()  # only the held devices' (added as leases are taken)
        zio = self.zio
        assert zio is not None and zio.session is not None
        s = zio.session
        loop = asyncio.get_running_loop()
        self._token = s.liveliness().declare_token(keys.worker_key(self.prefix, self.held.holder))

        def on_worker(sample: zenoh.Sample) -> None:
            holder = str(sample.key_expr).rsplit("/", 1)[-1]
            alive = sample.kind == zenoh.SampleKind.PUT
            loop.call_soon_threadsafe(self._worker_seen, holder, alive)

        self._extra.append(
            s.liveliness().declare_subscriber(
                keys.worker_key(self.prefix, "*"), on_worker, history=True
            )
        )

        def on_query(query: zenoh.Query) -> None:
            device = str(query.key_expr).rsplit("/", 1)[-1]
            payload = query.payload.to_bytes() if query.payload is not None else b"{}"
            if device not in self.held.epochs and not payload.startswith(START_QUERY):
                return  # not ours: the query ends without a reply from us
            # a start for a device nobody may hold yet: this worker tries to take it
            loop.call_soon_threadsafe(self._control, query, device, payload)

        self._extra.append(s.declare_queryable(keys.control_key(self.prefix), on_query))

        def on_notice(sample: zenoh.Sample) -> None:
            loop.call_soon_threadsafe(self._noticed, sample.payload.to_bytes())

        self._extra.append(s.declare_subscriber(keys.devices_notice(self.prefix), on_notice))
        self._feed_pub = s.declare_publisher(
            keys.feed_key(self.prefix, self.held.holder),
            congestion_control=zenoh.CongestionControl.DROP,
        )
        self._feed = FeedForwarder(self._feed_pub)
        self.hub.clients.add(self._feed)  # type: ignore[arg-type]
        self._tasks.append(asyncio.create_task(self._measure_lag(), name="worker-lag"))
        self._lease_thread = threading.Thread(
            target=self._keep_leases, args=(loop,), name="leases", daemon=True
        )
        self._lease_thread.start()
        self._tasks.append(asyncio.create_task(self._reconcile_loop(), name="worker-sessions"))
        self._tasks.append(asyncio.create_task(self._log_waits(), name="worker-waits"))
        log.info("worker %s started", self.held.holder)

    def _worker_seen(self, holder: str, alive: bool) -> None:
        if alive:
            self.workers_alive.add(holder)
        else:
            self.workers_alive.discard(holder)

    async def close(self) -> None:
        """A clean stop: files flushed (sessions stay active), leases released at once, so
        another worker takes the devices over and continues their sessions."""
        self._stop_leases.set()
        if self._lease_thread is not None:
            await asyncio.to_thread(self._lease_thread.join, 10)
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        for name, w in self.workers.items():
            if w.live.files is not None and self.held.valid(name):
                w.live.files.flush()
            w.close()
            self.held.drop(name)
        self.workers.clear()
        try:
            async with self.database.transaction() as db:
                await lease.release(db, self.held.holder)
        except Exception:
            log.exception("leases not released (they expire in %.1f s)", lease.TTL_S)
        await self.db.close()
        for x in self._extra:
            x.undeclare()
        if self._feed is not None:
            self._feed.flush()
        if self._feed_pub is not None:
            self._feed_pub.undeclare()  # type: ignore[no-untyped-call]
        if self._token is not None:
            self._token.undeclare()
        self.hub.clients.clear()
        if self.zio is not None:
            zio, self.zio = self.zio, None
            await asyncio.to_thread(zio.close)

    # ------------------------------------------------------------------ devices

    def _worker_for(self, name: str) -> DeviceWorker | None:
        if name not in self.held.epochs:
            return None
        w = self.workers.get(name)
        if w is None:
            w = super()._worker_for(name)
            if w is not None:
                w.set_lease(self.held.holder, self.held.epochs[name], lambda: self.held.valid(name))
                w.snapshots = self.snapshots
        return w

    def _device_stats(self, name: str) -> DeviceStats | None:
        if name not in self.held.epochs:
            return None  # another worker's device: its holder reports it
        return super()._device_stats(name)

    def _on_token(self, device: str, alive: bool) -> None:
        # an announced device is leased before its first message (which a session records)
        (self.announced.add if alive else self.announced.discard)(device)
        if device in self.held.epochs:
            super()._on_token(device, alive)

    def _touch(self, names: Sequence[str], offline: bool = False) -> None:
        mine = [n for n in names if n in self.held.epochs and n in self.stats]
        if mine:
            super()._touch(mine, offline)

    def _falling_behind(self) -> bool:
        if self.max_devices and len(self.held.epochs) >= self.max_devices:
            return True
        if self.lag_s > LAG_LIMIT_S:
            return True
        limit = self.settings.ingest_queue_size * QUEUE_LIMIT
        try:
            return any(w.queued > limit for w in list(self.workers.values()))
        except RuntimeError:  # the loop changed the dict meanwhile: ask again next step
            return True

    async def _log_waits(self) -> None:
        """Every ``WAITS_LOG_S``, where the samples waited (docs/scaling.md): in the device
        queues (arrival in the receiving thread to the device's turn) and the turns' loop
        time, and the snapshots taken on a turn."""
        sched = self.scheduler
        while True:
            await asyncio.sleep(WAITS_LOG_S)
            waits, turns = np.array(sched.waits), np.array(sched.turns)
            sched.waits.clear()
            sched.turns.clear()
            if not len(waits) or not len(turns):
                continue
            w = np.percentile(waits, [50, 99]) * 1e3
            t = np.percentile(turns, [50, 99]) * 1e3
            taken = self.snapshots.taken_s
            log.info(
                "last %.0f s: %d turns, queue wait p50 %.1f p99 %.1f max %.1f ms; turn p50 %.2f"
                " p99 %.1f max %.1f ms; loop lag %.0f ms; %d snapshots taken (max %.1f ms)",
                WAITS_LOG_S,
                len(turns),
                w[0],
                w[1],
                waits.max() * 1e3,
                t[0],
                t[1],
                turns.max() * 1e3,
                self.lag_s * 1e3,
                len(taken),
                max(taken, default=0.0) * 1e3,
            )
            taken.clear()

    async def _measure_lag(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            t0 = loop.time()
            await asyncio.sleep(lease.RENEW_S)
            self.lag_s = max(0.0, loop.time() - t0 - lease.RENEW_S)

    # ------------------------------------------------------------------ the lease thread

    def _keep_leases(self, loop: asyncio.AbstractEventLoop) -> None:
        """A thread of its own with a blocking connection: the pipelines keeping the event
        loop busy never delay a renewal (they did, into false expiries, under load)."""
        engine = lease.sync_engine(self.settings.db_url)
        try:
            while not self._stop_leases.wait(lease.RENEW_S):
                try:
                    self._lease_step(engine, loop)
                except Exception as exc:  # the database is away: self-expiry will act
                    log.warning("lease renewal failed: %s", exc)
                # A lease past its local deadline is paused, not dropped: the device's
                # turns stop (no processing, publishing or writing) until a renewal the
                # database grants again (the row was still ours), or the database says it
                # moved on (then it is lost). Dropping at once made every slow moment on
                # a loaded machine a takeover, and each takeover's replay more load.
                now = time.monotonic()
                late = [n for n in list(self.held.epochs) if not self.held.valid(n, now)]
                if late:
                    self.paused_steps += 1
        finally:
            engine.dispose()

    def _to_loop(self, loop: asyncio.AbstractEventLoop, fn: Any, *args: Any) -> None:
        with contextlib.suppress(RuntimeError):  # the loop closed: the worker is stopping
            loop.call_soon_threadsafe(fn, *args)

    def _lease_step(self, engine: Engine, loop: asyncio.AbstractEventLoop) -> None:
        holder = self.held.holder
        mine = list(self.held.epochs)
        sent_mono, sent_wall = time.monotonic(), time.time()
        with engine.begin() as conn:
            kept = lease.renew_sync(conn, holder, sent_wall) if mine else {}
            rows = lease.table_sync(conn)  # to try only the free ones: a read, not a write each
        # what a lost lease needs to be explained: the database's answer late (a writer
        # holding the lock), or this thread late to ask (the process starved of CPU)
        took, gap = time.monotonic() - sent_mono, sent_mono - self._last_renewal
        self._last_renewal = sent_mono
        if mine and (took > lease.RENEW_S or gap > lease.TTL_S - lease.MARGIN_S):
            self.late_renewals += 1
            log.warning(
                "lease renewal late: answered in %.3f s, %.3f s after the previous one",
                took,
                gap,
            )
        for name in mine:
            epoch = self.held.epochs.get(name)
            if epoch is None:
                continue
            if kept.get(name) != epoch:
                self._to_loop(loop, self._lose, name, "lease not renewed")
            else:
                self.held.renewed(name, epoch, sent_mono)
        # rows of ours no longer held here (dropped by the loop): let them go now
        stray = [d for d in kept if d not in self.held.epochs and d not in self._claiming]
        if stray:
            with engine.begin() as conn:
                lease.release_sync(conn, holder, stray)
        self.behind = self._falling_behind()
        if self.behind:
            return
        now = time.monotonic()
        workers = sorted(self.workers_alive | {holder})
        for name in list(self.announced - self.seen.keys()):
            self.seen[name] = now
        # a lease that expired lately (its holder died or was cut off) is a candidate
        # without the API node's notice: failover does not depend on that node
        for name, (was, _, expires) in rows.items():
            if was and sent_wall - SEEN_S < expires <= sent_wall and name not in self.seen:
                self.seen[name] = now
        room = TAKE_PER_STEP
        if self.max_devices:
            room = min(room, self.max_devices - len(self.held.epochs))
        want: list[str] = []
        for name, last in list(self.seen.items()):
            if name in self.held.epochs:
                self._first_unheld.pop(name, None)
                continue
            if now - last > SEEN_S and name not in self.announced:
                self.seen.pop(name, None)
                self._first_unheld.pop(name, None)
                continue
            first = self._first_unheld.setdefault(name, now)
            row = rows.get(name)
            if row is not None and row[2] > sent_wall:
                continue  # held by another
            if now - first < lease.rank(name, holder, workers) * lease.RANK_DELAY_S:
                continue
            if len(want) < room:
                want.append(name)
        if not want:
            return
        # One transaction for all: each one of its own waited for the write lock in turn,
        # and a step taking many devices delayed the next renewal of the held ones past
        # their expiry (measured: 3.3 s between two renewals at 50 devices).
        sent_mono, sent_wall = time.monotonic(), time.time()
        with engine.begin() as conn:
            taken = {name: lease.acquire_sync(conn, name, holder, sent_wall) for name in want}
        for name, epoch in taken.items():
            if epoch is not None:
                self.held.granted(name, epoch, sent_mono)
                self._to_loop(loop, self._gain, name)

    def _gain(self, name: str) -> None:
        if name not in self.held.epochs:
            return  # lost again meanwhile
        # what it sent between its first notice here and the subscription went to no
        # pipeline (docs/scaling.md, "Device discovery"): that wait is logged
        first = self._first_unheld.pop(name, None)
        log.info(
            "device %s: lease taken (epoch %d, %.2f s after this worker first noticed it)",
            name,
            self.held.epochs[name],
            0.0 if first is None else time.monotonic() - first,
        )
        if self.zio is not None:  # its data from now on (before a start query's answer)
            self.zio.subscribe_device(name)
        self._worker_for(name)
        if name in self.announced:  # its token came before the lease: online by it, as in
            super()._on_token(name, True)  # the one process (not only while data flows)
        asyncio.get_running_loop().create_task(self._reconcile([name]))

    def _lose(self, name: str, why: str) -> None:
        if name not in self.held.epochs and name not in self.workers:
            return  # already done
        log.warning("device %s: %s; stopped here", name, why)
        self.held.drop(name)
        if self.zio is not None:
            self.zio.unsubscribe_device(name)
        self.stats.pop(name, None)
        w = self.workers.pop(name, None)
        if w is not None:
            w.close()
            if w.live.files is not None:
                w.live.files.abandon()

    # ------------------------------------------------------------------ sessions

    async def _reconcile_loop(self) -> None:
        while True:
            await asyncio.sleep(RECONCILE_S)
            try:
                await self._reconcile(list(self.held.epochs))
            except Exception:
                log.exception("sessions not reconciled with the database")

    async def _reconcile(self, names: Sequence[str]) -> None:
        """Run on each held device the session the database says is active on it."""
        if not names:
            return
        async with self.database.session() as db:
            rows = (
                await db.execute(
                    select(Session, Device.name, Patient.code)
                    .join(Device, Session.device_id == Device.id)
                    .join(Patient, Session.patient_id == Patient.id)
                    .where(Session.status == "active", Device.name.in_(list(names)))
                )
            ).all()
        active = {name: (s, code) for s, name, code in rows}
        for name in names:
            w = self.workers.get(name)
            busy = self._resuming.get(name)
            if w is None or (busy is not None and busy.locked()) or not self.held.valid(name):
                continue
            running = w.live.session_id
            want = active.get(name)
            if want is not None and want[0].id != running and want[0].id not in self._stopped:
                s, code = want
                info = SessionInfo(
                    id=s.id,
                    device=name,
                    patient_id=s.patient_id,
                    params=s.params,
                    started_at=s.started_at,
                    recording_path=s.recording_path,
                )
                await self._take_session(w, info, code)
            elif (
                want is None
                and running is not None
                and time.monotonic() - self._started_at.get(running, 0.0) > FRESH_START_S
            ):
                log.warning("device %s: session %s is no longer active; ended", name, running)
                await self._stop(w, running)

    async def _take_session(self, w: DeviceWorker, info: SessionInfo, patient: str | None) -> None:
        """Start (or take over) ``info`` on ``w``, once: the query of the API node and the
        reconciliation with the database may both ask for it."""
        lock = self._resuming.get(w.name)
        if lock is None:
            lock = self._resuming[w.name] = asyncio.Lock()
        async with lock:  # a second asker waits for the first: answered once it runs
            await self._start_or_resume(w, info, patient)

    async def _start_or_resume(
        self, w: DeviceWorker, info: SessionInfo, patient: str | None
    ) -> None:
        if w.live.session_id == info.id:
            return
        params = session_params(dict(info.params))
        context = SessionContext(info, params, patient)
        path = self.settings.data_dir / files.recording_relpath(info.id)
        if not path.exists():
            session_files = files.SessionFiles(
                self.settings.data_dir, info.id, csv=files.csv_of(params)
            )
            await asyncio.wait_for(w.command(StartSession(context, session_files)), 30)
            self._started_at[info.id] = time.monotonic()
            return
        await self._resume(w, context, path)

    async def _resume(self, w: DeviceWorker, context: SessionContext, path: Path) -> None:
        """Takeover: replay the recording into new files, then go on from there."""
        name, sid = w.name, context.info.id
        epoch = self.held.epochs[name]
        w.paused = True
        t0 = time.monotonic()
        history = self._cache_history(name)
        last: deque[bytes] = deque(maxlen=RECOVER_LINES)
        recovered = 0
        try:
            if isinstance(context.params, WearableParams):  # snapshots: robot runs only
                staged = files.SessionFiles(
                    self.settings.data_dir,
                    sid,
                    staging=f"epoch{epoch}",
                    csv=files.csv_of(context.params),
                )
                fresh = new_run(name, self.prefix, DeviceStats(name), context, staged)
                ready = snapshot.Prepared(fresh, staged, 0, None)
            else:
                ready = await asyncio.to_thread(
                    snapshot.prepare,
                    self.settings.data_dir,
                    context,
                    name,
                    self.prefix,
                    f"epoch{epoch}",
                    self.snapshots_rejected,
                )
            run, staged = ready.run, ready.files
            try:
                cycles = await asyncio.to_thread(replay, run, path, self.prefix, ready.skip, last)
            except BaseException:
                log.exception("device %s: replay of session %s failed", name, sid)
                staged.close(None)  # the next attempt starts its staged files afresh
                raise
            if not self.held.valid(name) or self.held.epochs.get(name) != epoch:
                # lost, or paused past its local deadline (renewals late under load): a
                # later attempt, at this epoch or another, starts its staged files afresh
                staged.close(None)
                return
            staged.promote()
            run.stats = w.stats
            w.live = run
            if history is not None:
                recovered = await self._recover_gap(w, history, last)
                history = None
            self._started_at[sid] = time.monotonic()
            self._store_missing_cycles(w, sid, _cycles_before(run, ready.skip) + cycles)
        finally:
            if history is not None:  # given up: the subscriber goes all the same
                with contextlib.suppress(Exception):
                    await asyncio.to_thread(history.close)
            w.paused = False
            self.scheduler.ready(w)
        seconds = time.monotonic() - t0
        self.takeovers.append(
            {
                "device": name,
                "session": sid,
                "replay_s": round(seconds, 3),
                "snapshot": ready.snapshot.name if ready.snapshot else None,
                "skipped_lines": ready.skip,
                "recovered": recovered,
            }
        )
        log.warning(
            "device %s: session %s taken over (%s, %d messages from its cache, in %.2f s)",
            name,
            sid,
            f"from snapshot {ready.snapshot.name}" if ready.snapshot else "whole recording",
            recovered,
            seconds,
        )
        self.changed(name)

    def _cache_history(self, name: str) -> recovery.CacheHistory | None:
        """The device's publication cache, queried now (none: an empty history)."""
        zio = self.zio
        if zio is None or zio.session is None:
            return None
        try:
            return recovery.CacheHistory(zio.session, self.prefix, name, RECOVER_MAX_AGE_S)
        except Exception:
            log.warning("device %s: publication cache not queried", name, exc_info=True)
            return None

    async def _recover_gap(
        self, w: DeviceWorker, history: recovery.CacheHistory, last: deque[bytes]
    ) -> int:
        """The messages of the takeover gap that the device's cache still holds, in front
        of the device's queue; returns how many."""
        wait = recovery.MIN_WAIT_S - (time.monotonic() - history.opened)
        if wait > 0:
            await asyncio.sleep(wait)
        samples = await asyncio.to_thread(history.close)
        recorded = []
        for line in last:
            key, payload = recording.parse(line)
            if key is not None:
                recorded.append((key, bytes(payload)))
        missing = recovery.gap(samples, recorded, w.queued_messages(), self.prefix)
        if missing:
            w.recover(missing)
            self.recovered[w.name] += len(missing)
        return len(missing)

    def _store_missing_cycles(
        self, w: DeviceWorker, sid: int, cycles: list[tuple[int, CycleVerdict]]
    ) -> None:
        async def op(db: AsyncSession) -> None:
            stored = await db.scalar(
                select(func.count()).select_from(Cycle).where(Cycle.session_id == sid)
            )
            for index, v in cycles:
                if index >= (stored or 0):
                    await record_cycle(
                        db,
                        sid,
                        start=v.start,
                        end=v.end,
                        outside_fraction=v.outside_fraction,
                        compensatory=bool(v.compensatory),
                        coverage=v.coverage if v.coverage == v.coverage else None,
                        peak_displacement_m=v.max_displacement_m
                        if v.max_displacement_m == v.max_displacement_m
                        else None,
                        index=index,
                    )

        self.db.submit(f"cycles of session {sid} after takeover", op, fence=w.fence)

    async def _stop(self, w: DeviceWorker, sid: int) -> dict[str, Any] | None:
        self._stopped.add(sid)
        summary: dict[str, Any] | None = await asyncio.wait_for(
            w.command(StopSession(sid)), COMMAND_TIMEOUT_S
        )
        return summary

    # ------------------------------------------------------------------ control queries

    def _control(self, query: zenoh.Query, device: str, payload: bytes) -> None:
        asyncio.get_running_loop().create_task(self._answer(query, device, payload))

    async def _claim(self, device: str) -> bool:
        """Take ``device``'s lease now if it is free: a session is starting on a device that
        has announced itself but sent nothing yet (or not for long), so that its first
        messages find a holder with the session running. Every worker that is not falling
        behind tries; the database's conditional update picks one."""
        if device in self.held.epochs:
            return True
        if self.behind:
            return False
        if not self.admission.allows(device):  # a registry row is an admission (an admin's)
            async with self.database.session() as db:
                row = await get_device(db, device)
            if row is None or is_removed(row):
                return False
            self.admission.admit(device)
        sent_mono, sent_wall = time.monotonic(), time.time()
        # until granted here, the lease thread must not take the new row for a stray one
        self._claiming.add(device)
        try:
            async with self.database.transaction() as db:
                epoch = await lease.acquire(db, device, self.held.holder, sent_wall)
            if epoch is not None and device not in self.held.epochs:
                self.held.granted(device, epoch, sent_mono)
                self._gain(device)
        except Exception:
            log.warning("device %s: lease not taken", device, exc_info=True)
            return False
        finally:
            self._claiming.discard(device)
        return device in self.held.epochs

    async def _answer(self, query: zenoh.Query, device: str, payload: bytes) -> None:
        if device not in self.held.epochs and not await self._claim(device):
            query.drop()  # type: ignore[no-untyped-call]  # another worker's: no reply
            return
        try:
            result = await self._command(device, orjson.loads(payload))
            reply: dict[str, Any] = {"ok": True, "result": result}
        except LiveUnavailable as exc:
            reply = {"ok": False, "error": str(exc)}
        except Exception as exc:
            log.exception("device %s: command failed", device)
            reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
        try:
            query.reply(query.key_expr, orjson.dumps(reply, option=orjson.OPT_SERIALIZE_NUMPY))
        except Exception:
            log.warning("device %s: command answered too late", device, exc_info=True)
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    async def _command(self, device: str, msg: dict[str, Any]) -> Any:
        w = self._worker_for(device)
        if w is None or not self.held.valid(device):
            raise LiveUnavailable("this worker no longer holds the device")
        op = msg["op"]
        if op == "start":
            s = msg["session"]
            info = SessionInfo(
                id=s["id"],
                device=device,
                patient_id=s["patient_id"],
                params=s["params"],
                started_at=datetime.fromisoformat(s["started_at"]),
                recording_path=s.get("recording_path"),
            )
            self._stopped.discard(info.id)
            await self._take_session(w, info, msg.get("patient"))
            return files.recording_relpath(info.id)
        if op == "stop":
            if w.live.session_id != msg["session_id"]:
                self._stopped.add(msg["session_id"])
                return None
            return await self._stop(w, msg["session_id"])
        if op == "nominal":
            return await asyncio.wait_for(
                w.command(SetNominal(msg["session_id"], msg["point"], msg["from_estimate"])),
                COMMAND_TIMEOUT_S,
            )
        if op == "report":  # a running session's report so far (exports, the dashboard)
            return await self.live_report(msg["session_id"], device)
        if op == "flush":  # its files as of now (exports of a running session)
            await self.flush_session(msg["session_id"], device)
            return None
        if op == "rom":
            return await asyncio.wait_for(
                w.command(RomTestCommand(msg["session_id"], msg.get("movement"))),
                COMMAND_TIMEOUT_S,
            )
        raise ValueError(f"unknown command {op!r}")


async def run_worker(settings: Settings, max_devices: int = 0, router: bool = False) -> None:
    """The worker's life: database (migrated by the API node, checked here), Zenoh, leases,
    until SIGTERM/SIGINT."""
    import gc
    import signal

    database = Database(settings.db_url)
    await database.migrate()  # idempotent: a worker may start before the API node
    node = WorkerNode(settings, database, max_devices, router)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    await node.start(require_zenoh=True)
    # What start-up made (modules, compiled code, the Zenoh and database stacks) is never
    # freed: out of the collector's sight, a full collection pauses 20-40 ms instead of
    # 120-160 ms at 50 devices, and p50 publication-to-estimate went 16 -> 10 ms
    # (docs/benchmarks.md, Scale-out).
    gc.freeze()
    try:
        await stop.wait()
    finally:
        await node.close()
        await database.dispose()
