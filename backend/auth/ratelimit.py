"""Login throttling, in memory: failed attempts per (username, client) and per client.

Enough for one service process; counters reset on restart, which is acceptable for a
clinic LAN service (the KDF already makes each guess expensive).
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque

MAX_KEYS = 10_000  # bounds memory under a spray of random usernames


class LoginLimiter:
    def __init__(self, max_failures: int, window_s: float, per_client_factor: int = 4) -> None:
        self.max_failures = max_failures
        self.per_client_max = max_failures * per_client_factor
        self.window_s = window_s
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()

    def _recent(self, key: str, now: float) -> deque[float]:
        times = self._failures.get(key)
        if times is None:
            return deque()
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def _keys(self, username: str, client: str) -> tuple[str, str]:
        return f"u:{username.lower()}|{client}", f"c:{client}"

    def retry_after(self, username: str, client: str) -> float | None:
        """Seconds to wait if this attempt must be refused, else ``None``."""
        now = time.monotonic()
        user_key, client_key = self._keys(username, client)
        waits = []
        for key, limit in ((user_key, self.max_failures), (client_key, self.per_client_max)):
            times = self._recent(key, now)
            if len(times) >= limit:
                waits.append(times[0] + self.window_s - now)
        return max(waits) if waits else None

    def failed(self, username: str, client: str) -> None:
        now = time.monotonic()
        for key in self._keys(username, client):
            times = self._failures.pop(key, None) or deque()
            times.append(now)
            self._failures[key] = times  # most recent last, for eviction
        while len(self._failures) > MAX_KEYS:
            self._failures.popitem(last=False)

    def succeeded(self, username: str, client: str) -> None:
        self._failures.pop(self._keys(username, client)[0], None)
