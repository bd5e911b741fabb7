"""The streaming inertial-robotic pipeline (Passon et al. 2020, §3), message by message.

``feed()`` takes decoded contract messages in arrival order and only does cheap
book-keeping; ``poll()`` runs the numerical work on everything that has become ready and
returns the new estimate rows (one per robot sample) and feedback. Results depend only on
the messages and their order, never on how they are batched or when ``poll()`` is called,
and never on the wall clock: the live service and ``rehab analyze`` give identical numbers.

Stages (each keeps its own state, like ``scipy.signal``'s ``zi``; the first three in their
own modules, :mod:`estimators.imu_stage`, :mod:`estimators.robot_stage` and
:mod:`estimators.grid_stage`; what a poll returns is in :mod:`estimators.output`):

1. IMU: sample-rate probe, gap bridging or reset, 6D orientation ``q_IA`` (VQF), and the
   elbow's acceleration terms in frame I (eqs. 1–2).
2. Robot: elbow and forearm axis from the cuffs (eq. 13).
3. Fusion grid: both accelerations on a common uniform time base, low-passed (§3.2.1).
4. Heading: scheduled updates of δ (§3.2.2, eqs. 5–8, or the improved method).
5. Rows: ``q_RA = Rz(δ) q_IA`` (eqs. 9–10), elbow angle (eq. 11), shoulder (eq. 12), the
   conventional baseline, nominal shoulder, indicator state and cycle verdicts (§3.4).

Improved IMU-side acceleration: instead of eq. 1's ``ω̇ × r`` with ω̇ from a causally
low-passed gyro (delayed ~0.2 s against the raw ω in the centripetal term, which breaks
fast motions), the elbow acceleration is written exactly as
``a_E = (q f q* − g) + d²/dt² (q r q*)``; low-pass and differentiation commute, so the
second term is differentiated after the same 0.5 Hz low-pass as the robot's position.
Both sides then see the same filter, the same delay and no gyro derivative at all.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators import heading as hd
from estimators import rows
from estimators.buffers import RowQueue
from estimators.compensation import CompensationParams, EpisodeTracker, Indicator
from estimators.cycles import CycleParams, CycleSegmenter
from estimators.grid_stage import GridStage
from estimators.heading_stage import HeadingStage
from estimators.imu_stage import ImuStage
from estimators.nominal import NominalStage
from estimators.output import COL, NCOL, Output, Quality, RowTable
from estimators.params import PipelineParams
from estimators.robot_stage import RobotStage
from estimators.verdicts import CycleJudge, CycleVerdict

Array: TypeAlias = NDArray[np.float64]
Idx: TypeAlias = NDArray[Any]  # integer and boolean arrays


# The pipeline takes any message objects with protocol.wire's attributes (duck-typed).


class _Stream:
    """Per-stream ordering and sequence book-keeping."""

    __slots__ = ("last_seq", "last_t", "name")

    def __init__(self, name: str) -> None:
        self.name = name
        self.last_t = -math.inf
        self.last_seq: int | None = None

    def admit(self, t0: float, seq: int | None, q: Quality) -> bool:
        if t0 <= self.last_t:
            q.reject("duplicate_t" if t0 == self.last_t else "time_backwards")
            return False
        if seq is not None:
            if self.last_seq is not None and seq != self.last_seq + 1:
                lost = seq - self.last_seq - 1
                if lost > 0:
                    q.seq_lost[self.name] = q.seq_lost.get(self.name, 0) + lost
                else:
                    q.reject("seq_restart")  # counted, data still accepted (device restart)
            self.last_seq = seq
        return True


# ------------------------------------------------------------------------------ pipeline


class Pipeline:
    """One device's streaming pipeline. See the module docstring for the guarantees."""

    def __init__(self, params: PipelineParams | None = None) -> None:
        self.params = p = params or PipelineParams()
        self.hp = p.heading_params
        self.quality = Quality()
        self._imu_stream = _Stream("imu")
        self._robot_stream = _Stream("robot")
        self._imu = ImuStage(p)
        self._robot = RobotStage(p)
        self._grid = GridStage(p)
        # messages fed since the last poll
        self._imu_pending: list[tuple[Array, Array, Array, list[float] | None]] = []
        # (t, wrist, proximal, elbow)
        self._robot_pending: list[tuple[Array, Array, Array, Array | None]] = []
        # consecutive rows fed by feed_*_rows, not yet cut out as one pending piece:
        # [t, gyr, acc, i0, i1] and [t, wrist, proximal, elbow, i0, i1]
        self._imu_run: list[Any] | None = None
        self._robot_run: list[Any] | None = None
        self._cuff_src: tuple[Array, Array] | None = None  # arrays _cuff_bad describes
        self._cuff_bad: list[int] = []
        self._imu_frontier = -math.inf  # last IMU stamp fed
        self._imu_first = math.nan  # first IMU stamp admitted (the lead's reference, no robot)
        self._robot_frontier = -math.inf
        # rows: robot samples in order; decided[i] = (with_imu, nominal_spec)
        self._row_t: list[float] = []
        self._n_decided = 0
        # (with IMU, nominal spec, the newest IMU stamp the row may use: inf once the IMU
        # has reached the row, else its prediction starts there)
        self._decisions: list[tuple[bool, int, float]] = []
        self._n_done = 0
        self._rowq = RowQueue(9)  # wrist, p_E, x_C of the robot samples not yet emitted
        # heading
        self._heading = HeadingStage(self.hp, self.quality)
        self._nominal = NominalStage(p, self.quality)
        # compensation
        self._cp = CompensationParams(
            tolerance_m=p.tolerance_m,
            max_outside_fraction=p.max_outside_fraction,
            displacement_norm=p.displacement_norm,
            warning_after_s=p.warning_after_s,
        )
        self._indicator = Indicator(self._cp)
        self._segmenter = CycleSegmenter(CycleParams(mode=p.cycle_mode))
        self._judge = CycleJudge(self._cp)
        self._episodes = EpisodeTracker(self._cp)
        # read at every message fed (predict_s is a property)
        self._off = p.robot_time_offset_s
        self._wait = p.imu_wait_s
        self._ahead = p.predict_s
        self._lead_max = p.imu_lead_max_s
        self._grid_trimmed = -math.inf
        self._next_trim = -math.inf  # robot stamp from which the next poll trims buffers
        # a row uses the latest heading update the grid is sure to have reached by the time
        # the row became ready (two grid steps and the anti-alias half-width back)
        self._snap_lag = 2.0 * self._grid.dt + self._grid.half + 1e-9
        # the rows' kernel: its parameters and carried state, and the heading snapshots as
        # an array (made again when they change)
        self._row_st, self._row_part = rows.new_state(
            p.robot_time_offset_s,
            self._snap_lag,
            p.auto_nominal_s,
            p.displacement_norm,
            p.angle_timing,
        )
        self._snaps = np.empty((0, 8))
        self._snaps_last: tuple[float, ...] | None = None  # the newest snapshot in _snaps

    # ------------------------------------------------------------------ feeding

    def feed(self, msg: Any) -> bool:
        """Take one decoded message (IMU, robot or event). Returns False if rejected."""
        kind = _KINDS.get(type(msg))
        if kind is None:  # duck-typed by attributes, cached per slotted type (hasattr is slow)
            kind = _kind_of(msg)
            if hasattr(type(msg), "__slots__"):
                _KINDS[type(msg)] = kind
        if kind == "imu":
            return self.feed_imu(
                msg.t,
                msg.gyr,
                msg.acc,
                getattr(msg, "seq", None),
                getattr(msg, "segment", "upperarm"),
            )
        if kind == "robot":
            return self.feed_robot(
                msg.t,
                msg.wrist,
                msg.proximal,
                getattr(msg, "elbow", None),
                getattr(msg, "seq", None),
            )
        if kind == "event":
            return self.feed_event(float(msg.t), str(msg.type), getattr(msg, "point", None))
        # optional streams (camera) are valid but not used by the method: counted, not rejected
        self.quality.ignored[type(msg).__name__] = (
            self.quality.ignored.get(type(msg).__name__, 0) + 1
        )
        return False

    def feed_imu(
        self, t: Array, gyr: Array, acc: Array, seq: int | None = None, segment: str = "upperarm"
    ) -> bool:
        # (pending messages hold no Python lists: in a batch they would be many thousand
        # objects for the garbage collector to walk again and again)
        tl = t.tolist()
        if not self._admit_imu(tl[0], tl[-1], len(tl), seq, segment):
            return False
        if self._imu_run is not None:
            self._close_imu_run()
        self._imu_pending.append((t, gyr, acc, tl))
        if self._n_decided < len(self._row_t):
            self._decide()
        return True

    def feed_imu_rows(
        self,
        t: Array,
        tl: Sequence[float],
        gyr: Array,
        acc: Array,
        i0: int,
        i1: int,
        seq: int | None = None,
        segment: str = "upperarm",
    ) -> bool:
        """:meth:`feed_imu` of rows ``i0:i1`` of arrays that hold many messages end to end
        (``tl``: ``t`` as floats). The same result as
        ``feed_imu(t[i0:i1], gyr[i0:i1], acc[i0:i1], seq, segment)``, but consecutive
        messages stay one piece: a batch's poll then joins a few pieces, not ~10^4."""
        if not self._admit_imu(tl[i0], tl[i1 - 1], i1 - i0, seq, segment):
            return False
        run = self._imu_run
        if run is not None and run[0] is t and run[4] == i0:
            run[4] = i1
        else:
            self._close_imu_run()
            self._imu_run = [t, gyr, acc, i0, i1]
        if self._n_decided < len(self._row_t):
            self._decide()
        return True

    def _admit_imu(self, t0: float, t1: float, n: int, seq: int | None, segment: str) -> bool:
        if segment != "upperarm":  # forearm/trunk IMUs are for later estimators
            self.quality.ignored[f"imu_{segment}"] = (
                self.quality.ignored.get(f"imu_{segment}", 0) + 1
            )
            return False
        # bounded memory: decided in feed order (never by poll timing), so batch and stream agree
        ref = self._robot_frontier - self._off
        if ref == -math.inf:
            ref = self._imu_first if self._imu_first == self._imu_first else t0
        if t1 - ref > self._lead_max:
            self.quality.reject("imu_without_robot")
            return False
        if not self._imu_stream.admit(t0, seq, self.quality):
            return False
        if self._imu_first != self._imu_first:
            self._imu_first = t0
        self._imu_stream.last_t = self._imu_frontier = t1
        self.quality.imu_samples += n
        return True

    def _close_imu_run(self) -> None:
        run = self._imu_run
        if run is not None:
            t, gyr, acc, i0, i1 = run
            self._imu_pending.append((t[i0:i1], gyr[i0:i1], acc[i0:i1], None))
            self._imu_run = None

    def feed_robot(
        self,
        t: Array,
        wrist: Array,
        proximal: Array,
        elbow: Array | None = None,
        seq: int | None = None,
    ) -> bool:
        tl = t.tolist()
        if not self._robot_stream.admit(tl[0], seq, self.quality):
            return False
        # pure Python: per-message numpy calls would cost more than the whole check
        wl, pl = wrist.tolist(), proximal.tolist()
        for w, p in zip(wl, pl, strict=True):
            x, y, z = w[0] - p[0], w[1] - p[1], w[2] - p[2]
            if x * x + y * y + z * z <= _COINCIDENT_M2:
                self.quality.reject("coincident_cuffs")
                return False
        if self._robot_run is not None:
            self._close_robot_run()
        self._robot_pending.append((t, wrist, proximal, elbow))
        self._accept_robot(tl)
        return True

    def feed_robot_rows(
        self,
        t: Array,
        tl: Sequence[float],
        wrist: Array,
        proximal: Array,
        elbow: Array | None,
        i0: int,
        i1: int,
        seq: int | None = None,
    ) -> bool:
        """:meth:`feed_robot` of rows ``i0:i1`` (as :meth:`feed_imu_rows`). ``elbow``: NaN
        rows for messages without one (the cuffs' elbow is used there, as for None)."""
        if not self._robot_stream.admit(tl[i0], seq, self.quality):
            return False
        if self._cuff_src is None or not (
            self._cuff_src[0] is wrist and self._cuff_src[1] is proximal
        ):
            # the same arithmetic as feed_robot's loop, for all the rows at once
            d = wrist - proximal
            x, y, z = d[:, 0], d[:, 1], d[:, 2]
            self._cuff_bad = np.flatnonzero(x * x + y * y + z * z <= _COINCIDENT_M2).tolist()
            self._cuff_src = (wrist, proximal)
        j = bisect.bisect_left(self._cuff_bad, i0)
        if j < len(self._cuff_bad) and self._cuff_bad[j] < i1:
            self.quality.reject("coincident_cuffs")
            return False
        run = self._robot_run
        if run is not None and run[0] is t and run[3] is elbow and run[5] == i0:
            run[5] = i1
        else:
            self._close_robot_run()
            self._robot_run = [t, wrist, proximal, elbow, i0, i1]
        self._accept_robot(tl[i0:i1])
        return True

    def _accept_robot(self, tl: Sequence[float]) -> None:
        self._robot_stream.last_t = self._robot_frontier = tl[-1]
        self._row_t.extend(tl)
        self.quality.robot_samples += len(tl)
        self._decide()

    def _close_robot_run(self) -> None:
        run = self._robot_run
        if run is not None:
            t, wrist, prox, elbow, i0, i1 = run
            e = None if elbow is None else elbow[i0:i1]
            self._robot_pending.append((t[i0:i1], wrist[i0:i1], prox[i0:i1], e))
            self._robot_run = None

    def feed_event(self, t: float, etype: str, point: Array | None = None) -> bool:
        if etype == "shoulder_reference" and point is not None:
            self._nominal.add_reference(t, point)
        elif etype == "nominal_reset":
            self._nominal.add_reset(t)
        elif etype == "cycle_start":
            self._segmenter.add_event(t)
        else:
            self.quality.reject("unknown_event")
            return False
        return True

    def _decide(self) -> None:
        """Mark robot samples ready: the IMU has reached them, or is at most
        ``imu_predict_s`` behind (the upper arm is then predicted from the newest IMU
        sample), or the robot ran ahead by ``imu_wait_s`` (then they are emitted without
        IMU-derived values). Decided in feed order, so batching changes nothing."""
        row_t = self._row_t
        n = len(row_t)
        i = self._n_decided
        if i >= n:
            return
        off, wait, ahead = self._off, self._wait, self._ahead
        front = self._imu_frontier
        spec_for = self._nominal.spec_for
        decisions = self._decisions
        while i < n:
            tr = row_t[i]
            asof = math.inf
            with_imu = front >= tr - off
            if not with_imu and tr - off - front <= ahead:
                with_imu, asof = True, front
            elif not with_imu and self._robot_frontier < tr + wait:
                break
            decisions.append((with_imu, spec_for(tr), asof))
            i += 1
        self._n_decided = i

    @property
    def convergence_time(self) -> float | None:
        """Time of the heading update that first declared convergence (s), None before."""
        return self._heading.convergence_time

    @property
    def first_motion_time(self) -> float | None:
        """Time of the first heading update whose window had enough motion (s)."""
        return self._heading.first_motion_time

    @property
    def heading_state(self) -> hd.HeadingState:
        """The heading estimator's current state (read it, do not change it)."""
        return self._heading.state

    @property
    def arm_length_estimate(self) -> float | None:
        """The upper-arm length measured at the rope reference (m), None if none was."""
        return self._nominal.arm_length_estimate

    @property
    def rows_ready(self) -> bool:
        """Whether :meth:`poll` would return rows now (cheap; for callers polling on demand)."""
        return self._n_decided > self._n_done

    def status(self) -> dict[str, Any]:
        """What a dashboard shows beside the numbers: convergence and its progress, the
        heading's confidence, the estimated sensor errors, and the data quality."""
        s = self._heading.state
        hp = self.hp
        if s.converged:
            progress = 1.0
        elif hp.method == "paper":
            # the paper converges at the sixth counted window at the earliest (§3.2.2)
            progress = min(s.n_counted / (hp.n_two_step + 1), 0.99)
        else:
            # motion seen so far (sub-windows) and the heading's certainty, whichever lags
            need = hp.min_motion_subwindows * hp.window_s / hp.n_subwindows
            moved = 0.0 if self._heading.first_motion_time is None else need
            certainty = (
                0.0
                if not math.isfinite(s.std)
                else min(1.0, math.radians(hp.max_converge_std_deg) / s.std)
            )
            progress = min(0.99, 0.5 * moved / need + 0.5 * certainty)
        std = math.degrees(s.std) if math.isfinite(s.std) else None
        return {
            "heading_converged": s.converged,
            "convergence_progress": progress,
            "heading_offset_deg": None if s.delta is None else math.degrees(s.delta) % 360.0,
            "heading_std_deg": std,
            "heading_confidence": 0.0 if std is None else 1.0 / (1.0 + (std / 3.0) ** 2),
            "heading_drift_dps": math.degrees(s.rate),
            "excitation_m_s2": s.excitation,
            "first_motion_t": self._heading.first_motion_time,
            "converged_t": self._heading.convergence_time,
            "robot_latency_s": s.lag,
            "acc_bias_m_s2": s.acc_bias.tolist(),
            "lever_error_m": s.lever_error.tolist(),
            "upper_arm_length_m": self._nominal.arm_len,
            "upper_arm_length_measured": self._nominal.arm_length_estimate is not None,
            "quality": self.quality.as_dict(),
        }

    # ------------------------------------------------------------------ computing

    def poll(self) -> Output:
        """Run everything that is ready; return the new rows and feedback."""
        if self._imu_run is not None:
            self._close_imu_run()
        if self._robot_run is not None:
            self._close_robot_run()
        if self._imu_pending:
            pend, self._imu_pending = self._imu_pending, []
            if len(pend) == 1:
                t, gyr, acc, tl = pend[0]
                self._imu.process(t, gyr, acc, self.quality, tl)
            else:
                self._imu.process(
                    np.concatenate([c[0] for c in pend]),
                    np.concatenate([c[1] for c in pend]),
                    np.concatenate([c[2] for c in pend]),
                    self.quality,
                )
        off = self.params.robot_time_offset_s
        if self._robot_pending:
            pend_r, self._robot_pending = self._robot_pending, []
            if len(pend_r) == 1:
                self._robot_samples(*pend_r[0], off)
            else:  # one vectorised call (elementwise: the same numbers as one by one)
                given = [c[3] for c in pend_r]
                elbow = None
                if any(e is not None for e in given):
                    elbow = np.concatenate(
                        [np.full((len(c[0]), 3), np.nan) if c[3] is None else c[3] for c in pend_r]
                    )
                self._robot_samples(
                    np.concatenate([c[0] for c in pend_r]),
                    np.concatenate([c[1] for c in pend_r]),
                    np.concatenate([c[2] for c in pend_r]),
                    elbow,
                    off,
                )
        # fusion grid as far as both streams reach (stamps fed so far)
        until = min(self._imu_frontier - self._grid.half, self._robot_frontier - off)
        # The grid only feeds heading updates: advance it (in one vectorised chunk, with the
        # same numbers as sample by sample) once its output, which ends one grid step before
        # the last grid point, reaches the next update.
        dt = self._grid.dt
        t_next = self._heading.t_next
        due = t_next is None or (
            math.isfinite(until) and (math.floor(until / dt) - 1) * dt >= t_next
        )
        if self._imu.ts is not None and due:
            self._grid.advance(self._imu, self._robot, until)
            self._heading.run(self._grid)
        out = self._rows()
        # forgetting old data changes no result, so it is done every few seconds of data:
        # its cost is mostly per call (per poll it would cost as much as the row itself)
        if not self._robot_frontier < self._next_trim:
            self._trim()
            self._next_trim = self._robot_frontier + _TRIM_EVERY_S
        return out

    def finish(self) -> Output:
        """End of data: emit the rows still waiting for an IMU that will not come."""
        self._robot_frontier = math.inf
        self._decide()
        return self.poll()

    def run(self, messages: Any) -> Output:
        """Batch call: feed everything, then compute. Identical to any streaming schedule."""
        for m in messages:
            self.feed(m)
        out = self.poll()
        out.extend(self.finish())
        return out

    def _robot_samples(
        self, t: Array, wrist: Array, prox: Array, elbow: Array | None, off: float
    ) -> None:
        """Elbow and forearm axis from the cuffs (eq. 13), or the robot's own elbow."""
        lp = self.params.cuff_to_elbow_m
        tl, wl, pl = t.tolist(), wrist.tolist(), prox.tolist()
        el = None if elbow is None else elbow.tolist()
        pes: list[tuple[float, ...]] = []
        for j, (w, p) in enumerate(zip(wl, pl, strict=True)):
            xc = rows.unit(w[0] - p[0], w[1] - p[1], w[2] - p[2])
            pe = (p[0] - lp * xc[0], p[1] - lp * xc[1], p[2] - lp * xc[2])
            if el is not None:
                pe = tuple(e if math.isfinite(e) else v for e, v in zip(el[j], pe, strict=True))
            self._rowq.push((*w, *pe, *xc))
            pes.append(pe)
        self._robot.append([x - off for x in tl] if off else tl, pes, self.quality)

    def _rows(self) -> Output:
        """Rows of the robot samples decided since the last poll (eqs. 9–12, §3.4): their
        formulas in one compiled call (:func:`estimators.rows.compute`; a live poll brings
        one row, an analysis all of them), then the compensation rules row by row."""
        lo, hi = self._n_done, self._n_decided
        if hi <= lo:
            return Output()
        self._n_done = hi
        n = hi - lo
        tl = self._row_t[lo:hi]
        decisions = self._decisions[lo:hi]
        rin = np.empty((n, 5))  # t, with IMU, nominal spec, asof, l_A
        rin[:, 0] = tl
        rin[:, 1:4] = decisions
        robot = self._rowq.take_block(n)  # wrist, p_E, x_C
        self._nominal.arm_lengths(tl, robot[:, 3:6], [d[1] for d in decisions], rin[:, 4])
        snaps = self._heading.snapshots()
        last = snaps[-1] if snaps else None
        if len(snaps) != len(self._snaps) or last is not self._snaps_last:
            self._snaps = np.array(snaps, dtype=np.float64).reshape(-1, 8)
            self._snaps_last = last
        m = np.empty((n, NCOL))
        rows.compute(
            rin,
            robot,
            self._imu.lookup(),
            self._snaps,
            self._nominal.table(),
            self._row_st,
            self._row_part,
            _ROW_COLS,
            m,
        )
        self.quality.rows_without_imu += sum(1 for d in decisions if not d[0])
        codes: list[int] = []
        changes: list[tuple[float, str]] = []
        verdicts: list[CycleVerdict] = []
        episodes: list[Any] = []
        seg, ind, judge, eps = self._segmenter, self._indicator, self._judge, self._episodes
        disp = m[:, _DISP].tolist()
        for ti, (wx, wy), d in zip(tl, robot[:, 0:2].tolist(), disp, strict=True):
            # compensation rule (§3.4); segment first: a completed cycle sets the tolerated
            # duration from its end on
            boundaries = seg.push(ti, wx, wy)
            code = ind.push(ti, d, boundaries, changes)
            codes.append(code)
            verdicts += judge.push(ti, code, d, boundaries)
            episodes += eps.push(ti, code, d)
        table = RowTable(m, np.array(codes, dtype=np.int8))
        fb = _feedback(changes, verdicts) if changes or verdicts else []
        return Output(table, fb, verdicts, episodes)

    def _trim(self) -> None:
        # keep what the next rows, grid points and heading windows can still need
        off = self.params.robot_time_offset_s
        keep = (
            self._row_t[self._n_done] if self._n_done < len(self._row_t) else self._robot_frontier
        )
        keep = min(keep - off, self._grid.frontier) - 1.0
        if math.isfinite(keep):
            self._imu.trim(keep)
            self._robot.trim(keep)
        if self._grid_trimmed != self._grid.frontier:
            self._grid_trimmed = self._grid.frontier
            self._grid.trim(self._grid.frontier - self._heading.span_s - 1.0)
        if self._n_done < len(self._row_t):
            self._heading.trim(self._row_t[self._n_done] - off - 1.0)
        # forget rows already emitted (indices stay consistent through the offset); soon:
        # in a service, long lists are what the garbage collector's full passes walk
        if self._n_done > 256:
            k = self._n_done
            del self._row_t[:k]
            del self._decisions[:k]
            self._n_decided -= k
            self._n_done = 0


