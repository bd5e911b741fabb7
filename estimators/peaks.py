"""Peaks of a 1-D series by prominence, without ``scipy.signal`` (see :mod:`.filters` for why:
importing it costs ``rehab analyze`` about a second of start-up).

The semantics of ``scipy.signal.find_peaks(x, prominence=floor)`` (tests compare the two):
a peak is a sample higher than its left neighbour and higher than the first different sample
to its right (a flat top counts once, at its middle, rounded down; the first and last samples
are never peaks); its prominence is its height above the higher of the lowest points on either
side before the series rises above the peak again (or ends).
"""

from __future__ import annotations

from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.jit import aot

Array: TypeAlias = NDArray[np.float64]


@aot("i8[::1](f8[::1], f8)")
def _peaks(x: Any, floor: float) -> Any:  # pragma: no cover - compiled
    out = np.empty(len(x), dtype=np.int64)
    count = 0
    i, last = 1, len(x) - 1
    while i < last:
        if x[i - 1] < x[i]:
            ahead = i + 1
            while ahead < last and x[ahead] == x[i]:  # a flat top
                ahead += 1
            if x[ahead] < x[i]:
                peak = (i + ahead - 1) // 2
                h = x[peak]
                left_min = h
                j = peak
                while j >= 0 and x[j] <= h:
                    left_min = min(left_min, x[j])
                    j -= 1
                right_min = h
                j = peak
                while j <= last and x[j] <= h:
                    right_min = min(right_min, x[j])
                    j += 1
                if h - max(left_min, right_min) >= floor:
                    out[count] = peak
                    count += 1
                i = ahead
        i += 1
    return out[:count]


def find_peaks(x: Array, prominence: float) -> NDArray[np.int64]:
    """Indices (ascending) of the peaks of ``x`` (N,) whose prominence is ≥ ``prominence``
    (``x``'s unit)."""
    out: NDArray[np.int64] = _peaks(np.ascontiguousarray(x, dtype=np.float64), float(prominence))
    return out
