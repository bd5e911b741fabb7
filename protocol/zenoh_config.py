"""The Zenoh side of the clinic's security: which transports are allowed, and the JSON5 config
(mutual TLS and access control) that ``REHAB_ZENOH_CONFIG`` names.

Policy (docs/security.md):

- Plain TCP/UDP (no authentication, no encryption) is accepted on loopback only; on any
  other address the operator must opt in (``--zenoh-allow-plain``, ``REHAB_ZENOH_ALLOW_PLAIN``).
- The secured set-up is a config file made by ``scripts/make-clinic-certs.py``: the service
  listens on ``tls/…`` with ``enable_mtls``, every device has a certificate whose common name
  is its device name, and access-control rules (default deny) let a device publish only
  ``<prefix>/<its name>/{imu/*,robot,camera,event}``, hold its liveliness token and subscribe
  to its own outputs. Nobody else may publish outputs or subscribe to raw streams: the
  service's own session is not subject to its rules, everything arriving over the network is.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import zenoh

PLAIN = ("tcp", "udp", "ws", "unixsock-stream", "unixpipe")  # no authentication of the peer

# Zenoh's shared memory: off (Zenoh's default is on). With it, each other process on the
# machine that sends a message over 3 kB makes the receiver map that process's 16 MiB pool,
# and the pages stay resident after the sender has gone: every flood from a new local process
# left 32 MiB more in the API node and in each worker, for good (issue 21), and the sender
# could change a payload's bytes while the service reads them. Over loopback TCP a
# device's payload (1 MiB at most) is copied once; that costs nothing that matters.
SHARED_MEMORY = False


class ZenohConfigError(ValueError):
    """A refused Zenoh set-up; the message says what to do."""


def endpoints(cfg: zenoh.Config, which: str) -> list[str]:
    """``listen`` or ``connect`` endpoints of a config (a list, or a list per mode)."""
    raw = json.loads(cfg.get_json(f"{which}/endpoints"))
    if isinstance(raw, dict):  # per mode: the ones of the config's mode
        mode = json.loads(cfg.get_json("mode")) or "peer"
        return list(raw.get(mode) or [])
    return list(raw or [])


def _host(endpoint: str) -> str:
    """The address part of ``proto/host:port[#…]`` (brackets of IPv6 removed)."""
    addr = endpoint.split("/", 1)[1] if "/" in endpoint else endpoint
    addr = addr.split("#", 1)[0].split("?", 1)[0]
    if addr.startswith("["):
        return addr[1 : addr.index("]")]
    return addr.rsplit(":", 1)[0] if ":" in addr else addr


def is_loopback(endpoint: str) -> bool:
    host = _host(endpoint)
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_transport(eps: Iterable[str], allow_plain: bool) -> None:
    """Refuse an unauthenticated transport on a non-loopback address unless opted in."""
    for ep in eps:
        proto = ep.split("/", 1)[0].lower()
        if proto in PLAIN and not is_loopback(ep) and not allow_plain:
            raise ZenohConfigError(
                f"Zenoh endpoint {ep!r} is plain {proto.upper()} on a network address: anyone "
                "who reaches it could read patients' streams and inject data. Use TLS with a "
                "config file (REHAB_ZENOH_CONFIG, made by scripts/make-clinic-certs.py), or "
                "opt in explicitly with --zenoh-allow-plain (REHAB_ZENOH_ALLOW_PLAIN=1)."
            )


def load(path: Path) -> zenoh.Config:
    if not path.is_file():
        raise ZenohConfigError(f"Zenoh config {path} does not exist")
    try:
        return zenoh.Config.from_file(str(path))
    except Exception as exc:  # zenoh.ZError: the message says which key is wrong
        raise ZenohConfigError(f"Zenoh config {path}: {exc}") from None


# ----------------------------------------------------------------------------- making configs

INPUTS = ("imu/*", "robot", "camera", "event")
OUTPUTS = ("estimate", "feedback", "event")


def service_config(
    *,
    listen: str,
    ca: Path,
    cert: Path,
    key: Path,
    devices: Iterable[str],
    prefix: str = "rehab",
    mode: str = "peer",
    service_name: str | None = None,
) -> dict[str, Any]:
    """The service's config: mutual TLS on ``listen`` (``tls/host:port``) and the rules.

    ``mode="router"`` with ``service_name`` (the common name of the service's certificate):
    the same rules for a Zenoh router (zenohd) that devices and the service connect to;
    the service's certificate may then do everything under ``prefix``.
    Paths are written as given (the script writes absolute ones; compose mounts them)."""
    devices = sorted(set(devices))
    rules: list[dict[str, Any]] = [
        {
            # devices learn that the service subscribes (else they would not send)
            "id": "service_declarations",
            "messages": ["declare_subscriber", "declare_liveliness_subscriber"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [f"{prefix}/**"],
        }
    ]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for d in devices:
        rules += [
            {
                "id": f"{d}_publish",
                "messages": ["put"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [f"{prefix}/{d}/{k}" for k in INPUTS],
            },
            {
                "id": f"{d}_presence",
                "messages": ["liveliness_token"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [f"{prefix}/{d}", f"{prefix}/{d}/**"],
            },
            {
                "id": f"{d}_outputs",  # its own estimates, feedback and events, nobody else's
                "messages": ["put"],
                "flows": ["egress"],
                "permission": "allow",
                "key_exprs": [f"{prefix}/{d}/{k}" for k in OUTPUTS],
            },
            {
                "id": f"{d}_subscribe",
                "messages": ["declare_subscriber"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [f"{prefix}/{d}/{k}" for k in OUTPUTS],
            },
        ]
        subjects.append({"id": f"device_{d}", "cert_common_names": [d]})
        policies.append(
            {
                "id": f"device_{d}",
                "rules": [
                    "service_declarations",
                    f"{d}_publish",
                    f"{d}_presence",
                    f"{d}_outputs",
                    f"{d}_subscribe",
                ],
                "subjects": [f"device_{d}"],
            }
        )
    if service_name is not None:
        rules.append(
            {
                "id": "service_all",
                "messages": [
                    "put",
                    "delete",
                    "declare_subscriber",
                    "liveliness_token",
                    "declare_liveliness_subscriber",
                    "liveliness_query",
                ],
                "flows": ["ingress", "egress"],
                "permission": "allow",
                "key_exprs": [f"{prefix}/**", prefix],
            }
        )
        subjects.append({"id": "service", "cert_common_names": [service_name]})
        policies.append({"id": "service", "rules": ["service_all"], "subjects": ["service"]})
    return {
        "mode": mode,
        "listen": {"endpoints": [listen]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {
            "shared_memory": {"enabled": SHARED_MEMORY},  # as make_config; zenohd reads this
            "link": {
                "tls": {
                    "root_ca_certificate": str(ca),
                    "listen_certificate": str(cert),
                    "listen_private_key": str(key),
                    "enable_mtls": True,
                    "verify_name_on_connect": True,
                }
            },
        },
        "access_control": {
            "enabled": True,
            "default_permission": "deny",
            "rules": rules,
            "subjects": subjects,
            "policies": policies,
        },
    }


def device_config(*, connect: str, ca: Path, cert: Path, key: Path) -> dict[str, Any]:
    """A device's config: a client of the service over mutual TLS."""
    return {
        "mode": "client",
        "connect": {"endpoints": [connect]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {
            "link": {
                "tls": {
                    "root_ca_certificate": str(ca),
                    "connect_certificate": str(cert),
                    "connect_private_key": str(key),
                    "enable_mtls": True,
                    "verify_name_on_connect": True,
                }
            }
        },
    }


# Zenoh's own per-message ceiling (default 1 GiB): far above the contract's 1 MiB, low
# enough that a hostile peer cannot make the router side allocate without bound.
RX_MAX_MESSAGE_BYTES = 16 << 20


def make_config(
    *,
    listen: str | None = None,
    connect: str | None = None,
    mode: str | None = None,
    file: Path | None = None,
    allow_plain: bool = True,
) -> zenoh.Config:
    """Explicit endpoints only: multicast scouting is off so that a clinic's services,
    test runs and devices on one network never discover each other by accident.

    ``file``: a Zenoh JSON5 config (TLS, access control); its own endpoints and mode win.
    The service passes its ``zenoh_allow_plain`` setting: then plain TCP on a non-loopback
    address raises :class:`ZenohConfigError` (see :func:`check_transport`)."""
    cfg = load(file) if file is not None else zenoh.Config()
    if file is None or not endpoints(cfg, "listen") + endpoints(cfg, "connect"):
        cfg.insert_json5(
            "mode", json.dumps(mode or ("client" if connect and not listen else "peer"))
        )
        if listen:
            cfg.insert_json5("listen/endpoints", json.dumps([listen]))
        if connect:
            cfg.insert_json5("connect/endpoints", json.dumps([connect]))
    check_transport(
        endpoints(cfg, "listen") + endpoints(cfg, "connect"),
        allow_plain,
    )
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("transport/link/rx/max_message_size", str(RX_MAX_MESSAGE_BYTES))
    cfg.insert_json5("transport/shared_memory/enabled", json.dumps(SHARED_MEMORY))
    return cfg
