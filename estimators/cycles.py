"""Cycle segmentation of cyclic upper-limb tasks from the robot's wrist cuff (paper §3.4).

The paper judges every iteration of a repetitive task "when it is completed" (Passon et al.
2020, §3.4) and uses the game's iterations; this module finds the iterations when the game does
not send them. Three sources of boundaries:

- ``"path"``: closed paths (circles, rectangles...). The phase of the wrist around the causal
  running centre of its horizontal path (mean over the last ``centre_window_s`` of the samples
  where the wrist moves, so rests do not pull it); a boundary each time the unwrapped phase
  completes another full turn in the turning direction (see ``_PathDetector``).
- ``"reach"``: back-and-forth reaching. The wrist projected on the principal horizontal axis of
  the recent motion; a boundary each time the wrist returns to the near end (Schmitt trigger on
  the projection, thresholds from the previous cycle's range).
- ``"events"``: contract ``cycle_start`` events (:meth:`CycleSegmenter.add_event`).
- ``"auto"``: ``"path"`` until the first ``cycle_start`` event is received, events only from
  then on (samples with ``t`` before that event's time still go to the path detector).

Streaming and chunk invariance: every detector is a small state machine over the samples whose
per-sample quantities are computed with elementwise IEEE arithmetic, sequential accumulations
(``np.add.accumulate`` from the carried state) and ``math.atan2``; so any chunking of the same
samples yields bit-identical boundaries (tests check this with hypothesis).

Boundaries are :class:`Boundary` objects, i.e. ``float`` times (s) that also carry the start of
the cycle they complete (``None`` after a restart: too long, too short, unreliable phase, mode
switch), so a consumer that only needs times can treat them as floats.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass
from typing import Literal, TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.boundary import Boundary as Boundary  # re-exported: its home until now
from estimators.boundary import Source

FloatArray: TypeAlias = NDArray[np.float64]
Mode: TypeAlias = Literal["auto", "path", "events", "reach"]

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class CycleParams:
    """Cycle segmentation parameters. Times in s, lengths in m, angles in rad.

    - ``mode``: ``"auto"`` (path, then events once a ``cycle_start`` event arrives), ``"path"``,
      ``"reach"`` or ``"events"``.
    - ``centre_window_s``: the path centre (and, for reach, the principal axis) is the causal
      running mean (covariance) of the wrist's horizontal position over this long.
    - ``min_cycle_s`` / ``max_cycle_s``: a cycle outside these bounds is not reported; the
      detector restarts (the next boundary only opens a cycle). Events closer than
      ``min_cycle_s`` to the previous event boundary are ignored; an event gap longer than
      ``max_cycle_s`` opens a new cycle without closing one.
    - ``max_gap_s``: usable samples further apart than this (data gap, or the path detector's
      radius gate during a rest) restart the detector.
    - ``min_radius_m`` (path): samples closer than this to the centre carry no usable phase.
    - ``max_phase_step_rad`` (path): a larger phase step between consecutive usable samples makes
      the unwrapped phase ambiguous (e.g. a straight line through the centre): restart.
    - ``reach_return_fraction`` / ``reach_arm_fraction`` (reach): Schmitt trigger on the projection
      ``p``; armed once ``p`` is beyond ``min + arm_fraction × range``, a boundary when it comes
      back below ``min + return_fraction × range`` (range and min of ``p`` over the previous
      cycle; running since the (re)start for the first one).
    - ``min_range_m`` (reach): no boundaries while the range of ``p`` is below this.
    - ``max_axis_turn_rad`` (reach): the principal axis turning further than this from the
      axis at the (re)start restarts the detector (the task changed).
    - ``still_radius_m`` / ``still_window_s``: a sample is *moving* if the wrist is more than
      ``still_radius_m`` (horizontal) from where it was ``still_window_s`` earlier. Only moving
      samples enter the running centre and covariance, so rests and pauses do not pull the
      centre; after a rest longer than ``centre_window_s`` the window is empty and the detector
      restarts when motion resumes.
    """

    mode: Mode = "auto"
    centre_window_s: float = 10.0
    min_cycle_s: float = 1.0
    max_cycle_s: float = 30.0
    max_gap_s: float = 1.0
    min_radius_m: float = 0.03
    max_phase_step_rad: float = 1.5
    reach_return_fraction: float = 0.25
    reach_arm_fraction: float = 0.6
    min_range_m: float = 0.05
    max_axis_turn_rad: float = math.radians(60.0)
    still_radius_m: float = 0.02
    still_window_s: float = 0.5

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "path", "events", "reach"):
            raise ValueError("mode must be one of 'auto', 'path', 'events', 'reach'")
        if not self.centre_window_s > 0.0:
            raise ValueError("centre_window_s must be > 0")
        if not 0.0 <= self.min_cycle_s < self.max_cycle_s:
            raise ValueError("need 0 <= min_cycle_s < max_cycle_s")
        if not self.max_gap_s > 0.0:
            raise ValueError("max_gap_s must be > 0")
        if not self.min_radius_m > 0.0:
            raise ValueError("min_radius_m must be > 0")
        if not 0.0 < self.max_phase_step_rad < math.pi:
            raise ValueError("max_phase_step_rad must be in (0, pi)")
        if not 0.0 < self.reach_return_fraction < self.reach_arm_fraction < 1.0:
            raise ValueError("need 0 < reach_return_fraction < reach_arm_fraction < 1")
        if not self.min_range_m > 0.0:
            raise ValueError("min_range_m must be > 0")
        if not 0.0 < self.max_axis_turn_rad < math.pi / 2:
            raise ValueError("max_axis_turn_rad must be in (0, pi/2)")
        if not (self.still_radius_m > 0.0 and self.still_window_s > 0.0):
            raise ValueError("still_radius_m and still_window_s must be > 0")


class _MovingWindow:
    """Exact causal running means over the *moving* samples of a time window, streaming.

    A sample ``i`` is moving if its x-y position is more than ``still_radius_m`` from the
    position of the last sample at or before ``t[i] - still_window_s`` (not moving if there is
    none). For each sample the mean of ``vals`` over the moving samples with
    ``t >= t[i] - centre_window_s`` (including ``i``) comes from exclusive prefix sums
    accumulated sequentially since the start, so the result does not depend on chunking.
    One sample at a time (:meth:`step`, written out: this runs for every live sample); the
    history rows are float tuples in deques.
    """

    def __init__(self, p: CycleParams) -> None:
        self._w = p.centre_window_s
        self._lag = p.still_window_s
        self._r2 = p.still_radius_m * p.still_radius_m
        self._total = [0.0] * 6  # moving count, then the sums of x, y, x², y², x y
        # the last position at or before t - still_window_s (None: none yet), the later
        # ones (t, x, y), and the exclusive prefix sums of [moving, moving * vals] (t first)
        self._anchor: tuple[float, ...] | None = None
        self._pos_q: deque[tuple[float, ...]] = deque()
        self._h_q: deque[tuple[float, ...]] = deque()

    def step(self, t: float, x: float, y: float) -> tuple[float, float, float, float, float, float]:
        """One sample: the five means of ``vals = (x, y, x², y², x y)`` (the path detector's
        centre is the first two, the reach detector's axis all five) and the count (the means
        NaN if it is 0)."""
        pos = self._pos_q
        pos.append((t, x, y))
        lim = t - self._lag
        a: tuple[float, ...] | None
        if pos[0][0] <= lim:
            a = pos.popleft()
            while pos and pos[0][0] <= lim:
                a = pos.popleft()
            self._anchor = a
        else:
            a = self._anchor
        m = 0.0
        if a is not None:
            dx = x - a[1]
            dy = y - a[2]
            if dx * dx + dy * dy > self._r2:
                m = 1.0
        hist = self._h_q
        c0, s0, s1, s2, s3, s4 = self._total
        hist.append((t, c0, s0, s1, s2, s3, s4))
        lim = t - self._w
        pk = hist[0]
        while pk[0] < lim:
            hist.popleft()
            pk = hist[0]
        c0 += m
        s0 += x * m
        s1 += y * m
        s2 += x * x * m
        s3 += y * y * m
        s4 += x * y * m
        self._total = [c0, s0, s1, s2, s3, s4]
        count = c0 - pk[1]
        if count > 0.0:
            return (
                (s0 - pk[2]) / count,
                (s1 - pk[3]) / count,
                (s2 - pk[4]) / count,
                (s3 - pk[5]) / count,
                (s4 - pk[6]) / count,
                count,
            )
        nan = math.nan
        return nan, nan, nan, nan, nan, count


class _Detector:
    """Shared bookkeeping of the motion-based detectors: cycle bounds, restarts; samples are
    processed one by one (:meth:`step`)."""

    source: Source = "path"

    def __init__(self, p: CycleParams) -> None:
        self.p = p
        self.last_b: float | None = None  # last emitted boundary of the current sequence
        self.ref_t = 0.0  # time the current sequence (re)started
        self.origin: tuple[float, float] | None = None  # first sample, for numerical range

    def accept(self, b: float, t_now: float, out: list[Boundary]) -> bool:
        """Emit a boundary at ``b``, seen at the sample ``t_now``, if the cycle it closes is
        within bounds; False: restart."""
        p = self.p
        if self.last_b is None:
            if b - self.ref_t < p.min_cycle_s:
                return False
            out.append(Boundary(b, None, self.source, t_now))
        else:
            d = b - self.last_b
            if d < p.min_cycle_s or d > p.max_cycle_s:
                return False
            out.append(Boundary(b, self.last_b, self.source, t_now))
        self.last_b = b
        return True

    def anchor(self) -> float:
        return self.last_b if self.last_b is not None else self.ref_t

    def update(self, t: FloatArray, xy: FloatArray) -> list[Boundary]:
        """``t`` (n,) s, ``xy`` (n,2) m -> new boundaries."""
        n = t.shape[0]
        if n == 0:
            return []
        if self.origin is None:
            self.origin = (float(xy[0, 0]), float(xy[0, 1]))
        out: list[Boundary] = []
        ox, oy = self.origin
        for ti, (xi, yi) in zip(t.tolist(), xy.tolist(), strict=True):
            self.step(ti, xi - ox, yi - oy, out)
        return out

    def step(self, t: float, x: float, y: float, out: list[Boundary]) -> None:
        raise NotImplementedError


class _PathDetector(_Detector):
    """Phase of the wrist around the running centre of its horizontal path.

    Per sample ``i``: centre ``c_i`` = mean x-y of the moving samples of ``[t_i -
    centre_window_s, t_i]``; ``v_i = wrist_i - c_i``; usable if ``|v_i| >= min_radius_m``;
    phase ``atan2(v_y, v_x)`` unwrapped over usable samples (steps wrapped to (-pi, pi]).
    A sequence (re)starts at a usable sample with reference phase ``Phi_ref``. The first
    boundary is where the unwrapped phase first reaches ``Phi_ref ± 2 pi`` (this sets the
    turning direction ``dir``); boundary ``k`` is where it reaches ``Phi_ref + dir 2 pi (k+1)``,
    linearly interpolated in time between the two usable samples around the crossing. The
    levels only move forward, 2 pi apart, so jitter of the phase around a level cannot produce
    a second boundary (2 pi hysteresis); turning backwards delays the next boundary until the
    lost phase is made up (or the timeout restarts). Restarts: first usable sample, a phase
    step > ``max_phase_step_rad``, usable samples more than ``max_gap_s`` apart, no boundary
    within ``max_cycle_s`` (timeout, checked at usable samples), a turn shorter than
    ``min_cycle_s``.
    """

    source: Source = "path"

    def __init__(self, p: CycleParams) -> None:
        super().__init__(p)
        self._win = _MovingWindow(p)
        self._r2min = p.min_radius_m * p.min_radius_m
        self._prev: tuple[float, float, float] | None = None  # last usable (t, phi, Phi)
        self._ref_phi = 0.0  # unwrapped phase at the (re)start
        self._dir = 0  # +1 counter-clockwise, -1 clockwise, 0 not yet known
        self._turns = 0  # levels passed since the (re)start

    def _restart(self, t: float, phi: float) -> None:
        self.ref_t = t
        self._ref_phi = phi
        self._dir = 0
        self._turns = 0
        self.last_b = None

    def _level(self) -> float:
        return self._ref_phi + self._dir * TWO_PI * (self._turns + 1)

    def _crossing(self, t0: float, p0: float, t1: float, p1: float, out: list[Boundary]) -> None:
        level = self._level()
        b = t0 + (level - p0) / (p1 - p0) * (t1 - t0)
        if self.accept(b, t1, out):
            self._turns += 1
        else:
            self._restart(t1, p1)

    def step(self, t: float, x: float, y: float, out: list[Boundary]) -> None:
        m = self._win.step(t, x, y)
        self.step_at(t, x, y, m[0], m[1], out)

    def step_at(
        self, t: float, x: float, y: float, cx: float, cy: float, out: list[Boundary]
    ) -> None:
        """:meth:`step` with the running centre ``(cx, cy)`` of the moving window given."""
        # the phase step's wrap to (-pi, pi], anchor() and _level() written out: this runs
        # for every live sample
        p = self.p
        vx = x - cx
        vy = y - cy
        if not vx * vx + vy * vy >= self._r2min:
            return
        phi = math.atan2(vy, vx)
        prev = self._prev
        if prev is None:
            self._prev = (t, phi, 0.0)
            self._restart(t, 0.0)
            return
        t0, phi0, big0 = prev
        st = phi - phi0
        if st > math.pi:
            st -= TWO_PI
        elif st <= -math.pi:
            st += TWO_PI
        big = big0 + st
        self._prev = (t, phi, big)
        last_b = self.last_b
        if (
            abs(st) > p.max_phase_step_rad
            or t - t0 > p.max_gap_s
            or t > (self.ref_t if last_b is None else last_b) + p.max_cycle_s
        ):
            self._restart(t, big)
            return
        d = self._dir
        if d == 0:
            up = big - self._ref_phi
            if up >= TWO_PI:
                self._dir = 1
            elif up <= -TWO_PI:
                self._dir = -1
            else:
                return
        else:
            level = self._ref_phi + d * TWO_PI * (self._turns + 1)
            if not (big >= level if d > 0 else big <= level):
                return
        self._crossing(t0, big0, t, big, out)


class _ReachDetector(_Detector):
    """Returns to the near end of a back-and-forth reaching motion.

    Per sample: mean ``c_i`` and covariance of the moving samples' x-y over ``[t_i -
    centre_window_s, t_i]``; principal axis ``u_i`` (closed-form 2×2 eigenvector), signed to
    agree with the reference axis ``u_ref`` fixed at the (re)start (``u_ref`` points forward,
    +y, unless the axis is within ~17° of x, then +x); projection ``p_i = (wrist_i - o) · u_i``
    with ``o`` the first sample (a fixed point, so the range of ``p`` does not follow the
    drifting centre). The near end is the low end of ``p`` (toward the patient for forward
    reaching). Schmitt trigger: armed once ``p >= lo + arm_fraction (hi - lo)``, a boundary when
    armed and ``p <= lo + return_fraction (hi - lo)`` (time linearly interpolated), then
    disarmed; ``lo, hi`` are the range of ``p`` over the previous cycle, or its running range
    since the (re)start for the first one; nothing happens while ``hi - lo < min_range_m``.
    Restarts (which also reset ``u_ref``): first usable sample, usable samples more than
    ``max_gap_s`` apart, the axis turning more than ``max_axis_turn_rad`` away from ``u_ref``,
    no boundary within ``max_cycle_s``, a cycle shorter than ``min_cycle_s``.
    """

    source: Source = "reach"

    def __init__(self, p: CycleParams) -> None:
        super().__init__(p)
        self._win = _MovingWindow(p)
        self._prev: tuple[float, float] | None = None  # last usable (t, p)
        self._ref = (0.0, 1.0)
        self._armed = False
        self._range: tuple[float, float] | None = None  # (lo, hi) of the previous cycle
        self._run = (math.inf, -math.inf)  # running (min, max) of p since the last boundary
        self._cos_turn = math.cos(p.max_axis_turn_rad)

    def _restart(self, t: float, ux: float, uy: float) -> None:
        self.ref_t = t
        self.last_b = None
        self._armed = False
        self._range = None
        self._run = (math.inf, -math.inf)
        if abs(uy) >= 0.3:
            self._ref = (ux, uy) if uy > 0 else (-ux, -uy)
        else:
            self._ref = (ux, uy) if ux > 0 else (-ux, -uy)

    def _fire(self, b: float, t1: float, p1: float, out: list[Boundary]) -> bool:
        """A return to the near end at ``b``; False: the detector must restart."""
        run = self._run
        if not self.accept(b, t1, out):
            return False
        self._armed = False
        self._range = run if run[1] - run[0] >= self.p.min_range_m else None
        self._run = (p1, p1)
        return True

    # -- per sample ---------------------------------------------------------------------------

    def step(self, t: float, x: float, y: float, out: list[Boundary]) -> None:
        self.step_at(t, x, y, self._win.step(t, x, y), out)

    def step_at(
        self,
        t: float,
        x: float,
        y: float,
        moments: tuple[float, float, float, float, float, float],
        out: list[Boundary],
    ) -> None:
        """:meth:`step` with the moving window's moments (:meth:`_MovingWindow.step`)
        given."""
        p = self.p
        mx, my, exx, eyy, exy, count = moments
        # the principal axis (closed-form 2x2 eigenvector), anchor(), the Schmitt trigger and
        # the running range's min/max written out: this runs for every live sample
        a = exx - mx * mx
        c = eyy - my * my
        b = exy - mx * my
        h = 0.5 * (a - c)
        lam = 0.5 * (a + c) + math.sqrt(h * h + b * b)
        if a >= c:
            ux, uy = lam - c, b
        else:
            ux, uy = b, lam - a
        nrm = math.sqrt(ux * ux + uy * uy)
        if not (nrm > 0.0 and count >= 3.0):
            return
        ux = ux / nrm
        uy = uy / nrm
        prev = self._prev
        last_b = self.last_b
        if (
            prev is None
            or t - prev[0] > p.max_gap_s
            or t > (self.ref_t if last_b is None else last_b) + p.max_cycle_s
        ):
            self._restart(t, ux, uy)
        rx, ry = self._ref
        dot = ux * rx + uy * ry
        if abs(dot) < self._cos_turn:
            self._restart(t, ux, uy)
            rx, ry = self._ref
            dot = ux * rx + uy * ry
        pv = (1.0 if dot >= 0.0 else -1.0) * (x * ux + y * uy)
        # Schmitt trigger on pv: (lo, lo + rng) the previous cycle's range, else the running
        # one including pv
        run0, run1 = self._run
        rg = self._range
        if rg is None:
            lo = pv if pv < run0 else run0
            rng = (pv if pv > run1 else run1) - lo
        else:
            lo, up = rg
            rng = up - lo
        ok = rng >= p.min_range_m
        if self._armed:
            level = lo + p.reach_return_fraction * rng
            if ok and pv <= level:
                bt = t
                if prev is not None and prev[1] > level:
                    t0, p0 = prev
                    bt = t0 + (p0 - level) / (p0 - pv) * (t - t0)
                if not self._fire(bt, t, pv, out):
                    self._restart(t, ux, uy)
                    rx, ry = self._ref
                    dot = ux * rx + uy * ry
                    pv = (1.0 if dot >= 0.0 else -1.0) * (x * ux + y * uy)
                    self._run = (pv, pv)  # the restart's range is empty: folded with pv
                self._prev = (t, pv)
                return
        elif ok and pv >= lo + p.reach_arm_fraction * rng:
            self._armed = True
        self._run = (pv if pv < run0 else run0, pv if pv > run1 else run1)
        self._prev = (t, pv)


class PathAndReach:
    """The ``"path"`` and the ``"reach"`` detectors over the same wrist samples, streaming:
    :meth:`update` with consecutive chunks of the samples gives the same boundaries
    (:attr:`path`, :attr:`reach`, so far) as one call with all of them, and the same as a
    ``"path"`` and a ``"reach"`` :class:`CycleSegmenter` each fed the samples, with one moving
    window for both (the path centre is the window's first two moments, the same sums in the
    same order). ``params.mode`` is not used."""

    def __init__(self, params: CycleParams | None = None) -> None:
        p = params if params is not None else CycleParams()
        self._win = _MovingWindow(p)
        self._path, self._reach = _PathDetector(p), _ReachDetector(p)
        self.path: list[Boundary] = []
        self.reach: list[Boundary] = []

    def update(self, t: ArrayLike, wrist: ArrayLike) -> None:
        """``t`` (N,) s strictly increasing (and after the previous chunk's), ``wrist`` (N,3) m,
        as :meth:`CycleSegmenter.update`."""
        tt = np.asarray(t, dtype=np.float64)
        ww = np.asarray(wrist, dtype=np.float64)
        n = tt.shape[0]
        if ww.shape != (n, 3):
            raise ValueError("wrist must have shape (N, 3) matching t")
        if n == 0:
            return
        path, reach = self._path, self._reach
        if path.origin is None:  # the first sample: a fixed point for the numerical range
            path.origin = reach.origin = (float(ww[0, 0]), float(ww[0, 1]))
        ox, oy = path.origin
        step_path, step_reach, moments = path.step_at, reach.step_at, self._win.step
        out_path, out_reach = self.path, self.reach
        for ti, xi, yi in zip(tt.tolist(), ww[:, 0].tolist(), ww[:, 1].tolist(), strict=True):
            x, y = xi - ox, yi - oy
            m = moments(ti, x, y)
            step_path(ti, x, y, m[0], m[1], out_path)
            step_reach(ti, x, y, m, out_reach)


def path_and_reach(
    t: ArrayLike, wrist: ArrayLike, params: CycleParams | None = None
) -> tuple[list[Boundary], list[Boundary]]:
    """:class:`PathAndReach` over all the samples in one call: the ``"path"`` and the
    ``"reach"`` boundaries (``t`` (N,) s strictly increasing, ``wrist`` (N,3) m)."""
    both = PathAndReach(params)
    both.update(t, wrist)
    return both.path, both.reach


class CycleSegmenter:
    """Streaming cycle segmentation (see the module docstring for the methods).

    ``update(t, wrist)`` returns the boundaries found in the new samples, in time order; a
    boundary ``b`` with ``b.cycle_start is not None`` completes the cycle ``[b.cycle_start, b)``
    (equal to the previous boundary). Boundaries are strictly increasing.

    Events: :meth:`add_event` queues a ``cycle_start`` time; its boundary is reported by the
    first :meth:`update` call whose data reaches that time (``t[-1] >= t_event``), or by the
    next call (even with no samples) if the data was already past it when the event was added.

    Guarantees. Boundaries from the wrist path depend only on the samples (values and times),
    never on chunking. Event boundaries are at the events' own times, whatever the arrival
    order relative to sample chunks; only the call that reports them depends on it. Exceptions,
    both only when an event arrives after wrist data past its own time: (a) an event at or
    before the last boundary already emitted is ignored; (b) in ``"auto"`` mode, samples before
    the first received event's time go to the path detector and later ones do not, so path
    boundaries emitted from samples after that time (because the event came late) stay.
    In ``"path"`` and ``"reach"`` modes events are ignored.
    """

    def __init__(self, params: CycleParams | None = None) -> None:
        self.params = params if params is not None else CycleParams()
        mode = self.params.mode
        self._detector: _Detector | None = None
        if mode in ("auto", "path"):
            self._detector = _PathDetector(self.params)
        elif mode == "reach":
            self._detector = _ReachDetector(self.params)
        self._use_events = mode in ("auto", "events")
        self._switch_t: float | None = None  # auto: time of the first received event
        self._events: list[float] = []
        self._data_t = -math.inf
        self._last_b = -math.inf
        self._last_event_b: float | None = None

    @property
    def active_source(self) -> Source:
        """What produces boundaries for the next samples: ``"path"``, ``"reach"`` or
        ``"event"``."""
        det = self._detector
        if det is not None and (self._switch_t is None or self._data_t < self._switch_t):
            return det.source
        return "event"

    def add_event(self, t: float) -> None:
        """Queue a contract ``cycle_start`` event at time ``t`` (s)."""
        if not self._use_events or not math.isfinite(t):
            return
        if self._switch_t is None and self.params.mode == "auto":
            self._switch_t = float(t)
        bisect.insort(self._events, float(t))

    def update(self, t: ArrayLike, wrist: ArrayLike) -> list[Boundary]:
        """Feed wrist samples: ``t`` (N,) s strictly increasing, ``wrist`` (N,3) m, robot frame
        (z up; only x and y are used). Returns new :class:`Boundary` objects (floats, s)."""
        tt = np.asarray(t, dtype=np.float64)
        ww = np.asarray(wrist, dtype=np.float64)
        n = tt.shape[0]
        if ww.shape != (n, 3):
            raise ValueError("wrist must have shape (N, 3) matching t")
        out: list[Boundary] = []
        det = self._detector
        if det is not None and n:
            k = n
            if self._switch_t is not None:
                k = int(np.searchsorted(tt, self._switch_t, side="left"))
            if k:
                for b in det.update(tt[:k], ww[:k, :2]):
                    out.append(b)
                    self._last_b = b
            if k < n:
                self._detector = None
        seen = self._data_t  # data time before this chunk
        if n:
            self._data_t = max(self._data_t, float(tt[-1]))
        self._due_events(seen, out)
        return out

    def push(self, t: float, x: float, y: float) -> list[Boundary]:
        """:meth:`update` for one sample (time s, wrist x and y m), without numpy calls:
        the live pipeline feeds one row at a time."""
        out: list[Boundary] = []
        det = self._detector
        if det is not None:
            if self._switch_t is None or t < self._switch_t:
                origin = det.origin
                if origin is None:
                    origin = det.origin = (x, y)
                det.step(t, x - origin[0], y - origin[1], out)
                if out:
                    self._last_b = out[-1]
            else:
                self._detector = None
        seen = self._data_t
        if t > seen:  # max(seen, t), NaN included
            self._data_t = t
        if self._events and self._events[0] <= self._data_t:
            self._due_events(seen, out)
        return out

    def _due_events(self, seen: float, out: list[Boundary]) -> None:
        if self._events and self._events[0] <= self._data_t:
            k = bisect.bisect_right(self._events, self._data_t)
            due = self._events[:k]
            del self._events[:k]
            after = math.nextafter(seen, math.inf)
            for te in due:
                self._emit_event(te, max(te, after), out)

    def _emit_event(self, te: float, detected_at: float, out: list[Boundary]) -> None:
        p = self.params
        if te <= self._last_b:
            return
        prev = self._last_event_b
        if prev is not None and te - prev < p.min_cycle_s:
            return
        start = prev if prev is not None and te - prev <= p.max_cycle_s else None
        b = Boundary(te, start, "event", detected_at)
        out.append(b)
        self._last_b = te
        self._last_event_b = te
