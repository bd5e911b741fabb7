"""A growable FIFO of float64 rows: amortised O(1) append and drop-front.

Streaming stages append a few rows per message and forget old ones; concatenating numpy
arrays for that would copy the whole buffer on every message.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

FloatArray: TypeAlias = NDArray[np.float64]


class RowBuffer:
    """FIFO of float64 rows (``width`` columns). :meth:`view` and :meth:`col` return views
    that are valid until the next :meth:`append`/:meth:`push`."""

    def __init__(self, width: int, capacity: int = 256) -> None:
        self.a = np.empty((max(capacity, 16), width))
        self.lo = 0
        self.hi = 0

    def __len__(self) -> int:
        return self.hi - self.lo

    def _reserve(self, n: int) -> None:
        live = self.hi - self.lo
        if live + n > self.a.shape[0] // 2:
            grown = np.empty((2 * (live + n), self.a.shape[1]))
            grown[:live] = self.a[self.lo : self.hi]
            self.a = grown
        else:
            self.a[:live] = self.a[self.lo : self.hi]
        self.lo, self.hi = 0, live

    def append(self, rows: FloatArray) -> None:
        n = rows.shape[0]
        if self.hi + n > self.a.shape[0]:
            self._reserve(n)
        self.a[self.hi : self.hi + n] = rows
        self.hi += n

    def grow(self, n: int) -> FloatArray:
        """Append ``n`` uninitialised rows and return them as a view to fill in place (one
        copy less than building a block and appending it)."""
        if self.hi + n > self.a.shape[0]:
            self._reserve(n)
        self.hi += n
        return self.a[self.hi - n : self.hi]

    def push(self, row: Sequence[float]) -> None:
        """Append one row."""
        if self.hi >= self.a.shape[0]:
            self._reserve(1)
        self.a[self.hi] = row
        self.hi += 1

    def view(self) -> FloatArray:
        return self.a[self.lo : self.hi]

    def cols(self, lo: int, hi: int) -> FloatArray:
        """Columns ``lo:hi`` of the live rows, (n, hi − lo)."""
        return self.a[self.lo : self.hi, lo:hi]

    def col(self, j: int) -> FloatArray:
        """Column ``j`` of the live rows, (n,)."""
        return self.a[self.lo : self.hi, j]

    def row(self, i: int) -> list[float]:
        """Live row ``i`` as floats."""
        out: list[float] = self.a[self.lo + i].tolist()
        return out

    def drop(self, k: int) -> None:
        """Remove the ``k`` oldest rows."""
        self.lo = min(self.lo + max(k, 0), self.hi)


class RowQueue:
    """FIFO of float rows that arrive one at a time (tuples, the live case) or in blocks
    ((n, width) arrays, a batch), taken out in order as one array."""

    def __init__(self, width: int) -> None:
        self.width = width
        self._items: deque[tuple[float, ...] | FloatArray] = deque()
        self._off = 0  # rows of the first block already taken

    def push(self, row: tuple[float, ...]) -> None:
        self._items.append(row)

    def append(self, block: FloatArray) -> None:
        if len(block):
            self._items.append(block)

    def take_block(self, n: int) -> FloatArray:
        """The ``n`` oldest rows as one (n, width) array, removed."""
        parts: list[FloatArray] = []
        rows: list[tuple[float, ...]] = []  # consecutive single rows, converted together
        got = 0
        items = self._items
        while got < n:
            item = items[0]
            if isinstance(item, tuple):
                rows.append(item)
                items.popleft()
                got += 1
                continue
            if rows:
                parts.append(np.array(rows, dtype=np.float64))
                rows = []
            k = min(n - got, len(item) - self._off)
            parts.append(item[self._off : self._off + k])
            got += k
            self._off += k
            if self._off == len(item):
                items.popleft()
                self._off = 0
        if rows:
            parts.append(np.array(rows, dtype=np.float64))
        if not parts:
            return np.empty((0, self.width))
        return parts[0] if len(parts) == 1 else np.concatenate(parts)
