"""Zenoh with the clinic's mutual TLS and access control (scripts/make-clinic-certs.py), for
real: the service loads the generated config, devices connect with their own certificates
over loopback. Plain TCP beyond loopback needs an explicit opt-in."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from backend.settings import Settings
from protocol.zenoh_config import ZenohConfigError, make_config
from simulator.publish import Publisher
from tests.live.conftest import Service, _service, free_port, wait_for

REPO = Path(__file__).resolve().parents[2]


def _script() -> Any:
    spec = importlib.util.spec_from_file_location(
        "make_clinic_certs", REPO / "scripts" / "make-clinic-certs.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    out = tmp_path_factory.mktemp("pki")
    port = free_port()
    args = ["--out", str(out), "--port", str(port), "--listen-host", "127.0.0.1"]
    assert _script().main([*args, "--device", "dev01", "--device", "dev02"]) == 0
    return out, port


@pytest.fixture(scope="module")
def secure(pki: tuple[Path, int], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    out, _ = pki
    yield from _service(
        Settings(
            data_dir=tmp_path_factory.mktemp("secure"),
            port=free_port(),
            zenoh_config=out / "zenoh-service.json5",
            cookie_secure=False,
            admit=["*"],
        )
    )


def device(pki: tuple[Path, int], name: str) -> Publisher:
    out, _ = pki
    return Publisher(zenoh.open(zenoh.Config.from_file(str(out / "devices" / f"{name}.json5"))))


ROBOT = json.dumps({"t": [1.0], "wrist": [[0.3, 0.4, 0.1]], "proximal": [[0.3, 0.2, 0.1]]})


def test_config_is_tls_with_mtls_and_default_deny(pki: tuple[Path, int]) -> None:
    out, port = pki
    cfg = json.loads((out / "zenoh-service.json5").read_text())
    assert cfg["listen"]["endpoints"] == [f"tls/127.0.0.1:{port}"]
    assert cfg["transport"]["link"]["tls"]["enable_mtls"] is True
    acl = cfg["access_control"]
    assert acl["enabled"] and acl["default_permission"] == "deny"
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert subjects["device_dev01"]["cert_common_names"] == ["dev01"]
    # the CA signed each device's certificate, with its name as the common name
    subject = subprocess.run(
        ["openssl", "x509", "-noout", "-subject", "-in", str(out / "devices" / "dev01.pem")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "CN = dev01" in subject or "CN=dev01" in subject


def test_device_publishes_its_own_keys_only(secure: Service, pki: tuple[Path, int]) -> None:
    with device(pki, "dev01") as dev01, device(pki, "dev02") as dev02:
        forged: list[str] = []
        # dev02 may watch its own outputs: nothing dev01 forges there may reach it
        sub = dev02.session.declare_subscriber(
            "rehab/dev02/**", lambda s: forged.append(str(s.key_expr))
        )
        dev01.declare_key("rehab/dev01/robot")
        assert dev01.wait_for_subscribers(10.0)
        time.sleep(0.5)  # dev02's subscription reaches the service
        for key in ("rehab/dev02/robot", "rehab/dev02/estimate", "rehab/dev02/feedback"):
            dev01.session.put(key, ROBOT)
        dev01.session.put("rehab/dev01/estimate", ROBOT)
        time.sleep(0.3)
        dev01.put("rehab/dev01/robot", ROBOT.encode())
        wait_for(lambda: secure.received("dev01") >= 1, what="dev01's own message")
        time.sleep(0.5)
        assert secure.device("dev02") is None, "dev01 published as dev02"
        assert secure.received("dev01") == 1
        assert forged == [], forged
        sub.undeclare()  # type: ignore[no-untyped-call]


def test_no_raw_streams_for_other_devices(secure: Service, pki: tuple[Path, int]) -> None:
    with device(pki, "dev01") as dev01, device(pki, "dev02") as dev02:
        seen: list[str] = []
        sub = dev02.session.declare_subscriber(
            "rehab/dev01/**", lambda s: seen.append(str(s.key_expr))
        )
        time.sleep(0.5)
        before = secure.received("dev01")
        dev01.declare_key("rehab/dev01/robot")
        assert dev01.wait_for_subscribers(10.0)
        dev01.put("rehab/dev01/robot", json.dumps({**json.loads(ROBOT), "t": [2.0]}).encode())
        wait_for(lambda: secure.received("dev01") > before, what="the service got it")
        time.sleep(0.5)
        assert seen == [], "a device read another device's raw stream"
        sub.undeclare()  # type: ignore[no-untyped-call]


def test_no_certificate_no_connection(secure: Service, pki: tuple[Path, int]) -> None:
    out, port = pki
    cfg = {
        "mode": "client",
        "connect": {"endpoints": [f"tls/localhost:{port}"], "timeout_ms": 2000},
        "transport": {"link": {"tls": {"root_ca_certificate": str(out / "ca.pem")}}},
    }
    with pytest.raises(zenoh.ZError):
        zenoh.open(zenoh.Config.from_json5(json.dumps(cfg)))
    with pytest.raises(zenoh.ZError):  # nor in plain TCP on the TLS port
        zenoh.open(
            zenoh.Config.from_json5(
                json.dumps(
                    {
                        "mode": "client",
                        "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"], "timeout_ms": 2000},
                    }
                )
            )
        )


def test_plain_tcp_beyond_loopback_needs_opt_in(tmp_path: Path) -> None:
    make_config(listen="tcp/127.0.0.1:7447", allow_plain=False)  # demo and tests
    make_config(listen="tcp/[::1]:7447", allow_plain=False)
    with pytest.raises(ZenohConfigError, match="--zenoh-allow-plain"):
        make_config(listen="tcp/0.0.0.0:7447", allow_plain=False)
    with pytest.raises(ZenohConfigError, match="plain TCP"):
        make_config(connect="tcp/zenoh:7447", allow_plain=False)
    make_config(listen="tcp/0.0.0.0:7447", allow_plain=True)
    make_config(listen="tls/0.0.0.0:7447", allow_plain=False)
    r = subprocess.run(
        [sys.executable, "-m", "backend.cli", "serve", "--zenoh-listen", "tcp/0.0.0.0:7447",
         "--data-dir", str(tmp_path), "--port", str(free_port())],
        capture_output=True, text=True, timeout=60, cwd=REPO,
    )  # fmt: skip
    assert r.returncode == 2
    assert "--zenoh-allow-plain" in r.stderr and "Traceback" not in r.stderr


def test_router_set_up_of_compose(tmp_path: Path) -> None:
    """docker-compose's set-up: a router with the rules, the service its client with its own
    certificate (here the router is a Python Zenoh session in router mode, zenohd's code)."""
    out, port = tmp_path / "pki", free_port()
    args = ["--out", str(out), "--port", str(port), "--listen-host", "127.0.0.1"]
    assert _script().main([*args, "--device", "dev01", "--device", "dev02"]) == 0
    pki = (out, port)
    router = zenoh.open(zenoh.Config.from_file(str(out / "zenoh-router.json5")))
    running = _service(
        Settings(
            data_dir=tmp_path / "data",
            port=free_port(),
            zenoh_config=out / "zenoh-service-client.json5",
            cookie_secure=False,
            admit=["*"],
        )
    )
    try:
        service = next(running)
        with device(pki, "dev01") as dev01:
            dev01.declare_key("rehab/dev01/robot")
            assert dev01.wait_for_subscribers(10.0)
            dev01.session.put("rehab/dev02/robot", ROBOT)
            time.sleep(0.3)
            dev01.put("rehab/dev01/robot", ROBOT.encode())
            wait_for(lambda: service.received("dev01") >= 1, what="through the router")
            time.sleep(0.5)
            assert service.device("dev02") is None
    finally:
        next(running, None)  # the generator's clean-up: the service stops
        router.close()  # type: ignore[no-untyped-call]
