"""Service settings: one object, read from ``REHAB_*`` environment variables or given in code.

``rehab serve`` flags map onto the same fields, and ``docker-compose.yml`` sets them by their
environment names (``REHAB_DATABASE_URL``, ``REHAB_ZENOH_CONNECT``, ...).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

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

    # Storage
    data_dir: Path = Path("./data")
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL; default: SQLite file rehab.db in data_dir. "
        "PostgreSQL e.g. postgresql+psycopg://user:pw@host/db.",
    )

    # Zenoh (contract §1, §6)
    zenoh_listen: str | None = "tcp/127.0.0.1:7447"
    zenoh_connect: str | None = None
    key_prefix: str = "rehab"

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
    login_max_failures: int = Field(default=5, gt=0)
    login_window_s: float = Field(default=300.0, gt=0)

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
        "only, remote workers); unset: one process runs everything (tests, the demo).",
    )

    # 3D view (viser, backend/viz.py): its own HTTP/WebSocket port, started on first use.
    viser_enabled: bool = True
    viser_host: str | None = Field(default=None, description="Default: the API's host.")
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

    @property
    def db_url(self) -> str:
        """The effective database URL (the SQLite default lives in data_dir)."""
        if self.database_url:
            return self.database_url
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
