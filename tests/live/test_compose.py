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
    assert set(services) == {"zenoh", "postgres", "rehab", "worker"}
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

    # Zenoh: a client of the router service, on the port the router listens on
    assert args.zenoh_connect and args.zenoh_listen is None
    proto, hostport = settings.zenoh_connect.split("/", 1)  # type: ignore[union-attr]
    host, port = hostport.rsplit(":", 1)
    assert proto == "tcp" and host == "zenoh"
    zenoh_cmd = services["zenoh"]["command"]
    listen = zenoh_cmd[zenoh_cmd.index("-l") + 1]
    assert listen.endswith(f":{port}")
    assert f"{port}:{port}" in services["zenoh"]["ports"]  # devices reach the router
    rest_port = zenoh_cmd[zenoh_cmd.index("--rest-http-port") + 1]
    assert f":{rest_port}/" in " ".join(services["zenoh"]["healthcheck"]["test"])

    # PostgreSQL: the database the postgres service creates, through the async driver
    url = make_url(settings.db_url)
    pg = services["postgres"]["environment"]
    assert url.drivername == "postgresql+psycopg"
    assert (url.host, url.username, url.password, url.database) == (
        "postgres",
        pg["POSTGRES_USER"],
        pg["POSTGRES_PASSWORD"],
        pg["POSTGRES_DB"],
    )
    assert url.port == 5432
    pg_check = " ".join(services["postgres"]["healthcheck"]["test"])
    assert f"-U {pg['POSTGRES_USER']}" in pg_check and f"-d {pg['POSTGRES_DB']}" in pg_check

    # HTTP: listens on all interfaces of the container, published, health-checked there
    assert settings.host == "0.0.0.0"
    assert f"{settings.port}:{settings.port}" in rehab["ports"]
    check = " ".join(rehab["healthcheck"]["test"])
    health = re.search(r"http://[^'\"]+", check)
    assert health is not None
    parts = urlsplit(health.group(0))
    assert parts.port == settings.port and parts.path == "/api/health"
    assert str(settings.viser_port) + ":" + str(settings.viser_port) in rehab["ports"]

    # the data directory is a volume
    assert str(settings.data_dir) == "/data"
    assert any(v.split(":")[1] == "/data" for v in rehab["volumes"])


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
    assert mine.db_url == api.db_url and mine.key_prefix == api.key_prefix
    assert args.zenoh_connect == serve_args(rehab["command"]).zenoh_connect
    assert str(args.data_dir) == "/data"
    shared = {v for v in worker["volumes"]} & {v for v in rehab["volumes"]}
    assert any(v.split(":")[1] == "/data" for v in shared)
    assert worker["depends_on"]["rehab"] == {"condition": "service_healthy"}
