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


@settings(max_examples=30, deadline=None)
@given(
    st.sampled_from([(5, 0.5, "lowpass"), (2, 0.1, "highpass"), (1, 0.05, "highpass")]),
    st.integers(1, 200),
    st.integers(1, 24),
    st.integers(0, 2**32 - 1),
)
def test_call_is_scipy_sosfilt(spec, n, c, seed):
    """The direct call of scipy's compiled loop gives signal.sosfilt's bits and state."""
    from scipy import signal

    order, cutoff, btype = spec
    f = LowPass(order, cutoff, 25.0, btype)
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, c))[:, ::-1]  # not contiguous either
    zi = f.initial_state(rng.normal(size=c))
    y, zf = f(x, zi)
    y0, zf0 = signal.sosfilt(f.sos, x, axis=0, zi=zi)
    assert y.shape == y0.shape and zf.shape == zf0.shape
    assert np.array_equal(y, y0) and np.array_equal(zf, zf0)
    zi_copy, x_copy = zi.copy(), x.copy()
    f(x, zi)
    assert np.array_equal(zi, zi_copy) and np.array_equal(x, x_copy)  # inputs untouched
