"""Service settings: one object, read from ``REHAB_*`` environment variables or given in code.

``rehab serve`` flags map onto the same fields, and ``docker-compose.yml`` sets them by their
environment names (``REHAB_DATABASE_URL``, ``REHAB_ZENOH_CONNECT``, ...).
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Annotated

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

# Async drivers behind the plain URL schemes an operator is likely to write.
_SCHEME_ALIASES = {
    "sqlite://": "sqlite+aiosqlite://",
    "postgres://": "postgresql+psycopg://",
    "postgresql://": "postgresql+psycopg://",
}


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="REHAB_", extra="ignore")

    # HTTP
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=0, le=65535)
    cors_origins: list[str] = Field(
        default_factory=list, description="Allowed browser origins; empty = CORS off."
    )
    # Hardening (docs/security.md)
    forwarded_allow_ips: Annotated[list[str], NoDecode] = Field(
        default_factory=lambda: ["127.0.0.1"],
        description="Peers (addresses or CIDR) whose X-Forwarded-For/-Proto are believed: "
        "the clinic's TLS proxy, so each workstation gets its own login limits.",
    )
    max_body_bytes: int = Field(default=1 << 20, gt=0, description="Larger requests get 413.")
    api_docs: bool = Field(
        default=False, description="Swagger UI at /api/docs (it loads scripts from a CDN)."
    )

    # Storage
    data_dir: Path = Path("./data")
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL; default: SQLite file rehab.db in data_dir. "
        "PostgreSQL e.g. postgresql+psycopg://user:pw@host/db.",
    )
    database_password_file: Path | None = Field(
        default=None, description="File holding the database password (not in the URL)."
    )

    # Zenoh (contract §1, §6)
    zenoh_listen: str | None = "tcp/127.0.0.1:7447"
    zenoh_connect: str | None = None
    key_prefix: str = "rehab"
    # Security of the device side (docs/security.md)
    zenoh_config: Path | None = Field(
        default=None,
        description="Zenoh JSON5 config (mutual TLS, access control), e.g. made by "
        "scripts/make-clinic-certs.py; its endpoints win over zenoh_listen/zenoh_connect.",
    )
    zenoh_allow_plain: bool = Field(
        default=False,
        description="Allow plain (unauthenticated) TCP/UDP Zenoh on a non-loopback address.",
    )
    admit: list[str] = Field(
        default_factory=list,
        description="Device name globs admitted without approval ('*': every name); others "
        "wait, unregistered, until an administrator admits them.",
    )
    recording_max_bytes: int = Field(
        default=2 << 30, gt=0, description="Per session: device bytes recorded at most."
    )
    ingest_max_bytes: int = Field(
        default=64 << 20,
        gt=0,
        description="All devices' payloads waiting to be processed (--workers N: shared by "
        "the N local workers).",
    )

    # Auth
    secret_key: SecretStr | None = Field(
        default=None,
        description="Token signing key; generated once and kept in data_dir/secret-key if unset.",
    )
    access_token_ttl_s: int = Field(default=8 * 3600, gt=0, description="One clinic shift.")
    overlay_token_ttl_s: int = Field(
        default=12 * 3600, gt=0, description="Upper bound; the link also dies with its session."
    )
    cookie_name: str = "rehab_session"
    cookie_secure: bool = True  # browsers accept Secure cookies on http://localhost too
    admin_username: str = "admin"
    admin_password_file: Path | None = Field(
        default=None,
        description="File holding the first admin's password (e.g. a Docker secret); "
        "random if unset.",
    )
    secret_file: Path | None = Field(
        default=None, description="File holding the signing key (a Docker secret)."
    )
    login_max_failures: int = Field(default=5, gt=0)
    login_window_s: float = Field(default=300.0, gt=0)
    password_hash_concurrency: int = Field(
        default=2, gt=0, description="Argon2 runs at once (each takes ~50 ms of a core)."
    )
    session_idle_s: int = Field(
        default=30 * 60, gt=0, description="A login unused this long is ended."
    )
    ws_recheck_s: float = Field(
        default=30.0, gt=0, description="Open WebSockets re-check their login this often."
    )

    # Live data
    ingest_queue_size: int = Field(default=2048, gt=0)
    ws_queue_size: int = Field(default=256, gt=0)
    ws_max_rate_hz: float = Field(default=30.0, gt=0)
    ws_compression: bool = Field(
        default=False,
        description="permessage-deflate on WebSockets: less traffic for remote dashboards, "
        "but a few per cent of the live loop's CPU at 50 devices.",
    )
    device_offline_after_s: float = Field(default=5.0, gt=0)
    workers: int | None = Field(
        default=None,
        ge=0,
        description="Worker processes the API node starts (`rehab serve --workers`; 0: API "
        "only, remote workers); unset: one process runs everything. `rehab serve` makes it "
        "the core count unless --single-process; in code (create_app: the tests) and in "
        "`rehab demo` it stays unset.",
    )
    snapshot_every_s: float = Field(
        default=30.0,
        ge=0,
        description="A worker snapshots each session's pipeline this often (seconds of the "
        "device's data) beside its recording; a takeover replays only what follows (0: off).",
    )

    # Clinical records: a FHIR R4 server's base URL that receives a session's Bundle on
    # request (POST /api/sessions/{id}/fhir/send); unset = off.
    fhir_url: str | None = None
    fhir_timeout_s: float = Field(default=10.0, gt=0)

    # 3D view (viser, backend/viz.py): its own HTTP/WebSocket port, started on first use.
    viser_enabled: bool = True
    viser_host: str | None = Field(
        default=None,
        description="Default: loopback; browsers reach the view through /api/viz/view/.",
    )
    viser_port: int = Field(default=0, ge=0, le=65535, description="0 = any free port.")

    @field_validator("database_url")
    @classmethod
    def _async_driver(cls, url: str | None) -> str | None:
        if url is None or not url.strip():
            return None
        for plain, driver in _SCHEME_ALIASES.items():
            if url.startswith(plain):
                return driver + url[len(plain) :]
        return url

    @field_validator("forwarded_allow_ips", mode="before")
    @classmethod
    def _comma_list(cls, value: object) -> object:
        """``REHAB_FORWARDED_ALLOW_IPS=172.30.0.10,10.0.0.0/8`` (or a JSON list)."""
        if isinstance(value, str):
            if value.lstrip().startswith("["):
                return json.loads(value)
            return [v.strip() for v in value.split(",") if v.strip()]
        return value

    @property
    def db_url(self) -> str:
        """The effective database URL (the SQLite default lives in data_dir), with the
        password from ``database_password_file`` if one is given."""
        if self.database_url:
            if self.database_password_file is None:
                return self.database_url
            from sqlalchemy.engine import make_url

            password = self.database_password_file.read_text(encoding="utf-8").strip()
            url = make_url(self.database_url).set(password=password)
            return url.render_as_string(hide_password=False)
        return f"sqlite+aiosqlite:///{(self.data_dir / 'rehab.db').resolve().as_posix()}"

    @property
    def admin_credentials_file(self) -> Path:
        return self.data_dir / "admin-credentials.txt"

    @property
    def secret_key_file(self) -> Path:
        return self.data_dir / "secret-key"


@lru_cache
def get_settings() -> Settings:
    """Settings from the environment, read once (the CLI's default; an app keeps its own)."""
    return Settings()
