"""``rehab serve`` (contract §6) and ``rehab demo`` (the service with two simulated devices).

Registered by :mod:`backend.cli` through :func:`add_parser`.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import socket
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the app is imported by the commands, not by `rehab analyze`
    from backend.settings import Settings

log = logging.getLogger("rehab")

DEMO_DEVICES = (
    # (device, patient code, what it does)
    ("sim01", "demo-proper", "moves properly"),
    ("sim02", "demo-drift", "drifts into compensation"),
    ("wear01", "demo-wearable", "wearable: two IMUs and a camera, ROM test movements"),
)
# One simulated session each, played in a loop: sim02 drifts into compensation after a
# minute of proper movement (the paper's 8-minute protocol, shortened for a demo).
DRIFT_LAYOUT = (
    ("rest", 5.0),
    ("proper", 60.0),
    ("transition", 20.0),
    ("compensatory", 150.0),
    ("transition", 15.0),
    ("proper", 60.0),
)
DEMO_SECONDS = sum(d for _, d in DRIFT_LAYOUT)


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        port: int = s.getsockname()[1]
        return port


def settings_from_args(args: argparse.Namespace, **extra: Any) -> Settings:
    """Flags given on the command line override ``REHAB_*`` variables."""
    from backend.settings import Settings

    given: dict[str, Any] = {
        "host": args.host,
        "port": args.port,
        "data_dir": args.data_dir,
        "database_url": args.database_url,
        "zenoh_listen": args.zenoh_listen,
        "zenoh_connect": args.zenoh_connect,
        "zenoh_config": getattr(args, "zenoh_config", None),
        "zenoh_allow_plain": getattr(args, "zenoh_allow_plain", None) or None,
        "admit": getattr(args, "admit", None),
        **extra,
    }
    return Settings(**{k: v for k, v in given.items() if v is not None})


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", help="HTTP address (default 127.0.0.1, REHAB_HOST)")
    p.add_argument("--port", type=int, help="HTTP port (REHAB_PORT)")
    p.add_argument(
        "--data-dir",
        type=Path,
        metavar="DIR",
        help="database (SQLite by default), recordings, secret (REHAB_DATA_DIR)",
    )
    p.add_argument(
        "--database-url",
        metavar="URL",
        help="e.g. postgresql://user:pw@host/db (REHAB_DATABASE_URL)",
    )
    p.add_argument(
        "--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"]
    )


def _workers(text: str) -> int:
    """``--workers``: a count, or ``auto`` (-1: the core count, resolved at start)."""
    if text == "auto":
        return -1
    n = int(text)
    if n < 0:
        raise argparse.ArgumentTypeError("a count >= 0, or auto")
    return n


def _security(p: argparse.ArgumentParser) -> None:
    """Zenoh's TLS and access control, and device admission (docs/security.md)."""
    p.add_argument(
        "--zenoh-config",
        type=Path,
        metavar="FILE",
        help="Zenoh JSON5 config: mutual TLS and access control (REHAB_ZENOH_CONFIG; "
        "made by scripts/make-clinic-certs.py)",
    )
    p.add_argument(
        "--zenoh-allow-plain",
        action="store_true",
        help="allow plain TCP Zenoh on a non-loopback address (REHAB_ZENOH_ALLOW_PLAIN)",
    )
    p.add_argument(
        "--admit",
        action="append",
        metavar="GLOB",
        help="admit devices whose name matches GLOB without approval; repeatable; "
        "'*' admits every name (REHAB_ADMIT, a JSON list)",
    )


def add_parser(sub: Any) -> None:
    s = sub.add_parser(
        "serve",
        help="run the service (contract §6)",
        description="Run the live service: Zenoh ingest, one pipeline per device, REST and "
        "WebSocket API, the dashboard. Settings come from REHAB_* variables; flags override.",
    )
    _common(s)
    z = s.add_mutually_exclusive_group()
    z.add_argument(
        "--zenoh-listen",
        metavar="ENDPOINT",
        help="listen as a Zenoh peer (default tcp/127.0.0.1:7447, REHAB_ZENOH_LISTEN)",
    )
    z.add_argument(
        "--zenoh-connect",
        metavar="ENDPOINT",
        help="be a client of the Zenoh router at ENDPOINT (REHAB_ZENOH_CONNECT)",
    )
    _security(s)
    mode = s.add_mutually_exclusive_group()
    mode.add_argument(
        "--workers",
        type=_workers,
        metavar="N|auto",
        help="worker processes running the pipelines (default and 'auto': the core count; "
        "0: API only, for workers started elsewhere with `rehab worker`; REHAB_WORKERS)",
    )
    mode.add_argument(
        "--single-process",
        action="store_true",
        help="run every pipeline in this process, no workers (a small installation, "
        "debugging; docs/scaling.md)",
    )
    s.set_defaults(func=cmd_serve)

    w = sub.add_parser(
        "worker",
        help="run the pipelines of the devices this process leases (docs/scaling.md)",
        description="A worker: takes device leases in the database, subscribes to their "
        "data on Zenoh, records them and publishes estimates and feedback. Joins the API "
        "node's Zenoh router (--zenoh-connect) and its database (--database-url); "
        "recordings go to --data-dir, which every node must share.",
    )
    _common(w)
    w.add_argument("--zenoh-connect", metavar="ENDPOINT", help="the Zenoh router to join")
    _security(w)
    w.add_argument("--max-devices", type=int, default=0, metavar="N", help="0: no limit")
    w.add_argument(
        "--router",
        metavar="ENDPOINT",
        dest="zenoh_listen",
        help="be this machine's Zenoh router, listening on ENDPOINT (devices may connect "
        "to it) and joined to --zenoh-connect's router",
    )
    w.set_defaults(func=cmd_worker)

    d = sub.add_parser(
        "demo",
        help="the service with two simulated devices streaming in real time",
        description="Start the service with an embedded Zenoh on a free loopback port and "
        "SQLite in the data directory, and two simulated devices streaming in real time: "
        "sim01 moves properly, sim02 drifts into shoulder compensation. Prints the URL and "
        "the first administrator's credentials; runs until Ctrl-C.",
    )
    _common(d)
    d.set_defaults(zenoh_listen=None, zenoh_connect=None)
    d.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    d.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="X",
        help="simulated time per second (default 1: real time)",
    )
    d.set_defaults(func=cmd_demo)


