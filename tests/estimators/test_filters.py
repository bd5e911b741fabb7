"""Filters: chunked filtering equals one call, and restarts have no step transient."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.filters import LowPass, dc_group_delay_s

LP = LowPass(5, 0.5, 25.0)
X = np.random.default_rng(0).normal(size=(400, 3))


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 60), min_size=1, max_size=20))
def test_chunking_is_bit_identical(sizes):
    whole, _ = LP(X, LP.initial_state(X[0]))
    zi = LP.initial_state(X[0])
    parts, i = [], 0
    for s in sizes:
        y, zi = LP(X[i : i + s], zi)
        parts.append(y)
        i += s
    y, _ = LP(X[i:], zi)
    parts.append(y)
    assert np.array_equal(np.concatenate(parts), whole)


def test_initial_state_is_steady():
    c = np.array([1.0, -2.0, 9.81])
    y, _ = LP(np.tile(c, (50, 1)), LP.initial_state(c))
    np.testing.assert_allclose(y, np.tile(c, (50, 1)), rtol=1e-9)


def test_group_delay_of_paper_filters():
    # 5th-order Butterworth: ~1 s at 0.5 Hz, ~0.2 s at 2.5 Hz (the gyro low-pass of eq. 1)
    assert 0.95 < dc_group_delay_s(5, 0.5, 25.0) < 1.1
    assert 0.18 < dc_group_delay_s(5, 2.5, 100.0) < 0.23
