"""Login throttling, in memory: attempts per (username, client), per account and per client.

An attempt is counted when it starts, before the password is verified: requests arriving
together cannot all read the counter before any of them has failed. A successful login
takes its attempt back. Three limits hold at once:

- (username, client): ``max_failures`` — the ordinary lock-out of one workstation;
- the account, from any address: ``max_failures × per_account_factor`` — a guesser spread
  over many addresses;
- the client, over any usernames: ``max_failures × per_client_factor`` — a password spray.

"client" is the address the app believes (``forwarded_allow_ips``: behind the clinic's TLS
proxy, each workstation's own). Counters reset on restart, which is acceptable for a clinic
LAN service (the KDF already makes each guess expensive).
"""

from __future__ import annotations

import contextlib
import time
from collections import OrderedDict, deque

MAX_KEYS = 10_000  # bounds memory under a spray of random usernames


class LoginLimiter:
    def __init__(
        self,
        max_failures: int,
        window_s: float,
        per_client_factor: int = 4,
        per_account_factor: int = 4,
    ) -> None:
        self.max_failures = max_failures
        self.per_client_max = max_failures * per_client_factor
        self.per_account_max = max_failures * per_account_factor
        self.window_s = window_s
        self._attempts: OrderedDict[str, deque[float]] = OrderedDict()

    def _recent(self, key: str, now: float) -> deque[float]:
        times = self._attempts.get(key)
        if times is None:
            return deque()
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def _limits(self, username: str, client: str) -> tuple[tuple[str, int], ...]:
        user = username.lower()
        return (
            (f"u:{user}|{client}", self.max_failures),
            (f"a:{user}", self.per_account_max),
            (f"c:{client}", self.per_client_max),
        )

    def retry_after(self, username: str, client: str) -> float | None:
        """Seconds to wait if an attempt now must be refused, else ``None``."""
        now = time.monotonic()
        waits = []
        for key, limit in self._limits(username, client):
            times = self._recent(key, now)
            if len(times) >= limit:
                waits.append(times[0] + self.window_s - now)
        return max(waits) if waits else None

    def attempt(self, username: str, client: str) -> tuple[float | None, float]:
        """Count an attempt unless refused: ``(retry_after, stamp)``.

        ``retry_after`` is ``None`` when the attempt may go on (it is counted already);
        ``stamp`` identifies it for :meth:`succeeded`. Check and count happen without an
        ``await`` in between, so concurrent requests see each other's attempts.
        """
        wait = self.retry_after(username, client)
        now = time.monotonic()
        if wait is not None:
            return wait, now
        for key, _ in self._limits(username, client):
            times = self._attempts.pop(key, None) or deque()
            times.append(now)
            self._attempts[key] = times  # most recent last, for eviction
        while len(self._attempts) > MAX_KEYS:
            self._attempts.popitem(last=False)
        return None, now

    def failed(self, username: str, client: str) -> None:
        """Count a failure that was not announced by :meth:`attempt` (tests, tools)."""
        self.attempt(username, client)

    def succeeded(self, username: str, client: str, stamp: float | None = None) -> None:
        """The right password: this workstation's failures are forgotten, and the attempt
        ``stamp`` no longer counts against the account or the client."""
        keys = self._limits(username, client)
        self._attempts.pop(keys[0][0], None)
        if stamp is None:
            return
        for key, _ in keys[1:]:
            times = self._attempts.get(key)
            if times is not None:
                with contextlib.suppress(ValueError):
                    times.remove(stamp)
