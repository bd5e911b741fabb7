"""The token signing key and private files in data_dir."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from backend.settings import Settings

MIN_SECRET_LENGTH = 32  # HS256 wants at least 256 bits of key


def write_private(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` readable by the owner only (0600), also if it existed."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, text.encode("utf-8"))
        os.fsync(fd)
    finally:
        os.close(fd)


def load_or_create_secret(settings: Settings) -> bytes:
    """The configured key (``secret_key``, else the file ``secret_file``: a Docker secret),
    else the one kept in data_dir, else a new one saved there.

    Persisting it keeps therapists logged in across restarts.
    """
    if settings.secret_key is not None:
        key = settings.secret_key.get_secret_value()
    elif settings.secret_file is not None:
        key = settings.secret_file.read_text(encoding="utf-8").strip()
    else:
        path = settings.secret_key_file
        if not path.exists():
            settings.data_dir.mkdir(parents=True, exist_ok=True)
            write_private(path, secrets.token_urlsafe(48) + "\n")
        key = path.read_text(encoding="utf-8").strip()
    if len(key) < MIN_SECRET_LENGTH:
        raise ValueError(f"secret key must be at least {MIN_SECRET_LENGTH} characters")
    return key.encode("utf-8")
