"""Which device names the service takes data from.

A name is admitted when it matches a ``--admit`` glob (``REHAB_ADMIT``; ``*`` admits every
name) or an administrator admitted it (its registry row, kept across restarts). Anything
else is *pending*: its messages are dropped and counted, nothing is written to the
database, and the pending list is bounded (least recently seen names fall out), so a flood
of invented names costs a bounded amount of memory and nothing persistent.
"""

from __future__ import annotations

import fnmatch
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

MAX_PENDING = 256  # names shown to the administrator; beyond it the oldest are forgotten


@dataclass
class Pending:
    first_seen: float
    last_seen: float
    messages: int = 0


class Admission:
    def __init__(self, globs: Iterable[str] = (), max_pending: int = MAX_PENDING) -> None:
        self.globs = tuple(globs)
        self._all = "*" in self.globs
        self.admitted: set[str] = set()
        self.pending: OrderedDict[str, Pending] = OrderedDict()
        self.max_pending = max_pending
        self.refused = 0  # messages (and liveliness tokens) of names not admitted
        self.forgotten = 0  # pending names dropped to keep the list bounded

    def allows(self, name: str) -> bool:
        if name in self.admitted or self._all:
            return True
        return any(fnmatch.fnmatchcase(name, g) for g in self.globs)

    def refuse(self, name: str, now: float, n: int = 1) -> None:
        """Count ``n`` messages of a name that is not admitted (in memory only)."""
        self.refused += n
        p = self.pending.get(name)
        if p is None:
            if len(self.pending) >= self.max_pending:
                self.pending.popitem(last=False)
                self.forgotten += 1
            p = self.pending[name] = Pending(now, now)
        else:
            self.pending.move_to_end(name)
        p.last_seen = now
        p.messages += n

    def admit(self, name: str) -> None:
        self.admitted.add(name)
        self.pending.pop(name, None)

    def remove(self, name: str) -> None:
        """No longer admitted by the administrator (a matching glob still admits it)."""
        self.admitted.discard(name)

    def snapshot(self) -> dict[str, Any]:
        return {
            "globs": list(self.globs),
            "refused_messages": self.refused,
            "forgotten": self.forgotten,
            "pending": [
                {
                    "name": n,
                    "first_seen": p.first_seen,
                    "last_seen": p.last_seen,
                    "messages": p.messages,
                }
                for n, p in reversed(self.pending.items())
            ],
        }
