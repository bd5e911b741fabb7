"""Fixtures of the estimators' tests."""

from __future__ import annotations

import numpy as np
import pytest

from protocol import wire
from tests.conftest import Session

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray]


@pytest.fixture(scope="module")
def imu(short_session: Session) -> Arrays:
    """The session's first 30 s of IMU samples, with a short gap (bridged) and a long one
    (the 6D filter restarts: a new segment)."""
    ms = [m for m in short_session.messages if isinstance(m, wire.ImuMessage)]
    t = np.concatenate([m.t for m in ms])
    gyr = np.concatenate([m.gyr for m in ms])
    acc = np.concatenate([m.acc for m in ms])
    keep = (t < 30.0) & ~((t > 10.0) & (t < 10.05)) & ~((t > 20.0) & (t < 21.0))
    return t[keep], gyr[keep], acc[keep]
