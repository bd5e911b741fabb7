#!/usr/bin/env python3
"""Make a clinic's Zenoh PKI and configs: a CA, the service's certificate, one certificate
per device, and the matching Zenoh JSON5 configs (mutual TLS, access control).

    python scripts/make-clinic-certs.py --out clinic-pki --host rehab.clinic.local \\
        --device robot01 --device robot02

writes into ``--out``:

- ``ca.pem`` (give it to every device), ``ca-key.pem`` (keep it OFFLINE: it signs devices);
- ``service.pem``/``service-key.pem`` and ``zenoh-service.json5``: ``REHAB_ZENOH_CONFIG``
  for ``rehab serve`` listening itself on ``tls/<host>:7447``;
- ``zenoh-router.json5`` (a zenohd router with the same rules) and
  ``zenoh-service-client.json5`` (the service connecting to it): the docker-compose set-up;
- ``devices/<name>.pem``, ``devices/<name>-key.pem``, ``devices/<name>.json5`` per device.

A new device later: run again with ``--add`` and the same ``--out``: the CA is kept, the
configs are rewritten with every device found in ``devices/``; restart the service.
``--base`` writes that directory into the configs instead of ``--out``'s absolute path
(e.g. ``/run/zenoh`` where compose mounts it). Needs the ``openssl`` command.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from backend import clinic_certs
from protocol import keys, zenoh_config

SERVICE = "rehab-service"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--host", action="append", default=[], help="service host name or IP")
    ap.add_argument("--port", type=int, default=7447)
    ap.add_argument("--listen-host", default="0.0.0.0", help="address the service listens on")
    ap.add_argument("--device", action="append", default=[], help="device name (repeatable)")
    ap.add_argument("--prefix", default=keys.DEFAULT_PREFIX)
    ap.add_argument("--base", help="directory of these files as the service sees them")
    ap.add_argument("--add", action="store_true", help="keep the existing CA and certificates")
    args = ap.parse_args(argv)
    out: Path = args.out.resolve()
    hosts = args.host or ["localhost", "127.0.0.1"]
    for d in args.device:
        if not keys.DEVICE_RE.fullmatch(d):
            ap.error(f"not a device name: {d!r}")
    devdir = out / "devices"
    devdir.mkdir(parents=True, exist_ok=True)
    if (out / "ca.pem").exists() and not args.add:
        ap.error(f"{out} holds a CA already: --add to issue more devices with it")
    if (out / "ca.pem").exists():
        ca = clinic_certs.Pair(out / "ca.pem", out / "ca-key.pem")
    else:
        ca = clinic_certs.make_ca(out)
    if not (out / "service.pem").exists():
        srv = clinic_certs.issue(ca, out, SERVICE, server_hosts=hosts)
        srv.cert.rename(out / "service.pem")
        srv.key.rename(out / "service-key.pem")
    for d in args.device:
        if not (devdir / f"{d}.pem").exists():
            clinic_certs.issue(ca, devdir, d)
    devices = sorted(p.name[:-4] for p in devdir.glob("*.pem") if not p.name.endswith("-key.pem"))
    base = Path(args.base) if args.base else out
    listen = f"tls/{hosts[0]}:{args.port}"
    ca_p, cert_p, key_p = base / "ca.pem", base / "service.pem", base / "service-key.pem"

    def write(path: Path, cfg: dict[str, object]) -> None:
        path.write_text(json.dumps(cfg, indent=2) + "\n")

    listen_any = f"tls/{args.listen_host}:{args.port}"
    write(
        out / "zenoh-service.json5",
        zenoh_config.service_config(
            listen=listen_any, devices=devices, prefix=args.prefix, ca=ca_p, cert=cert_p, key=key_p
        ),
    )
    write(
        out / "zenoh-router.json5",
        zenoh_config.service_config(
            listen=listen_any,
            devices=devices,
            prefix=args.prefix,
            mode="router",
            service_name=SERVICE,
            ca=ca_p,
            cert=cert_p,
            key=key_p,
        ),
    )
    write(
        out / "zenoh-service-client.json5",
        zenoh_config.device_config(connect=listen, ca=ca_p, cert=cert_p, key=key_p),
    )
    for d in devices:
        write(
            devdir / f"{d}.json5",
            zenoh_config.device_config(
                connect=listen,
                ca=base / "ca.pem",
                cert=base / "devices" / f"{d}.pem",
                key=base / "devices" / f"{d}-key.pem",
            ),
        )
    print(
        f"{out}: CA, service ({', '.join(hosts)}), {len(devices)} device(s): {', '.join(devices)}"
    )
    print(f"  rehab serve --zenoh-config {out / 'zenoh-service.json5'}")
    print("  keep ca-key.pem offline; give each device ca.pem and its own files only")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
