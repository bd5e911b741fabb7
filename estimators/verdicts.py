"""Per-cycle verdicts of the compensation rule (paper §3.4; contract §3, §7).

Passon et al. 2020, §3.4: shoulder displacements beyond the tolerance are allowed "for up to 20%
of an iteration during repetitive movement training"; "each iteration is examined when it is
completed" and the verdict is signalled at once. :class:`CycleJudge` joins the indicator codes
(:class:`estimators.compensation.Indicator`) with the cycle boundaries
(:class:`estimators.cycles.CycleSegmenter`).

Time weighting (same as :mod:`estimators.compensation`): sample ``i`` stands for ``[t[i],
t[i] + min(t[i+1] - t[i], max_hold_s))``, clipped to the cycle ``[start, end)``; the sample at
or before ``start`` contributes the part of its interval after ``start``. Sums use
``math.fsum`` (correctly rounded), so verdicts are bit-identical for any chunking.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import SupportsFloat

import numpy as np
from numpy.typing import ArrayLike

from estimators.buffers import RowBuffer
from estimators.compensation import CompensationParams, FloatArray

_FLUSH = 256  # rows reach the numpy buffer this many at a time (or to be judged)


@dataclass(frozen=True, slots=True)
class CycleVerdict:
    """The verdict on one completed cycle ``[start, end)``.

    - ``start``, ``end``: s.
    - ``outside_fraction``: time outside tolerance (``OUTSIDE`` or ``WARNING``) / ``end - start``;
      unknown time never counts as outside.
    - ``compensatory``: ``outside_fraction > max_outside_fraction``; ``None`` when the cycle is
      not judged (``coverage < min_coverage``).
    - ``coverage``: time with a known state / ``end - start``.
    - ``outside_s``: time outside, s (``outside_s / (coverage * duration)`` is the fraction of the
      known time, if a consumer prefers that).
    - ``max_displacement_m``: peak displacement over the known samples that contribute time to
      the cycle, m; ``mean_displacement_m``: their time-weighted mean, m (NaN without
      displacement input or known samples).
    - ``source``: where the end boundary came from (``"path"``, ``"reach"``, ``"event"``, or
      ``""`` for plain float boundaries).
    """

    start: float
    end: float
    outside_fraction: float
    compensatory: bool | None
    coverage: float
    outside_s: float
    max_displacement_m: float
    mean_displacement_m: float
    source: str = ""

    @property
    def duration_s(self) -> float:
        return self.end - self.start


class CycleJudge:
    """Streaming per-cycle verdicts.

    ``update(t, codes, boundaries, displacement)``: ``t`` (N,) s, ``codes`` (N,) indicator
    codes, ``boundaries`` new cycle boundaries (s, strictly increasing across calls; others
    are ignored), ``displacement`` (N,) m optional. A boundary that carries ``cycle_start``
    (:class:`estimators.cycles.Boundary`) completes the cycle ``[cycle_start, b)`` or, if
    ``cycle_start`` is ``None``, only opens one; a plain float completes the cycle from the
    previous boundary. Cycles longer than ``max_cycle_s`` are dropped (no verdict). A cycle is
    judged, and returned, by the call in which a sample with ``t >= end`` has been seen; the
    samples are buffered from the earliest cycle start still needed, and at least the last
    ``max_cycle_s + history_s`` seconds (a cycle still to come may start that early), so
    boundaries may arrive late by up to ``history_s`` (e.g. a ``cycle_start`` event received
    after later robot samples) without changing the verdict, however the rows are chunked.
    """

    def __init__(
        self,
        params: CompensationParams | None = None,
        max_cycle_s: float = 30.0,
        history_s: float = 5.0,
    ) -> None:
        self.params = params if params is not None else CompensationParams()
        self.max_cycle_s = max_cycle_s
        self.history_s = history_s
        self._buf = RowBuffer(3)  # t, code, displacement
        # columns t, code, displacement of the rows of small calls as floats, moved into
        # _buf in blocks: a numpy row write costs more than the rest of a live call
        self._cols: tuple[list[float], list[float], list[float]] = ([], [], [])
        self._data_t = -math.inf
        self._last_b: float | None = None
        self._pending: list[tuple[float, float, str]] = []  # (start, end, source)

    def update(
        self,
        t: ArrayLike,
        codes: ArrayLike,
        boundaries: Sequence[SupportsFloat] = (),
        displacement: ArrayLike | None = None,
    ) -> list[CycleVerdict]:
        tl: list[float] = np.asarray(t, dtype=np.float64).tolist()
        n = len(tl)
        cl: list[float] = np.asarray(codes, dtype=np.float64).tolist()
        dl: list[float] = (
            [math.nan] * n
            if displacement is None
            else np.asarray(displacement, dtype=np.float64).tolist()
        )
        if len(cl) != n or len(dl) != n:
            raise ValueError("t, codes and displacement must have shape (N,)")
        col_t, col_c, col_d = self._cols
        col_t.extend(tl)
        col_c.extend(cl)
        col_d.extend(dl)
        if n:
            self._data_t = tl[-1]
        for b in boundaries:
            self._add_boundary(b)
        if (self._pending and self._pending[0][1] <= self._data_t) or len(col_t) >= _FLUSH:
            return self._after_rows()
        return []

    def push(
        self, t: float, code: int, displacement: float, boundaries: Sequence[SupportsFloat]
    ) -> list[CycleVerdict]:
        """:meth:`update` of one row (the live case) as floats."""
        col_t, col_c, col_d = self._cols
        col_t.append(t)
        col_c.append(code)
        col_d.append(displacement)
        self._data_t = t
        for b in boundaries:
            self._add_boundary(b)
        if (self._pending and self._pending[0][1] <= t) or len(col_t) >= _FLUSH:
            return self._after_rows()
        return []

    def _flush(self) -> None:
        """Move the rows gathered as floats into the buffer."""
        if self._cols[0]:
            self._buf.append(np.array(self._cols, dtype=np.float64).T)
            self._cols = ([], [], [])

    def _after_rows(self) -> list[CycleVerdict]:
        """Judge the cycles the data has reached, then forget rows no longer needed."""
        self._flush()
        verdicts: list[CycleVerdict] = []
        if self._pending and self._pending[0][1] <= self._data_t:
            view = self._buf.view()
            while self._pending and self._pending[0][1] <= self._data_t:
                start, end, source = self._pending.pop(0)
                verdicts.append(self._judge(view, start, end, source))
        self._trim()
        return verdicts

    def _add_boundary(self, b: SupportsFloat) -> None:
        # (SupportsFloat, not float: a compiled build unboxes floats, a Boundary's extras too)
        bt = float(b)
        if not math.isfinite(bt) or (self._last_b is not None and bt <= self._last_b):
            return
        start = getattr(b, "cycle_start", self._last_b)
        self._last_b = bt
        if start is None or not 0.0 < bt - start <= self.max_cycle_s:
            return
        self._pending.append((float(start), bt, str(getattr(b, "source", ""))))

    def _trim(self) -> None:
        # a boundary still to come may open its cycle up to max_cycle_s before it (the first
        # cycle, or a detector restart's reference time, can lie before the last boundary
        # seen): keep that much, and history_s more for the boundary's detection delay.
        # Dropping less than a cycle made a chunked run judge fewer rows than one call.
        keep = self._data_t - self.history_s - self.max_cycle_s
        for start, _, _ in self._pending:
            keep = min(keep, start)
        buf = self._buf
        # drop in batches of 64 rows: rows kept longer change no verdict, and the check
        # costs no numpy call in the usual case
        if len(buf) < 66 or buf.a.item(buf.lo + 64, 0) > keep:
            return
        bt = buf.view()[:, 0]
        buf.drop(int(np.searchsorted(bt, keep, side="right")) - 1)

    def _judge(self, view: FloatArray, start: float, end: float, source: str) -> CycleVerdict:
        p = self.params
        tb = view[:, 0]
        j0 = max(int(np.searchsorted(tb, start, side="right")) - 1, 0)
        j1 = int(np.searchsorted(tb, end, side="left"))  # first sample at/after end (exists)
        ti = tb[j0:j1]
        tn = tb[j0 + 1 : j1 + 1]
        lo = np.maximum(ti, start)
        hi = np.minimum(np.minimum(tn, ti + p.max_hold_s), end)
        w = np.maximum(hi - lo, 0.0)
        code = view[j0:j1, 1]
        disp = view[j0:j1, 2]
        known = code >= 0.0
        outside_s = math.fsum(w[code >= 1.0].tolist())
        known_s = math.fsum(w[known].tolist())
        duration = end - start
        fraction = outside_s / duration
        coverage = known_s / duration
        compensatory = None if coverage < p.min_coverage else fraction > p.max_outside_fraction
        m = known & (w > 0.0) & ~np.isnan(disp)
        peak = mean = math.nan
        if m.any():
            dm = disp[m]
            wm = w[m]
            peak = float(dm.max())
            mean = math.fsum((wm * dm).tolist()) / math.fsum(wm.tolist())
        return CycleVerdict(
            start=start,
            end=end,
            outside_fraction=fraction,
            compensatory=compensatory,
            coverage=coverage,
            outside_s=outside_s,
            max_displacement_m=peak,
            mean_displacement_m=mean,
            source=source,
        )
