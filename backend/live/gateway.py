"""The API node of a scaled-out service (``rehab serve --workers N``).

It keeps REST, the WebSockets and the device registry (the ``devices`` table the workers
write), and runs no pipeline: devices' data goes to the workers through its Zenoh router.

- Sessions: the REST layer still calls :class:`backend.deps.LiveHooks`; here each call is a
  Zenoh query on ``<prefix>/@ctl/<device>``, answered by the one worker holding the device.
  Without a holder (no data yet), a start still succeeds: the session is in the database and
  the worker that takes the device runs it (workers follow the database every second).
- WebSockets: fed with the dashboard messages the workers publish on ``<prefix>/@feed/*``
  (one put per worker per 30 ms tick, messages joined by newlines),
  like any other Zenoh subscriber.
- Local workers: ``N`` child processes (``rehab worker``), killed with the node.
- Device discovery: workers subscribe only to the devices they hold; this node samples the
  devices' inputs and tells the workers which devices it heard (``<prefix>/@devices``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any, cast

import orjson
import zenoh
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession

from backend.db.base import utcnow
from backend.db.devices import mark_device_offline, touch_devices
from backend.db.engine import Database
from backend.db.models import Device, Session
from backend.db.sessions import get_session, stop_session
from backend.deps import LiveUnavailable, Point, SessionInfo
from backend.live import feed, files, lease
from backend.live.budget import DEVICE_FLOOR_BYTES
from backend.live.hub import Client, dumps
from backend.live.manager import COMMAND_TIMEOUT_S, LiveManager
from backend.live.run import session_params
from backend.schemas.live import StatusMsg
from backend.settings import Settings
from estimators.params import PipelineParams
from protocol import keys

log = logging.getLogger(__name__)

WORKERS_START_S = 60.0
START_RETRY_S = 5.0  # a session start asks for a holder this long (then: workers' reconcile)
START_RETRY_PERIOD_S = 0.1
# The start of a worker's rows message (the hub writes type and device first): enough to
# drop one that nobody on this node watches without decoding its ~20 columns. A message
# that does not match is decoded in full.
ROWS_HEAD = re.compile(rb'\{"type":"(?:estimate|joints)","device":"([^"]+)"')
# Device discovery (docs/scaling.md): the devices' inputs reach this node's subscriptions
# in ring channels of WATCH_RING samples (Zenoh keeps the newest: nothing per message in
# Python), drained every WATCH_S (at 50 devices 64 robot messages span 51 ms, more than a
# device's 40 ms period: every streaming device is in every drain; with many more devices
# a drain is a sample of them); the admitted devices heard within NOTICE_WINDOW_S go to the
# workers on `<prefix>/@devices` every NOTICE_S, and at once when one is new.
WATCH_RING = 64
WATCH_S = 0.25
NOTICE_S = 0.5
NOTICE_WINDOW_S = 1.0


def _die_with_parent() -> None:  # pragma: no cover (runs in the child before exec)
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def local_endpoint(listen: str) -> str:
    """Where a child worker reaches this node's Zenoh listener."""
    proto, _, addr = listen.partition("/")
    host, _, port = addr.rpartition(":")
    if host in ("0.0.0.0", "[::]", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


def worker_command(
    settings: Settings, endpoint: str | None, workers: int = 1
) -> tuple[list[str], dict[str, str]]:
    """A local worker's command line and environment: the node's settings travel in
    ``REHAB_*`` variables (the database URL may hold a password: never on a command line,
    which ``ps`` shows to every user). The ingest budget is the machine's: each of the
    ``workers`` local workers gets its share (each had all of it: N times the budget queued
    under a flood, and as much more memory until the backlog drained)."""
    env = dict(os.environ)
    env.update(
        REHAB_INGEST_MAX_BYTES=str(max(settings.ingest_max_bytes // workers, DEVICE_FLOOR_BYTES)),
        REHAB_DATABASE_URL=settings.database_url or settings.db_url,
        REHAB_DATA_DIR=str(settings.data_dir),
        REHAB_KEY_PREFIX=settings.key_prefix,
        REHAB_ADMIT=json.dumps(list(settings.admit)),
        REHAB_ZENOH_ALLOW_PLAIN="true" if settings.zenoh_allow_plain else "false",
    )
    if settings.database_password_file is not None:
        env["REHAB_DATABASE_PASSWORD_FILE"] = str(settings.database_password_file)
    if settings.zenoh_config is not None:  # the same identity and router as this node
        env["REHAB_ZENOH_CONFIG"] = str(settings.zenoh_config)
    argv = [sys.executable, "-m", "backend.cli", "worker"]
    if endpoint:
        argv += ["--zenoh-connect", endpoint]
    return argv, env


class Gateway(LiveManager):
    RUNS_PIPELINES = False  # the workers do

    def __init__(
        self,
        settings: Settings,
        database: Database,
        interrupted: Sequence[int] = (),
        workers: int = 0,
    ) -> None:
        super().__init__(settings, database, interrupted)
        self._zio_subscribe = False
        self._zio_mode = "router" if not settings.zenoh_connect else None
        self.n_workers = workers
        self.children: list[subprocess.Popen[bytes]] = []
        self.last_status: dict[str, str] = {}
        self.session_of: dict[str, int | None] = {}
        self._feed_sub: Any = None
        self._watch: list[Any] = []
        self._notice_pub: zenoh.Publisher | None = None
        self.heard: dict[str, float] = {}  # device → monotonic time this node last heard it
        self._command: list[str] = []
        self._env: dict[str, str] = {}

    async def start(self, require_zenoh: bool = False) -> None:
        await super().start(require_zenoh=require_zenoh)
        loop = asyncio.get_running_loop()
        if self.zio is not None and self.zio.session is not None:

            def on_feed(sample: zenoh.Sample) -> None:
                loop.call_soon_threadsafe(self._on_feeds, sample.payload.to_bytes())

            self._feed_sub = self.zio.session.declare_subscriber(
                keys.feed_key(self.prefix), on_feed
            )
            self._start_watch(self.zio.session)
        s = self.settings
        # the children join this node's router, or the router this node is a client of
        endpoint = s.zenoh_connect or (local_endpoint(s.zenoh_listen) if s.zenoh_listen else None)
        if self.n_workers and (endpoint or s.zenoh_config) and self.zio is not None:
            self._command, self._env = worker_command(s, endpoint, self.n_workers)
            for _ in range(self.n_workers):
                self.children.append(self._spawn())
            self._tasks.append(asyncio.create_task(self._supervise(), name="workers"))
            await self._wait_for_workers(loop)
            log.info("%d local workers started", self.n_workers)

    async def _wait_for_workers(self, loop: asyncio.AbstractEventLoop) -> None:
        """Ready when the local workers are (their liveliness tokens): a device that
        publishes once the API answers is heard."""
        assert self.zio is not None and self.zio.session is not None
        alive: set[str] = set()
        ready = asyncio.Event()

        def seen(holder: str, up: bool) -> None:
            (alive.add if up else alive.discard)(holder)
            if len(alive) >= self.n_workers:
                ready.set()

        def on_token(sample: zenoh.Sample) -> None:
            up = sample.kind == zenoh.SampleKind.PUT
            loop.call_soon_threadsafe(seen, str(sample.key_expr).rsplit("/", 1)[-1], up)

        sub = self.zio.session.liveliness().declare_subscriber(
            keys.worker_key(self.prefix, "*"), on_token, history=True
        )
        try:
            await asyncio.wait_for(ready.wait(), WORKERS_START_S)
        except TimeoutError:
            log.error(
                "only %d of %d workers up after %.0f s", len(alive), self.n_workers, WORKERS_START_S
            )
        finally:
            sub.undeclare()  # type: ignore[no-untyped-call]

    # ------------------------------------------------------------------ device discovery

    def _start_watch(self, session: zenoh.Session) -> None:
        """Workers subscribe only to the devices they hold, so they learn of the others from
        this node, which every topology has: it samples the devices' inputs and tells the
        workers which it heard. No liveliness token is needed (the contract asks none of a
        device); a token, where a device has one, is heard by the workers directly."""
        for expr in keys.device_inputs(self.prefix):
            self._watch.append(
                session.declare_subscriber(expr, zenoh.handlers.RingChannel(WATCH_RING))
            )
        self._notice_pub = session.declare_publisher(
            keys.devices_notice(self.prefix), congestion_control=zenoh.CongestionControl.DROP
        )
        self._tasks.append(asyncio.create_task(self._watch_devices(), name="device-watch"))

    def _heard_now(self) -> list[str]:
        """Drain the rings: the admitted devices heard since the last call that are new here.
        Names not admitted are counted as pending (as their holder would have); keys
        outside the contract as ``unknown_key`` (both sampled: the rings keep the newest)."""
        now, wall = time.monotonic(), time.time()
        new: list[str] = []
        for sub in self._watch:
            channel = sub.handler
            sample = channel.try_recv()
            while sample is not None:
                try:
                    device = keys.parse(str(sample.key_expr), self.prefix).device
                except keys.KeyError_:
                    self.ingest.count("unknown_key")
                else:
                    if not self.admission.allows(device):
                        self.admission.refuse(device, wall)
                    else:
                        if device not in self.heard:
                            new.append(device)
                        self.heard[device] = now
                sample = channel.try_recv()
        return new

    def _notice(self) -> None:
        """The admitted devices heard within ``NOTICE_WINDOW_S`` to the workers."""
        now = time.monotonic()
        names = []
        for name, t in list(self.heard.items()):
            if now - t > NOTICE_WINDOW_S or not self.admission.allows(name):  # or removed
                del self.heard[name]
            else:
                names.append(name)
        if names and self._notice_pub is not None:
            self._notice_pub.put(orjson.dumps(names))

    async def _watch_devices(self) -> None:
        last = 0.0
        while True:
            await asyncio.sleep(WATCH_S)
            try:
                new = self._heard_now()
                if new:  # registered at once: a session can start on it
                    self._touch(new)
                if new or time.monotonic() - last >= NOTICE_S:
                    last = time.monotonic()
                    self._notice()
            except Exception:
                log.exception("device discovery failed")

    def _spawn(self) -> subprocess.Popen[bytes]:
        return subprocess.Popen(self._command, env=self._env, preexec_fn=_die_with_parent)

    async def _supervise(self) -> None:
        """A local worker that died is started again (its devices moved on meanwhile)."""
        while True:
            await asyncio.sleep(1.0)
            for i, child in enumerate(self.children):
                if child.poll() is not None:
                    log.error("worker %d ended (%s); starting another", child.pid, child.returncode)
                    self.children[i] = self._spawn()

    async def _finish_local_sessions(self) -> None:
        """The node stops with its workers and no other worker would take their devices:
        their sessions end as the one-process service ends them (files complete, report
        written, stored as interrupted). With other workers alive, they take them over."""
        pids = {str(c.pid) for c in self.children if c.poll() is None}
        now = time.time()
        async with self.database.session() as db:
            leases = await lease.table(db)
            rows = (
                await db.execute(
                    select(Session.id, Device.name)
                    .join(Device, Session.device_id == Device.id)
                    .where(Session.status == "active")
                )
            ).all()
        mine = {d for d, (h, _, x) in leases.items() if x > now and h.split("-")[-2] in pids}
        others = any(x > now and h.split("-")[-2] not in pids for h, _, x in leases.values())
        if others or not mine:
            return
        for sid, device in rows:
            if device not in mine:
                continue
            try:
                _, summary = await self._ask(device, {"op": "stop", "session_id": sid})
            except Exception:
                log.exception("session %s not finished cleanly", sid)
                summary = None
            async with self.database.transaction() as db:
                session = await get_session(db, sid)
                if session.status == "active":
                    await stop_session(db, session, status="interrupted", summary=summary)

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        if self.children:
            try:
                await self._finish_local_sessions()
            except Exception:
                log.exception("sessions of the local workers not finished")
        for child in self.children:
            with contextlib.suppress(ProcessLookupError):
                child.send_signal(signal.SIGTERM)
        for child in self.children:
            try:
                await asyncio.to_thread(child.wait, 20)
            except subprocess.TimeoutExpired:
                child.kill()
        self.children.clear()
        if self._feed_sub is not None:
            self._feed_sub.undeclare()
            self._feed_sub = None
        for sub in self._watch:
            sub.undeclare()
        self._watch.clear()
        if self._notice_pub is not None:
            self._notice_pub.undeclare()  # type: ignore[no-untyped-call]
            self._notice_pub = None
        await super().close()

    # ------------------------------------------------------------------ WebSockets

    def _watched(self, device: str) -> bool:
        """A socket of this node or its 3D view wants ``device``'s rows."""
        if self.viz is not None and self.viz.selected == device:
            return True
        sid = self.session_of.get(device)
        return any(c.wants(device, sid) for c in self.hub.clients)

    def _on_feeds(self, batch: bytes) -> None:
        """A worker's batch: its dashboard messages of one tick, joined by newlines."""
        for data in batch.split(b"\n"):
            self._on_feed(data)

    def _on_feed(self, data: bytes) -> None:
        """A worker's dashboard message: to the therapists' sockets as it is; to the
        session's overlays as the one-process hub would send them (their status, their
        columns of the rows); the rows of the device on screen to the 3D view. Rows nobody
        here watches are dropped undecoded."""
        head = ROWS_HEAD.match(data)
        if head is not None and not self._watched(head[1].decode()):
            return
        try:
            msg = orjson.loads(data)
            device = msg["device"]
            kind = msg.get("type")
        except (orjson.JSONDecodeError, KeyError, TypeError):
            return
        text = data.decode("utf-8")
        sid = self.session_of.get(device)
        if kind == "status":
            self.last_status[device] = text
            # overlays close on the stop (session_stopped), not on a status: one without the
            # session may be older than the start, or come from a holder still replaying it
            sid = self.session_of[device] = msg.get("session_id")
        elif kind == "estimate" and self.viz is not None and self.viz.selected == device:
            rows = msg.get("rows")
            if isinstance(rows, dict):
                self.viz.update(device, rows)
        elif kind == "joints" and self.viz is not None and self.viz.selected == device:
            rows = msg.get("rows")
            if isinstance(rows, dict):
                self.viz.update(device, feed.joints_view(rows))
        otext: str | None = None
        for c in list(self.hub.clients):
            if not c.wants(device, sid):
                continue
            if c.overlay is None:
                c.send(text)
                continue
            if otext is None:
                otext = self._overlay_text(msg, text)
            if otext:
                c.send(otext)

    @staticmethod
    def _overlay_text(msg: dict[str, Any], text: str) -> str:
        """What an overlay gets of a therapist message ("" for nothing)."""
        kind = msg.get("type")
        if kind in ("state", "cycle"):
            return text
        if kind == "status":
            return dumps(feed.overlay_status(cast(StatusMsg, msg)))  # a worker built it
        if kind == "estimate":
            rows = msg.get("rows")
            cols = feed.overlay_columns(rows) if isinstance(rows, dict) else None
            if cols is not None:
                return dumps({"type": "estimate", "device": msg["device"], "rows": cols})
        return ""

    def send_initial(self, client: Client) -> None:
        for name, text in sorted(self.last_status.items()):
            if client.wants(name, self.session_of.get(name)):
                if client.overlay is None:
                    client.send(text)
                else:
                    client.send(dumps(feed.overlay_status(orjson.loads(text))))

    def device_names(self) -> list[str]:
        return sorted(set(self.stats) | set(self.last_status))

    def changed(self, name: str) -> None:
        pass  # the workers send the statuses

    def _touch(self, names: Sequence[str], offline: bool = False) -> None:
        """Devices announced by a liveliness token are registered here (a session can
        start on them before their data flows); their statistics are their holder's."""
        seen = utcnow()
        names = list(names)

        async def op(db: AsyncSession) -> None:
            await touch_devices(db, [(name, seen, None) for name in names])
            for name in names if offline else ():
                await mark_device_offline(db, name)

        self.db.submit(f"registry of {len(names)} device(s)", op)

    def _each_second(self) -> None:
        pass

    def admit_device(self, name: str) -> None:
        """Admitted and registered; no pipeline here (a worker leases it when a session
        starts on it or its data comes, and admits it by its registry row)."""
        self.admission.admit(name)
        self._touch([name])

    # ------------------------------------------------------------------ LiveHooks

    def _query(self, device: str, body: dict[str, Any]) -> dict[str, Any] | None:
        session = self.zio.session if self.zio is not None else None
        if session is None:
            raise LiveUnavailable("no Zenoh session")
        replies = session.get(
            keys.control_key(self.prefix, device),
            payload=orjson.dumps(body),
            target=zenoh.QueryTarget.ALL,
            timeout=COMMAND_TIMEOUT_S,
        )
        for reply in replies:
            if reply.ok is not None:
                answer: dict[str, Any] = orjson.loads(reply.ok.payload.to_bytes())
                return answer
        return None

    async def _ask(self, device: str, body: dict[str, Any]) -> tuple[bool, Any]:
        """(a worker answered, its result); raises its refusal."""
        answer = await asyncio.to_thread(self._query, device, body)
        if answer is None:
            return False, None
        if not answer.get("ok"):
            raise LiveUnavailable(str(answer.get("error")))
        return True, answer.get("result")

    async def session_started(self, session: SessionInfo) -> str | None:
        # Nothing asked of the workers yet: the session is not committed, and on SQLite the
        # request's transaction holds the database's one write lock, which a worker taking
        # the device's lease needs. The holder starts it in session_committed.
        params = session_params(dict(session.params))
        if self.viz is not None and isinstance(params, PipelineParams):
            self.viz.configure(
                session.device,
                tolerance_m=params.tolerance_m,
                cuff_to_elbow_m=params.cuff_to_elbow_m,
                imu_to_elbow_m=params.imu_to_elbow_m,
            )
        return files.recording_relpath(session.id)

    async def session_committed(self, session: SessionInfo) -> None:
        """The session is in the database: the request answers once the device's holder
        has started it, as in the one process (every message after the answer is in the
        recording). A device nobody holds yet (announced, no data) is leased on this
        query by a worker (``WorkerNode._claim``). Without any worker answering within
        ``START_RETRY_S`` the request answers anyway; workers follow the database every
        second and start it then."""
        patient = await self._patient_code(session.patient_id)
        body = {
            "op": "start",
            "session": {
                "id": session.id,
                "patient_id": session.patient_id,
                "params": dict(session.params),
                "started_at": session.started_at.isoformat(),
                "recording_path": session.recording_path,
            },
            "patient": patient,
        }
        deadline = time.monotonic() + START_RETRY_S
        while True:
            try:
                answered, _ = await self._ask(session.device, body)
            except Exception:
                log.exception("session %s: the holder of %s refused it", session.id, session.device)
                return
            if answered:
                self.session_of[session.device] = session.id
                return
            if time.monotonic() > deadline:
                log.warning("session %s: no worker holds %s yet", session.id, session.device)
                return
            await asyncio.sleep(START_RETRY_PERIOD_S)

    async def session_stopped(self, session: SessionInfo) -> dict[str, Any] | None:
        answered, result = await self._ask(session.device, {"op": "stop", "session_id": session.id})
        if self.session_of.get(session.device) == session.id:
            self.session_of[session.device] = None
        self.hub.end_session(session.id)
        if answered and isinstance(result, dict):
            return result
        return None

    async def set_nominal_shoulder(
        self, session: SessionInfo, point: Point | None, from_estimate: bool
    ) -> Point | None:
        pt = None if point is None else [float(x) for x in point]
        body = {"op": "nominal", "session_id": session.id, "point": pt}
        answered, result = await self._ask(session.device, {**body, "from_estimate": from_estimate})
        if not answered:
            raise LiveUnavailable("no worker holds the device")
        return None if result is None else [float(x) for x in result]

    async def rom_test(self, session: SessionInfo, movement: str | None) -> dict[str, Any] | None:
        body = {"op": "rom", "session_id": session.id, "movement": movement}
        answered, result = await self._ask(session.device, body)
        if not answered:
            raise LiveUnavailable("no worker holds the device")
        return result if isinstance(result, dict) else None

    async def live_report(self, session_id: int, device: str) -> dict[str, Any] | None:
        answered, result = await self._ask(device, {"op": "report", "session_id": session_id})
        return result if answered and isinstance(result, dict) else None

    def is_running(self, session_id: int, device: str) -> bool:
        return self.session_of.get(device) == session_id

    async def flush_session(self, session_id: int, device: str) -> None:
        await self._ask(device, {"op": "flush", "session_id": session_id})


def make_live(
    settings: Settings, database: Database, interrupted: Sequence[int] = ()
) -> LiveManager:
    """One process for everything (``workers`` unset: tests, the demo) or an API node."""
    if settings.workers is None:
        return LiveManager(settings, database, interrupted)
    return Gateway(settings, database, interrupted, workers=settings.workers)


def default_workers() -> int:
    return os.cpu_count() or 1
