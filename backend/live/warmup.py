"""The compiled kernels loaded before the first device's turn.

With the kernels built ahead of time (``python -m estimators.aot``) these calls load only that
module. Without it (or with a module older than the sources) the first call of a kernel loads
numba's back-end (and with it scipy.linalg): about 0.5-1 s and 50 MiB. Paid in a device's
turn, it would stall every device of the process for that long; paid at start-up, it is part
of the process's resident size from the beginning (the fuzz benchmark's "memory flat"
measures growth, not this). The UKF's steps are not built ahead of time: a UKF device loads
numba on its first turn."""

from __future__ import annotations

import numpy as np

from estimators.filters import LowPass
from estimators.wearable import tracker
from estimators.wearable.params import WearableParams


def load_kernels() -> None:
    """Call the robot pipeline's filter and the wearable tracker once on empty data."""
    LowPass(5, 0.5, 25.0)(np.zeros((4, 3)), np.zeros((3, 2, 3)))
    tracker.run(WearableParams(), [])
