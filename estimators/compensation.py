"""Shoulder displacement, indicator state and compensatory episodes (paper §3.4; contract §3).

Passon et al. 2020, §3.4 ("Detection of Compensatory Motions for Biofeedback"): the estimated
shoulder position is compared with the nominal (therapeutically desired) one; a displacement
beyond ±10 cm is *outside*; the indicator turns orange (*warning*) when the shoulder has been
outside "for longer than a short user-defined duration, which might be chosen as a percentage of
the current cycle duration". For non-repetitive tasks the paper suggests a tolerated time instead
of the per-cycle rule (20 % of their cycles was about 1 s); :class:`EpisodeTracker` reports such
episodes. The per-cycle verdict lives in :mod:`estimators.verdicts`.

Pure numpy. Everything streaming is chunk-invariant: the same samples fed in any chunking give
bit-identical outputs.

Time weighting, used consistently here and in :mod:`estimators.verdicts`: sample ``i`` stands for
the interval ``[t[i], t[i] + min(t[i+1] - t[i], max_hold_s))`` (zero-order hold, capped so that a
data gap is not filled with a stale state). A gap longer than ``max_hold_s`` also breaks an
outside run.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, SupportsFloat, TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray: TypeAlias = NDArray[np.float64]
CodeArray: TypeAlias = NDArray[np.int8]

UNKNOWN = -1
OK = 0
OUTSIDE = 1
WARNING = 2
STATE_NAMES: tuple[str, str, str] = ("ok", "outside", "warning")
"""Contract §3 state names, indexed by code (``OK``, ``OUTSIDE``, ``WARNING``)."""

Norm: TypeAlias = Literal["horizontal", "3d"]


@dataclass(frozen=True, slots=True)
class CompensationParams:
    """Parameters of the compensation rule (contract §4 names where they exist).

    - ``tolerance_m``: displacement beyond which the shoulder is *outside*, m (paper: 0.10).
    - ``max_outside_fraction``: a cycle is compensatory when outside for more than this fraction
      of its duration (paper: 0.20).
    - ``displacement_norm``: ``"horizontal"`` (distance in the robot x-y plane, z is up; the
      top-view circle of the paper's indicator) or ``"3d"``.
    - ``warning_after_s``: tolerated continuous outside time before *warning*, s. ``None``: the
      tolerated time is ``max_outside_fraction`` × the duration of the last completed cycle
      (see :meth:`Indicator.cycle_completed`), ``default_warning_after_s`` before any cycle.
    - ``default_warning_after_s``: s (paper: 20 % of their cycles ≈ 1 s).
    - ``min_coverage``: a cycle is judged only if known states cover at least this fraction of
      its duration.
    - ``max_hold_s``: longest interval one sample stands for, s; longer gaps count as unknown and
      break outside runs. Must exceed the robot sample interval (0.1 s at 10 Hz).
    """

    tolerance_m: float = 0.10
    max_outside_fraction: float = 0.20
    displacement_norm: Norm = "horizontal"
    warning_after_s: float | None = None
    default_warning_after_s: float = 1.0
    min_coverage: float = 0.8
    max_hold_s: float = 0.25

    def __post_init__(self) -> None:
        if not self.tolerance_m > 0.0:
            raise ValueError("tolerance_m must be > 0")
        if not 0.0 <= self.max_outside_fraction <= 1.0:
            raise ValueError("max_outside_fraction must be in [0, 1]")
        if self.displacement_norm not in ("horizontal", "3d"):
            raise ValueError("displacement_norm must be 'horizontal' or '3d'")
        if self.warning_after_s is not None and not self.warning_after_s >= 0.0:
            raise ValueError("warning_after_s must be >= 0 or None")
        if not self.default_warning_after_s >= 0.0:
            raise ValueError("default_warning_after_s must be >= 0")
        if not 0.0 <= self.min_coverage <= 1.0:
            raise ValueError("min_coverage must be in [0, 1]")
        if not self.max_hold_s > 0.0:
            raise ValueError("max_hold_s must be > 0")


def displacement(shoulder: ArrayLike, nominal: ArrayLike, norm: Norm = "horizontal") -> FloatArray:
    """Distance between estimated and nominal shoulder positions (contract §3).

    ``shoulder`` (N,3) m and ``nominal`` (3,) or (N,3) m, robot frame (z up). ``norm``:
    ``"horizontal"`` uses x and y only, ``"3d"`` all three. Returns (N,) m; NaN wherever an
    input component used by the norm is NaN (no estimate, or no nominal yet).
    Elementwise IEEE arithmetic only, so results do not depend on how samples are chunked.
    """
    s = np.asarray(shoulder, dtype=np.float64)
    n = np.asarray(nominal, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError("shoulder must have shape (N, 3)")
    if n.shape not in ((3,), s.shape):
        raise ValueError("nominal must have shape (3,) or (N, 3)")
    d = s - n
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    sq = dx * dx + dy * dy
    if norm == "3d":
        sq = sq + dz * dz
    elif norm != "horizontal":
        raise ValueError("norm must be 'horizontal' or '3d'")
    out: FloatArray = np.sqrt(sq)
    return out


def state_name(code: int) -> str | None:
    """Contract name of a state code; ``None`` for ``UNKNOWN``."""
    return STATE_NAMES[code] if 0 <= code < len(STATE_NAMES) else None


class Indicator:
    """Per-sample indicator state (contract §3; paper §3.4 and Figure 5), streaming.

    ``update(t, displacement)`` classifies each sample:

    - ``UNKNOWN`` (-1) where the displacement is NaN (no estimate or no nominal shoulder yet);
    - ``OK`` (0) where displacement ≤ ``tolerance_m``;
    - ``OUTSIDE`` (1) where displacement > ``tolerance_m``;
    - ``WARNING`` (2) where the sample is outside and the current outside run started more than
      the tolerated duration earlier: ``t[i] - t[run start] > tolerated``. A run is a sequence
      of consecutive outside samples; an ``OK`` or ``UNKNOWN`` sample or a gap longer than
      ``max_hold_s`` ends it.

    Tolerated duration, in order of precedence: the ``tolerated_s`` argument of the call (one
    value for the whole chunk: chunk-invariant only if the caller's value is), else
    ``params.warning_after_s``, else ``max_outside_fraction`` × the duration of the last cycle
    reported with :meth:`cycle_completed` (effective from the boundary's ``detected_at``), else
    ``params.default_warning_after_s``.

    State-change events (contract §7 ``{"type": "state"}``): ``UNKNOWN`` is not a state and is
    transparent for them. An event ``(t, name)`` is emitted at the first known sample ever and
    whenever a known sample's state differs from the previous *known* sample's state; a gap of
    unknown samples between two samples in the same state emits nothing. Consumers therefore
    always hold the latest known state.
    """

    def __init__(self, params: CompensationParams | None = None) -> None:
        self.params = params if params is not None else CompensationParams()
        self._tol_m = self.params.tolerance_m
        self._hold = self.params.max_hold_s
        self._t_last = -math.inf  # time of the last sample seen
        self._run_start: float | None = None  # start of the ongoing outside run
        self._last_known = -9  # code of the last known sample (-9: none yet)
        self._tol = self.params.default_warning_after_s
        self._sched_t: list[float] = []  # pending tolerated-duration changes (effective time)
        self._sched_v: list[float] = []

    @property
    def tolerated_s(self) -> float:
        """Tolerated duration currently in force (before pending changes), s."""
        if self.params.warning_after_s is not None:
            return self.params.warning_after_s
        return self._tol

    def cycle_completed(self, start: float, end: float, effective_t: float | None = None) -> None:
        """Report a completed cycle ``[start, end)`` (s); with ``warning_after_s=None`` the
        tolerated duration becomes ``max_outside_fraction * (end - start)`` for samples with
        ``t >= max(end, effective_t)``. For chunk invariance pass the boundary's
        ``detected_at`` as ``effective_t`` and call this before :meth:`update` of the chunk in
        which the segmenter reported the boundary (segment first, then update the indicator;
        ``update(..., boundaries=...)`` does both). If samples past that time were already
        processed, the change applies from the next sample."""
        if self.params.warning_after_s is not None or not end > start:
            return
        when = end if effective_t is None else max(end, effective_t)
        value = self.params.max_outside_fraction * (end - start)
        i = bisect.bisect_right(self._sched_t, when)
        self._sched_t.insert(i, when)
        self._sched_v.insert(i, value)

    def update(
        self,
        t: ArrayLike,
        displacement: ArrayLike,
        tolerated_s: float | None = None,
        boundaries: Sequence[SupportsFloat] = (),
    ) -> tuple[CodeArray, list[tuple[float, str]]]:
        """Classify a chunk.

        ``t`` (N,) s strictly increasing (also across calls); ``displacement`` (N,) m, NaN for
        no estimate. ``tolerated_s``: override of the tolerated duration for this chunk, s.
        ``boundaries``: convenience; every item with a ``cycle_start`` attribute that is not
        ``None`` (the :class:`estimators.cycles.Boundary` objects) is passed to
        :meth:`cycle_completed` first, with its ``detected_at``. Returns ``codes`` (N,) int8
        and the state-change events ``[(t, "ok" | "outside" | "warning"), ...]`` in time order.
        """
        self._take_boundaries(boundaries)
        if tolerated_s is None:
            tolerated_s = self.params.warning_after_s
        ts = np.asarray(t, dtype=np.float64)
        ds = np.asarray(displacement, dtype=np.float64)
        if ts.shape != ds.shape or ts.ndim != 1:
            raise ValueError("t and displacement must both have shape (N,)")
        changes: list[tuple[float, str]] = []
        codes = [
            self._step(ti, di, tolerated_s, changes)
            for ti, di in zip(ts.tolist(), ds.tolist(), strict=True)
        ]
        return np.array(codes, dtype=np.int8), changes

    def push(
        self,
        t: float,
        displacement: float,
        boundaries: Sequence[SupportsFloat],
        changes: list[tuple[float, str]],
    ) -> int:
        """:meth:`update` of one sample (the live case) as floats: its code; its
        state-change event, if any, is appended to ``changes``."""
        if boundaries:
            self._take_boundaries(boundaries)
        return self._step(t, displacement, self.params.warning_after_s, changes)

    def _take_boundaries(self, boundaries: Sequence[SupportsFloat]) -> None:
        # (SupportsFloat, not float: a compiled build unboxes floats, a Boundary's extras too)
        for b in boundaries:
            cs = getattr(b, "cycle_start", None)
            if cs is not None:
                self.cycle_completed(float(cs), float(b), getattr(b, "detected_at", None))

    # -- tolerated duration per sample ------------------------------------------------------

    def _advance_schedule(self, upto: float) -> None:
        """Apply scheduled changes effective at or before ``upto``."""
        k = bisect.bisect_right(self._sched_t, upto)
        if k:
            self._tol = self._sched_v[k - 1]
            del self._sched_t[:k]
            del self._sched_v[:k]

    def _step(
        self, ti: float, di: float, override: float | None, changes: list[tuple[float, str]]
    ) -> int:
        """One sample's code."""
        if self._sched_t and self._sched_t[0] <= ti:
            self._advance_schedule(ti)
        if di > self._tol_m:  # False for NaN
            run = self._run_start
            if run is None or ti - self._t_last > self._hold:
                run = self._run_start = ti
            code = WARNING if ti - run > (self._tol if override is None else override) else OUTSIDE
        else:
            self._run_start = None
            code = OK if di == di else UNKNOWN
        self._t_last = ti
        if code != self._last_known and code != UNKNOWN:
            self._last_known = code
            changes.append((ti, STATE_NAMES[code]))
        return code


@dataclass(frozen=True, slots=True)
class Episode:
    """A compensatory episode: an outside run that reached *warning* (tolerated-time rule).

    ``start``: time of the run's first outside sample, s; ``end``: end of the run's last sample
    interval (the next sample's time, at most ``max_hold_s`` later), s; ``duration_s = end -
    start``; ``max_displacement_m``: peak displacement over the run (NaN if not given).
    """

    start: float
    end: float
    duration_s: float
    max_displacement_m: float


class EpisodeTracker:
    """Streaming detector of compensatory episodes for non-repetitive tasks (paper §3.4).

    Consumes the :class:`Indicator` codes. An episode is a contiguous outside run (codes
    ``OUTSIDE``/``WARNING``; ended by ``OK``, ``UNKNOWN`` or a gap > ``max_hold_s``) that
    contains at least one ``WARNING`` sample, i.e. it lasted longer than the tolerated duration
    in force; so an episode is reported exactly when the indicator showed orange. It is reported
    by the call that sees the sample ending the run (or by :meth:`flush`).
    """

    def __init__(self, params: CompensationParams | None = None) -> None:
        self.params = params if params is not None else CompensationParams()
        self._hold = self.params.max_hold_s
        self._t_last = -math.inf
        self._start: float | None = None  # ongoing run
        self._warned = False
        self._peak = -math.inf

    def update(
        self, t: ArrayLike, codes: ArrayLike, displacement: ArrayLike | None = None
    ) -> list[Episode]:
        """``t`` (N,) s, ``codes`` (N,) indicator codes, ``displacement`` (N,) m (optional,
        for the peak). Returns the episodes that ended in this chunk."""
        episodes: list[Episode] = []
        tt = np.asarray(t, dtype=np.float64)
        cc = np.asarray(codes, dtype=np.int8)
        n = tt.shape[0]
        if cc.shape != (n,):
            raise ValueError("t and codes must both have shape (N,)")
        dd = np.full(n, np.nan) if displacement is None else np.asarray(displacement, np.float64)
        if dd.shape != (n,):
            raise ValueError("displacement must have shape (N,)")
        for ti, ci, di in zip(tt.tolist(), cc.tolist(), dd.tolist(), strict=True):
            self._step(ti, ci, di, episodes)
        return episodes

    def push(self, t: float, code: int, displacement: float) -> list[Episode]:
        """:meth:`update` of one sample (the live case) as floats."""
        episodes: list[Episode] = []
        if code >= OUTSIDE or self._start is not None:
            self._step(t, code, displacement, episodes)
        else:  # mostly no run is open and none starts
            self._t_last = t
        return episodes

    def _step(self, ti: float, ci: int, di: float, episodes: list[Episode]) -> None:
        """One sample."""
        if ci >= OUTSIDE:
            if self._start is not None and ti - self._t_last > self._hold:
                self._end_run(ti, episodes)
            if self._start is None:
                self._open(ti)
            if ci == WARNING:
                self._warned = True
            if di == di and di > self._peak:
                self._peak = di
        elif self._start is not None:
            self._end_run(ti, episodes)
        self._t_last = ti

    def _end_run(self, ti: float, episodes: list[Episode]) -> None:
        """Close the ongoing run before the sample at ``ti``."""
        t_last = self._t_last
        ep = self._close(t_last + min(ti - t_last, self._hold))
        if ep is not None:
            episodes.append(ep)

    def flush(self) -> list[Episode]:
        """End of data: close an ongoing run at the last sample's time."""
        ep = self._close(self._t_last) if self._start is not None else None
        return [ep] if ep is not None else []

    def _open(self, start: float) -> None:
        self._start = start
        self._warned = False
        self._peak = -math.inf

    def _close(self, end: float) -> Episode | None:
        start = self._start
        self._start = None
        if start is None or not self._warned:
            return None
        peak = self._peak if self._peak > -math.inf else math.nan
        return Episode(start, end, end - start, peak)
