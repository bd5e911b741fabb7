"""A cycle boundary: a float time that carries where its cycle started, and how it was found."""

from __future__ import annotations

from typing import Literal, TypeAlias

Source: TypeAlias = Literal["path", "reach", "event"]


class Boundary(float):
    """A cycle boundary: a ``float`` time (s) with read-only extras.

    - ``cycle_start``: start (s) of the completed cycle ``[cycle_start, self)``, or ``None``
      when this boundary only opens a cycle (first boundary, or after a restart: the cycle
      before it was too short, too long, interrupted or from another source).
    - ``source``: ``"path"``, ``"reach"`` or ``"event"``.
    - ``detected_at``: s, ``>= self``; no sample at or after this time had been fed when the
      boundary was reported (the crossing sample for path/reach; the event time, or just after
      the data already seen for a late event). Consumers that act on a boundary per sample
      (:meth:`estimators.compensation.Indicator.cycle_completed`) start at samples with
      ``t >= detected_at`` to stay chunk-invariant.

    Compares, hashes and serialises (``json``) as the plain float.
    """

    __slots__ = ("cycle_start", "detected_at", "source")
    cycle_start: float | None
    source: Source
    detected_at: float

    def __new__(
        cls,
        t: float,
        cycle_start: float | None = None,
        source: Source = "path",
        detected_at: float | None = None,
    ) -> Boundary:
        obj = super().__new__(cls, t)
        obj.cycle_start = cycle_start
        obj.source = source
        obj.detected_at = float(t) if detected_at is None else detected_at
        return obj

    @property
    def closes_cycle(self) -> bool:
        return self.cycle_start is not None

    def __reduce__(
        self,
    ) -> tuple[type[Boundary], tuple[float, float | None, Source, float]]:
        return (Boundary, (float(self), self.cycle_start, self.source, self.detected_at))

    def __repr__(self) -> str:
        return (
            f"Boundary({float(self)!r}, cycle_start={self.cycle_start!r}, "
            f"source={self.source!r}, detected_at={self.detected_at!r})"
        )
