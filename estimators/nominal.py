"""Stage of the pipeline's rows: the nominal shoulder's specifications (paper §3.4, contract
§4) fed so far (parameter, rope reference, automatic after convergence or after a reset
event), and the upper-arm length per row. The rows' kernel (:mod:`estimators.rows`) keeps
the nominal shoulder of each row from these specs."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

from estimators.output import Quality
from estimators.params import PipelineParams

Array: TypeAlias = NDArray[np.float64]
NAN3 = (math.nan,) * 3


class NominalStage:
    """Nominal-shoulder specs and the upper-arm length of each row.

    Specifications in feed order: ``("param", −inf, xyz)`` from the parameters, ``("point", t,
    xyz)`` for a ``shoulder_reference`` event (the rope end held on the shoulder), ``("auto",
    t, None)`` at the start or for a ``nominal_reset`` event. A row uses the newest spec whose
    time has come (:meth:`spec_for`, decided when the row is)."""

    def __init__(self, params: PipelineParams, quality: Quality) -> None:
        self.params = params
        self.quality = quality
        self._specs: list[tuple[str, float, Array | None]] = []
        if params.nominal_shoulder_m is not None:
            point = np.array(params.nominal_shoulder_m, dtype=np.float64)
            self._specs.append(("param", -math.inf, point))
        else:
            self._specs.append(("auto", -math.inf, None))
        self._table: Array | None = None  # the specs for the rows' kernel, when asked
        self.arm_len = params.upper_arm_length_m
        self._arm_spec = -1
        self._arm_spec_done = -1
        self._arm_pts: list[Array] = []
        self._arm_free: set[int] = set()  # specs whose rows all use arm_len as it is
        self.arm_length_estimate: float | None = None

    def add_reference(self, t: float, point: Array) -> None:
        """A ``shoulder_reference`` event: the rope end on the shoulder at ``point`` (m)."""
        self._specs.append(("point", t, np.asarray(point, dtype=np.float64)))
        self._table = None

    def add_reset(self, t: float) -> None:
        """A ``nominal_reset`` event: the nominal shoulder is set anew, automatically."""
        self._specs.append(("auto", t, None))
        self._table = None

    def spec_for(self, tr: float) -> int:
        """The newest spec (in feed order) whose time has come at row time ``tr``."""
        k = len(self._specs) - 1
        while k > 0 and self._specs[k][1] > tr:
            k -= 1
        return k

    def table(self) -> Array:
        """The specs (k, 4) for :func:`estimators.rows.compute`, which keeps the nominal
        shoulder itself: each one's point and 1 if automatic (the mean estimate over
        ``auto_nominal_s`` after convergence, or after a reset event)."""
        if self._table is None:
            self._table = np.array(
                [
                    (*(NAN3 if p is None else p.tolist()), 1.0 if p is None else 0.0)
                    for _, _, p in self._specs
                ]
            )
        return self._table

    def arm_lengths(self, t: list[float], p_e: Array, ks: list[int], out: Array) -> None:
        """Upper-arm length (m) at rows ``t`` (s) with elbows ``p_e`` (n, 3) of specs ``ks``
        (see :meth:`_measure`), in row order, into ``out`` (n,)."""
        free = self._arm_free
        for k in set(ks) - free:  # specs that never measure join the free ones
            self._fixed(k)
        if free.issuperset(ks):  # the usual: every row takes arm_len as it is
            out[:] = self.arm_len
        else:
            out[:] = [
                self.arm_len if k in free else self._measure(tk, p.tolist(), k)
                for tk, p, k in zip(t, p_e, ks, strict=True)
            ]

    def _fixed(self, k: int) -> bool:
        """Whether :meth:`_measure` returns ``arm_len`` for every row of spec ``k`` from
        here on, whatever the row."""
        kind, _, point = self._specs[k]
        if self.params.arm_length_mode != "calibrate" or kind != "point" or point is None:
            self._arm_free.add(k)  # for good: a spec's kind and point never change
            return True
        return k == self._arm_spec_done

    def _measure(self, t: float, p_e: Sequence[float], k: int) -> float:
        """Upper-arm length at a row: the parameter, or measured at the rope reference.

        While the therapist holds the rope end on the shoulder (``shoulder_reference``), the
        shoulder is at ``p_ref`` and the robot measures the elbow, so ``l_A = |p_E − p_ref|``
        (mean elbow over ``arm_reference_s`` after the event). This removes the constant
        offset an assumed length leaves in every shoulder estimate (eq. 12), without
        needing the heading. Out-of-bounds or moving-arm measurements are ignored.
        """
        if self._fixed(k):
            return self.arm_len
        p = self.params
        _, t_e, point = self._specs[k]
        if self._arm_spec != k:
            self._arm_spec, self._arm_pts = k, []
        if t <= t_e + p.arm_reference_s:
            self._arm_pts.append(np.array(p_e))
            return self.arm_len
        self._arm_spec_done = k
        # its later rows take arm_len as it is now: later specs' rows come after them all
        # (a row's spec is the newest whose time has come), so a new measurement misses them
        self._arm_free.add(k)
        pts = np.array(self._arm_pts)
        self._arm_pts = []
        if len(pts) >= 3 and float(np.max(np.std(pts, axis=0))) < 0.01:
            length = float(np.linalg.norm(pts.mean(axis=0) - point))
            lo_b, hi_b = p.arm_length_bounds_m
            if lo_b <= length <= hi_b:
                self.arm_len = length
                self.arm_length_estimate = length
                return length
        self.quality.reject("arm_reference_unusable")
        return self.arm_len
