"""docker-compose.yml (no Docker engine here): its settings are what the service reads."""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import yaml
from sqlalchemy.engine import make_url

from backend import cli_live
from backend.settings import Settings

REPO = Path(__file__).resolve().parents[2]


def compose() -> dict[str, Any]:
    data: dict[str, Any] = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    return data


def serve_args(command: list[str]) -> argparse.Namespace:
    assert command[:2] == ["rehab", "serve"]
    parser = argparse.ArgumentParser(prog="rehab")
    cli_live.add_parser(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(command[1:])


def test_services_and_health_checks() -> None:
    services = compose()["services"]
    assert set(services) == {"zenoh", "postgres", "rehab", "proxy", "worker"}
    assert services["zenoh"]["image"].startswith("eclipse/zenoh:")
    assert services["postgres"]["image"].startswith("postgres:")
    for name, svc in services.items():
        assert svc["healthcheck"]["test"], name
    deps = services["rehab"]["depends_on"]
    assert deps == {
        "zenoh": {"condition": "service_healthy"},
        "postgres": {"condition": "service_healthy"},
    }
    assert (REPO / "Dockerfile").is_file() and services["rehab"]["build"] == "."


def test_the_service_is_a_client_of_the_router_and_uses_postgres() -> None:
    services = compose()["services"]
    rehab = services["rehab"]
    args = serve_args(rehab["command"])
    env = {k: str(v) for k, v in rehab["environment"].items()}

    # every variable is one Settings reads
    fields = {f"REHAB_{name.upper()}" for name in Settings.model_fields}
    assert set(env) <= fields, set(env) - fields
    settings = cli_live.settings_from_args(args)
    settings = Settings(
        **{**{k[6:].lower(): v for k, v in env.items()}, **settings.model_dump(exclude_unset=True)}
    )

    # Zenoh: mutual TLS and access control, the router and the service configured by the
    # files scripts/make-clinic-certs.py makes, mounted where the configs point
    assert args.zenoh_config is not None and args.zenoh_listen is None
    mounted = {v.split(":")[1]: v.split(":")[0] for v in rehab["volumes"]}
    assert mounted[str(args.zenoh_config)] == "./clinic-pki/zenoh-service-client.json5"
    zenoh_cmd = services["zenoh"]["command"]
    router_cfg = zenoh_cmd[zenoh_cmd.index("-c") + 1]
    router_mounts = {v.split(":")[1]: v.split(":")[0] for v in services["zenoh"]["volumes"]}
    assert router_mounts[router_cfg] == "./clinic-pki/zenoh-router.json5"
    assert not any("ca-key" in v for v in rehab["volumes"] + services["zenoh"]["volumes"])
    assert "7447:7447" in services["zenoh"]["ports"]  # devices reach the router
    rest_port = zenoh_cmd[zenoh_cmd.index("--rest-http-port") + 1]
    assert f":{rest_port}/" in " ".join(services["zenoh"]["healthcheck"]["test"])

    # PostgreSQL: the database the postgres service creates, through the async driver; the
    # password is the secret both read, never written in the file
    url = make_url(settings.database_url or "")
    pg = services["postgres"]["environment"]
    assert url.drivername == "postgresql+psycopg"
    assert (url.host, url.username, url.password, url.database) == (
        "postgres",
        pg["POSTGRES_USER"],
        None,
        pg["POSTGRES_DB"],
    )
    assert "POSTGRES_PASSWORD" not in pg
    assert pg["POSTGRES_PASSWORD_FILE"] == str(settings.database_password_file)
    assert url.port == 5432
    pg_check = " ".join(services["postgres"]["healthcheck"]["test"])
    assert f"-U {pg['POSTGRES_USER']}" in pg_check and f"-d {pg['POSTGRES_DB']}" in pg_check

    # HTTP: listens on all interfaces of the container, published on the host's loopback
    # only (the clinic network reaches it through the TLS proxy), health-checked there
    assert settings.host == "0.0.0.0"
    assert rehab["ports"] == [f"127.0.0.1:{settings.port}:{settings.port}"]
    check = " ".join(rehab["healthcheck"]["test"])
    health = re.search(r"http://[^'\"]+", check)
    assert health is not None
    parts = urlsplit(health.group(0))
    assert parts.port == settings.port and parts.path == "/api/health"
    # the 3D view stays on the container's loopback (served through the API's proxy path)
    assert settings.viser_host == "127.0.0.1"

    # the data directory is a volume
    assert str(settings.data_dir) == "/data"
    assert any(v.split(":")[1] == "/data" for v in rehab["volumes"])


def secret_files(service: dict[str, Any], secrets: dict[str, Any]) -> dict[str, str]:
    """In-container path -> the host file, for each secret the service gets."""
    return {f"/run/secrets/{name}": secrets[name]["file"] for name in service["secrets"]}


def test_secrets_come_from_files_not_from_this_file() -> None:
    data = compose()
    services, secrets = data["services"], data["secrets"]
    rehab, pg = services["rehab"], services["postgres"]
    env = {k: str(v) for k, v in rehab["environment"].items()}
    given = secret_files(rehab, secrets)
    assert env["REHAB_SECRET_FILE"] in given and env["REHAB_DATABASE_PASSWORD_FILE"] in given
    # the service and PostgreSQL read the same password file
    assert (
        given[env["REHAB_DATABASE_PASSWORD_FILE"]]
        == secret_files(pg, secrets)[pg["environment"]["POSTGRES_PASSWORD_FILE"]]
    )
    text = (REPO / "docker-compose.yml").read_text()
    assert not re.search(r"(PASSWORD|SECRET_KEY)\s*:\s*(?!/run/secrets/)\S", text), (
        "a secret value written in docker-compose.yml"
    )
    assert not re.search(r"postgres(ql)?://[^@\s]*:[^@\s]*@", text)  # no password in a URL
    ignored = (REPO / ".gitignore").read_text().splitlines()
    assert all(f.startswith("./secrets/") for f in (s["file"] for s in secrets.values()))
    assert "/secrets/" in ignored


def test_tls_proxy_in_front() -> None:
    services = compose()["services"]
    proxy, rehab = services["proxy"], services["rehab"]
    assert proxy["image"].startswith("caddy:")
    assert "443:443" in proxy["ports"]
    assert proxy["depends_on"] == {"rehab": {"condition": "service_healthy"}}
    mounts = {v.split(":")[1]: v.split(":")[0] for v in proxy["volumes"]}
    caddyfile = (REPO / mounts["/etc/caddy/Caddyfile"]).read_text()
    port = serve_args(rehab["command"]).port
    assert re.search(rf"^\s*reverse_proxy rehab:{port}\s*$", caddyfile, re.M)
    tls = re.search(r"^\s*tls (\S+) (\S+)\s*$", caddyfile, re.M)
    assert tls is not None and {tls.group(1), tls.group(2)} <= set(mounts)
    assert all(mounts[p].startswith("./secrets/") for p in (tls.group(1), tls.group(2)))
    assert "Strict-Transport-Security" in caddyfile
    # the service believes X-Forwarded-For from the proxy's fixed address, and from no one else
    env = {k: str(v) for k, v in rehab["environment"].items()}
    settings = Settings(forwarded_allow_ips=env["REHAB_FORWARDED_ALLOW_IPS"])  # type: ignore[arg-type]
    assert settings.forwarded_allow_ips == [proxy["networks"]["default"]["ipv4_address"]]
    subnet = compose()["networks"]["default"]["ipam"]["config"][0]["subnet"]
    import ipaddress

    assert ipaddress.ip_address(settings.forwarded_allow_ips[0]) in ipaddress.ip_network(subnet)
    # nothing but the proxy (and the devices' Zenoh router) is published beyond loopback
    for name, svc in services.items():
        for mapping in svc.get("ports", []):
            if name not in ("proxy", "zenoh"):
                assert mapping.startswith("127.0.0.1:"), (name, mapping)


def test_workers_scale_out_on_the_same_router_database_and_volume() -> None:
    """`docker compose up --scale worker=N`: each worker joins the rehab service's router,
    database, key prefix and data volume (no fixed name or port: it can be replicated)."""
    services = compose()["services"]
    worker, rehab = services["worker"], services["rehab"]
    assert worker["build"] == "." and "container_name" not in worker and "ports" not in worker
    assert worker["command"][:2] == ["rehab", "worker"]
    parser = argparse.ArgumentParser(prog="rehab")
    cli_live.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(worker["command"][1:])
    env: dict[str, Any] = {k: str(v) for k, v in worker["environment"].items()}
    fields = {f"REHAB_{name.upper()}" for name in Settings.model_fields}
    assert set(env) <= fields, set(env) - fields
    mine = Settings(**{k[6:].lower(): v for k, v in env.items()})
    api_env: dict[str, Any] = {k[6:].lower(): str(v) for k, v in rehab["environment"].items()}
    api = Settings(**api_env)
    assert mine.database_url == api.database_url and mine.key_prefix == api.key_prefix
    assert mine.database_password_file == api.database_password_file
    assert set(worker["secrets"]) <= set(rehab["secrets"])
    # the same Zenoh identity (the service's certificate) and router as the API node
    assert args.zenoh_config == serve_args(rehab["command"]).zenoh_config
    zenoh_mounts = {v for v in rehab["volumes"] if "/run/zenoh/" in v}
    assert zenoh_mounts <= set(worker["volumes"])
    assert str(args.data_dir) == "/data"
    shared = {v for v in worker["volumes"]} & {v for v in rehab["volumes"]}
    assert any(v.split(":")[1] == "/data" for v in shared)
    assert worker["depends_on"]["rehab"] == {"condition": "service_healthy"}


def test_the_service_is_an_api_node_beside_the_workers() -> None:
    """With a `worker` service, the service itself runs no pipeline (`--workers 0`): a device
    is never run both by the service and by a leased worker."""
    services = compose()["services"]
    assert "worker" in services
    assert serve_args(services["rehab"]["command"]).workers == 0


def test_serve_runs_workers_by_default(monkeypatch: Any) -> None:
    """`rehab serve`: one worker process per core unless told otherwise; --single-process
    keeps every pipeline in the API's process (Settings.workers unset)."""
    from backend.live.gateway import default_workers

    monkeypatch.delenv("REHAB_WORKERS", raising=False)

    def workers(*flags: str) -> int | None:
        args = serve_args(["rehab", "serve", *flags])
        return cli_live.serve_workers(args, cli_live.settings_from_args(args))

    assert workers() == default_workers() >= 1
    assert workers("--workers", "3") == 3
    assert workers("--workers", "0") == 0
    assert workers("--workers", "auto") == default_workers()
    assert workers("--single-process") is None
    monkeypatch.setenv("REHAB_WORKERS", "5")
    assert workers() == 5
    assert workers("--single-process") is None
