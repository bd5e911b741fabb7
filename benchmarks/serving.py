"""What the benchmarks that start ``rehab serve`` share: waiting until it answers."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import httpx


def wait_healthy(
    proc: subprocess.Popen[bytes] | subprocess.Popen[str],
    url: str,
    timeout: float = 60.0,
    log: Path | None = None,
) -> None:
    """Until ``url``'s ``/api/health`` answers 200; exits with the service's log (if given)
    when the process ends first or ``timeout`` seconds pass."""
    deadline = time.monotonic() + timeout
    while True:
        if proc.poll() is not None:
            raise SystemExit("rehab serve exited" + (f":\n{log.read_text()}" if log else ""))
        try:
            if httpx.get(url + "/api/health", timeout=1).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        if time.monotonic() > deadline:
            raise SystemExit("rehab serve did not start")
        time.sleep(0.2)
