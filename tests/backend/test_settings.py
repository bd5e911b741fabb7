"""Settings: defaults, environment names, URL normalisation, the persisted secret."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from pydantic import SecretStr

from backend.auth.secret import load_or_create_secret
from backend.settings import Settings


def test_defaults(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    for name in [n for n in os.environ if n.startswith("REHAB_")]:
        monkeypatch.delenv(name)
    s = Settings()
    assert s.data_dir == Path("data")
    assert s.db_url == f"sqlite+aiosqlite:///{(tmp_path / 'data' / 'rehab.db').as_posix()}"
    assert s.zenoh_listen == "tcp/127.0.0.1:7447" and s.zenoh_connect is None
    assert s.key_prefix == "rehab" and s.ws_max_rate_hz == 30
    assert s.cors_origins == [] and s.cookie_secure


def test_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("REHAB_DATABASE_URL", "postgresql://u:p@db:5432/rehab")
    monkeypatch.setenv("REHAB_ZENOH_CONNECT", "tcp/zenoh:7447")
    monkeypatch.setenv("REHAB_PORT", "9000")
    monkeypatch.setenv("REHAB_CORS_ORIGINS", '["http://localhost:5173"]')
    s = Settings()
    assert s.db_url == "postgresql+psycopg://u:p@db:5432/rehab"
    assert s.zenoh_connect == "tcp/zenoh:7447" and s.port == 9000
    assert s.cors_origins == ["http://localhost:5173"]
    assert Settings(database_url="sqlite:///x.db").db_url == "sqlite+aiosqlite:///x.db"


def test_secret_is_generated_once_and_private(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path / "d")
    key = load_or_create_secret(s)
    assert len(key) >= 32 and load_or_create_secret(s) == key
    assert stat.S_IMODE(s.secret_key_file.stat().st_mode) == 0o600
    assert (
        load_or_create_secret(Settings(data_dir=tmp_path, secret_key=SecretStr("k" * 32)))
        == b"k" * 32
    )
    with pytest.raises(ValueError, match="at least"):
        load_or_create_secret(Settings(data_dir=tmp_path, secret_key=SecretStr("short")))