def _feedback(
    changes: list[tuple[float, str]], verdicts: list[CycleVerdict]
) -> list[dict[str, Any]]:
    """Contract §7's feedback of a poll: state changes and completed cycles, in time order."""
    fb: list[dict[str, Any]] = [{"t": tc, "type": "state", "state": st} for tc, st in changes]
    if verdicts:
        fb.extend(
            {
                "type": "cycle",
                "start": v.start,
                "end": v.end,
                "outside_fraction": v.outside_fraction,
                "compensatory": v.compensatory,
            }
            for v in verdicts
            if v.compensatory is not None
        )
        fb.sort(key=lambda f: f.get("t", f.get("end", 0.0)))
    return fb


_KINDS: dict[type, str] = {}


def _kind_of(msg: Any) -> str:
    if hasattr(msg, "gyr"):
        return "imu"
    if hasattr(msg, "proximal"):
        return "robot"
    if hasattr(msg, "type") and hasattr(msg, "t"):
        return "event"
    return "other"


_COINCIDENT_M2 = 1e-12  # squared cuff distance, m², below which the cuffs coincide
_TRIM_EVERY_S = 2.0  # s of robot data between two trims (1 s: +2 % CPU; 5 s: +10 % memory)
_DISP = COL["shoulder_displacement_m"]
# the rows' kernel's columns: the IMU samples' looked up, then its outputs'
_ROW_COLS = np.concatenate((ImuStage.LOOKUP, [COL[name] for name in rows.OUT])).astype(np.int64)