def serve_workers(args: argparse.Namespace, settings: Settings) -> int | None:
    """Worker processes of ``rehab serve``: ``--workers``, else REHAB_WORKERS, else the core
    count; ``None`` (one process) with ``--single-process``."""
    from backend.live.gateway import default_workers

    if args.single_process:
        return None
    if args.workers is not None:  # `--workers auto`: the core count
        return default_workers() if args.workers < 0 else int(args.workers)
    return default_workers() if settings.workers is None else settings.workers


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from backend.app import create_app

    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    settings = settings_from_args(args)
    from protocol.zenoh_config import ZenohConfigError, make_config

    try:  # a refused Zenoh set-up: one clear line, not a lifespan traceback
        make_config(
            listen=None if settings.zenoh_connect else settings.zenoh_listen,
            connect=settings.zenoh_connect,
            file=settings.zenoh_config,
            allow_plain=settings.zenoh_allow_plain,
        )
    except ZenohConfigError as exc:
        print(f"rehab serve: {exc}", file=sys.stderr)
        return 2
    settings = settings.model_copy(update={"workers": serve_workers(args, settings)})
    app = create_app(settings)
    app.state.live_required = True  # a service that cannot open Zenoh must not pretend
    uvicorn.run(
        app,
        host=settings.host,
        port=settings.port,
        log_level=args.log_level,
        ws="websockets-sansio",
        ws_per_message_deflate=settings.ws_compression,
        proxy_headers=False,  # the app believes X-Forwarded-* from forwarded_allow_ips only
        ws_max_size=settings.max_body_bytes,  # nothing we read from a client is larger
    )
    return 0


def cmd_worker(args: argparse.Namespace) -> int:
    from backend.live.node import run_worker

    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    settings = settings_from_args(args)
    if not settings.zenoh_connect and settings.zenoh_config is None:
        log.error(
            "rehab worker needs --zenoh-connect (the API node's or a router's endpoint) "
            "or a Zenoh config (REHAB_ZENOH_CONFIG) that connects"
        )
        return 2
    _set_title("rehab worker")
    router = args.zenoh_listen is not None
    asyncio.run(run_worker(settings, args.max_devices, router))
    return 0


def _set_title(title: str) -> None:
    """The process title (ps, top): its command line says ``-m backend.cli worker``."""
    try:
        import setproctitle
    except ImportError:
        return
    setproctitle.setproctitle(title)


# --------------------------------------------------------------------------- demo


def _stream(
    device: str, compensating: bool, endpoint: str, speed: float, stop: threading.Event
) -> None:
    """One simulated device, session after session, on a continuous clock."""
    from simulator import SimConfig, simulate
    from simulator.publish import Publisher, play, prepare

    layout = DRIFT_LAYOUT if compensating else (("rest", 5.0), ("proper", DEMO_SECONDS - 5.0))
    seed = 2 if compensating else 1
    with Publisher.connect(endpoint) as pub:
        pub.announce(device)
        loop = 0
        while not stop.is_set():
            cfg = SimConfig(
                seed=seed,
                duration_s=DEMO_SECONDS,
                device=device,
                layout=layout,
                t0_s=loop * DEMO_SECONDS,
            )
            sim = simulate(cfg)
            outgoing = prepare(_continue_seq(sim.messages, loop))
            pub.declare(outgoing)
            if loop == 0:
                pub.wait_for_subscribers(10.0)
            play(pub, outgoing, speed, stop=stop)
            loop += 1


