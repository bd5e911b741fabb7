"""One device's clock, checked before its messages reach the pipeline (live and offline alike).

The pipeline handles small disorder per stream (``time_backwards``, ``duplicate_t``) and gaps.
What it cannot take is a stamp far from the others: a clock glitch ``t = 1e9`` made the
offline grid allocate 186 GiB, and live every later message was "going back in time". So a
message whose first stamp lies more than ``near_s`` from the newest fed stamp is not fed at
once; it is a *candidate* for a new time base:

- a candidate alone is a counted rejection (``time_jump``, or ``time_backwards`` when it
  lies in the past, the pipeline's name for that): one message never blinds a
  device, nor makes the pipeline span (and allocate for) its jump;
- the next message agreeing with it (within ``near_s``) confirms a *forward* jump of at most
  ``max_gap_s``: a pause of the device; it is fed and the pipeline handles the gap (the
  first message after the pause is the one lost);
- a jump backwards (a clock that restarted) or beyond ``max_gap_s`` needs ``confirm``
  agreeing messages in a row; then the stream is *reset*: the caller finishes the pipeline
  (its rows are kept) and starts a fresh one on the new time base (the heading converges
  again; the last nominal-shoulder event is carried over).

Events more than ``EVENT_S`` from the newest stamp are rejected (``time_jump``) and never
move it. Decisions depend on the stamps only, in feed order: ``rehab analyze`` decides as
the live service did.
"""

from __future__ import annotations

import math
from enum import Enum

NEAR_S = 2.0  # farther from the newest stamp: a candidate for a new time base
MAX_GAP_S = 3600.0  # a confirmed forward jump up to this is a pause (the pipeline bridges it)
CONFIRM = 10  # agreeing messages before a backward or longer jump resets the stream
EVENT_S = 60.0  # an event farther than this from the newest stamp is rejected


class Verdict(Enum):
    FEED = "feed"
    REJECT = "reject"  # counted under ClockGuard.reason
    RESET = "reset"  # finish the pipeline, start a fresh one, then feed


class ClockGuard:
    __slots__ = (
        "_cand_last",
        "_cand_n",
        "_forward",
        "confirm",
        "event_s",
        "max_gap_s",
        "near_s",
        "reason",
        "ref",
        "resets",
    )

    def __init__(
        self, near_s: float = NEAR_S, max_gap_s: float = MAX_GAP_S, confirm: int = CONFIRM
    ) -> None:
        self.near_s = near_s
        self.event_s = EVENT_S
        self.max_gap_s = max_gap_s
        self.confirm = confirm
        self.ref: float | None = None  # newest stamp fed
        self._cand_last: float | None = None  # newest stamp of the would-be new time base
        self._cand_n = 0
        self._forward = False  # the candidate base is ahead by at most max_gap_s
        self.resets = 0
        self.reason = "time_jump"  # of the last REJECT: time_jump, or time_backwards

    def stream(self, t0: float, t1: float) -> Verdict:
        """An IMU or robot message with stamps ``t0`` .. ``t1`` (finite, as decoded)."""
        if not (math.isfinite(t0) and math.isfinite(t1)):
            self.reason = "non_finite"
            return Verdict.REJECT
        ref, near = self.ref, self.near_s
        if ref is None or abs(t0 - ref) <= near:
            self._cand_last, self._cand_n = None, 0
            if ref is None or t1 > ref:
                self.ref = t1
            return Verdict.FEED
        last = self._cand_last
        if last is not None and abs(t0 - last) <= near:
            self._cand_n += 1
            self._cand_last = max(last, t1)
        else:
            self._cand_last, self._cand_n = t1, 1
            self._forward = 0.0 < t0 - ref <= self.max_gap_s
        if self._forward and self._cand_n >= 2:
            verdict = Verdict.FEED
        elif self._cand_n >= self.confirm:
            verdict = Verdict.RESET
            self.resets += 1
        else:
            self.reason = "time_backwards" if t0 < ref else "time_jump"
            return Verdict.REJECT
        self.ref = self._cand_last
        self._cand_last, self._cand_n = None, 0
        return verdict

    def event(self, t: float) -> bool:
        """Whether an event stamped ``t`` may be fed."""
        self.reason = "time_jump"
        return math.isfinite(t) and (self.ref is None or abs(t - self.ref) <= self.event_s)
