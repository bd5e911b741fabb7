"""Stage of the pipeline's rows: the nominal shoulder and the upper-arm length (paper §3.4,
contract §4), per row, from the specifications fed so far (parameter, rope reference,
automatic after convergence or after a reset event)."""

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
    """Nominal shoulder and upper-arm length of each row.

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
        self._nom_spec = -1
        self._nom_point: tuple[float, ...] | None = None
        self._nom_acc: list[tuple[float, ...]] = []
        self._nom_t0: float | None = None
        self._ref_point: Array | None = None  # the last rope-measured point (for l_A)
        self.arm_len = params.upper_arm_length_m
        self._arm_spec = -1
        self._arm_spec_done = -1
        self._arm_pts: list[Array] = []
        self._arm_free: set[int] = set()  # specs whose rows all use arm_len as it is
        self.arm_length_estimate: float | None = None

    def add_reference(self, t: float, point: Array) -> None:
        """A ``shoulder_reference`` event: the rope end on the shoulder at ``point`` (m)."""
        self._specs.append(("point", t, np.asarray(point, dtype=np.float64)))

    def add_reset(self, t: float) -> None:
        """A ``nominal_reset`` event: the nominal shoulder is set anew, automatically."""
        self._specs.append(("auto", t, None))

    def spec_for(self, tr: float) -> int:
        """The newest spec (in feed order) whose time has come at row time ``tr``."""
        k = len(self._specs) - 1
        while k > 0 and self._specs[k][1] > tr:
            k -= 1
        return k

    def arm_length(self, t: float, p_e: Sequence[float], k: int) -> float:
        """Upper-arm length at a row of spec ``k`` (see :meth:`_measure`)."""
        return self.arm_len if k in self._arm_free else self._measure(t, p_e, k)

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

    def nominal_at(
        self, t: float, shoulder: tuple[float, ...], good: bool, k: int
    ) -> tuple[float, ...]:
        """Nominal shoulder at a row (contract §4): parameter, rope reference, or automatic
        (mean estimate over ``auto_nominal_s`` after convergence / after a reset event)."""
        if k != self._nom_spec:
            self._nom_spec = k
            kind, _, point = self._specs[k]
            self._nom_point = None if point is None else tuple(point.tolist())
            self._nom_acc, self._nom_t0 = [], None
            if point is not None and kind == "point":
                self._ref_point = point
        if self._nom_point is None and good:
            if self._nom_t0 is None:
                self._nom_t0 = t
            self._nom_acc.append(shoulder)
            if t - self._nom_t0 >= self.params.auto_nominal_s:
                m = len(self._nom_acc)
                self._nom_point = tuple(math.fsum(c) / m for c in zip(*self._nom_acc, strict=True))
                self._nom_acc = []
        return NAN3 if self._nom_point is None else self._nom_point