def _stream_wearable(device: str, endpoint: str, speed: float, stop: threading.Event) -> None:
    """A simulated wearable device (contract §8): the ROM test movements, then reaching, in
    a loop on a continuous clock (the start at rest in the zero pose, as §8 asks)."""
    from simulator import wearable as sw
    from simulator.publish import Publisher, play, prepare
    from simulator.wearable_moves import rom_duration

    with Publisher.connect(endpoint) as pub:
        pub.announce(device)
        loop = 0
        t0 = 0.0
        while not stop.is_set():
            move = "rom" if loop % 2 == 0 else "reaching"
            duration = rom_duration() if move == "rom" else 60.0
            cfg = sw.WearableSimConfig(move=move, duration_s=duration, seed=loop, device=device)
            msgs = [
                (k, {**p, "t": [t + t0 for t in p["t"]], "seq": p["seq"] + loop * 1_000_000})
                for k, p in sw.simulate(cfg).messages
            ]
            outgoing = prepare(msgs)
            pub.declare(outgoing)
            if loop == 0:
                pub.wait_for_subscribers(10.0)
            play(pub, outgoing, speed, stop=stop)
            t0 += duration
            loop += 1


def _continue_seq(
    messages: list[tuple[str, dict[str, Any]]], loop: int
) -> list[tuple[str, dict[str, Any]]]:
    """Sequence numbers go on across loops (a restart would be counted as one)."""
    if loop == 0:
        return messages
    out = []
    for key, payload in messages:
        if "seq" in payload:
            payload = {**payload, "seq": payload["seq"] + loop * 1_000_000}
        out.append((key, payload))
    return out


async def _demo_patients(base_url: str, settings: Settings) -> None:
    """Patients for the two devices, so a session starts with two clicks."""
    import httpx

    from backend.auth.first_admin import read_admin_credentials

    creds = read_admin_credentials(settings)
    if creds is None:
        return
    async with httpx.AsyncClient(base_url=base_url) as client:
        r = await client.post(
            "/api/auth/login", json={"username": creds.username, "password": creds.password}
        )
        if r.status_code != 200:
            return
        headers = {"Authorization": f"Bearer {r.json()['access_token']}"}
        existing = {p["code"] for p in (await client.get("/api/patients", headers=headers)).json()}
        for _, code, _ in DEMO_DEVICES:
            if code not in existing:
                await client.post(
                    "/api/patients", headers=headers, json={"code": code, "affected_side": "right"}
                )


def cmd_demo(args: argparse.Namespace) -> int:
    import uvicorn

    from backend.app import create_app

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    host = args.host or "127.0.0.1"
    port = args.port or free_port(host)
    zport = free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    data_dir = args.data_dir or Path("data/demo")  # data/ is git-ignored
    settings = settings_from_args(
        args,
        host=host,
        port=port,
        data_dir=data_dir,
        zenoh_listen=endpoint,
        admit=[d for d, _, _ in DEMO_DEVICES],  # the simulated devices only
    )
    settings = replace_cookie_secure(settings, host)
    app = create_app(settings)
    app.state.live_required = True
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=host,
            port=port,
            log_level="warning",
            ws="websockets-sansio",
            ws_per_message_deflate=settings.ws_compression,
            proxy_headers=False,  # the app believes X-Forwarded-* from forwarded_allow_ips
            ws_max_size=settings.max_body_bytes,
        )
    )
    stop = threading.Event()
    streams: list[threading.Thread] = []

    async def main() -> None:
        serving = asyncio.create_task(server.serve())
        while not server.started:
            if serving.done():
                await serving  # startup failed: raise its error
                return
            await asyncio.sleep(0.05)
        url = f"http://{host}:{port}/"
        from backend.auth.first_admin import read_admin_credentials

        creds = read_admin_credentials(settings)
        print(f"rehab demo: open {url}")
        if creds is not None:
            print(f"  log in as {creds.username!r}, password {creds.password!r}")
        else:
            print(f"  (admin password changed: {settings.admin_credentials_file} is gone)")
        print(f"  data in {data_dir.resolve()}, Zenoh on {endpoint}")
        await _demo_patients(f"http://{host}:{port}", settings)
        for device, code, what in DEMO_DEVICES:
            print(f"  device {device} ({what}); patient {code}")
            thread = threading.Thread(
                target=_stream,
                name=f"demo-{device}",
                daemon=True,
                args=(device, device == "sim02", endpoint, args.speed, stop),
            )
            if device.startswith("wear"):
                thread = threading.Thread(
                    target=_stream_wearable,
                    name=f"demo-{device}",
                    daemon=True,
                    args=(device, endpoint, args.speed, stop),
                )
            thread.start()
            streams.append(thread)
        print("  Ctrl-C to stop")
        started = time.monotonic()
        while not serving.done():
            if args.duration is not None and time.monotonic() - started >= args.duration:
                server.should_exit = True
            await asyncio.sleep(0.2)
        stop.set()

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        for thread in streams:  # their Zenoh sessions must close before the interpreter
            thread.join(30)
    return 0


def replace_cookie_secure(settings: Settings, host: str) -> Settings:
    """The demo serves plain http: browsers keep Secure cookies from localhost only."""
    if host in ("127.0.0.1", "localhost", "::1"):
        return settings
    log.warning("plain http on %s: the session cookie is not Secure", host)
    return settings.model_copy(update={"cookie_secure": False})


if __name__ == "__main__":  # pragma: no cover
    import backend.cli

    sys.exit(backend.cli.main(["demo", *sys.argv[1:]]))
