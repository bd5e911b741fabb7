"""Filters and the peak finder against ``scipy.signal`` (the independent oracle; the
estimators do not import it): the same numbers, bit for bit, on random data, on a simulated
session's IMU and robot streams and on a real BROAD recording (skipped without the data),
including state carried across chunks; and their physical properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal, sparse

from estimators import filters, imu_stage, peaks
from estimators.filters import LowPass, dc_group_delay_s
from evaluation import broad
from protocol import wire
from tests.conftest import Session

LP = LowPass(5, 0.5, 25.0)
X = np.random.default_rng(0).normal(size=(400, 3))
# orders, cut-offs (fractions of Nyquist) and rates, both sides of fs/4 (the bilinear
# transform's real pole changes sign there) and the project's own designs
DESIGNS = [
    (order, frac * fs / 2, fs, btype)
    for order in range(1, 9)
    for frac in (0.002, 0.04, 0.2, 0.5, 0.7, 0.98)
    for fs in (25.0, 100.0, 285.714)
    for btype in ("lowpass", "highpass")
] + [(5, 0.5, 25.0, "lowpass"), (5, 2.5, 100.0, "lowpass"), (2, 6.0, 100.0, "lowpass")]


def scipy_sos(order: int, cutoff: float, fs: float, btype: str = "lowpass") -> np.ndarray:
    return np.asarray(signal.butter(order, cutoff, btype=btype, fs=fs, output="sos"))


@pytest.mark.parametrize("design", DESIGNS)
def test_design_and_steady_state_equal_scipys(design: tuple[int, float, float, str]) -> None:
    sos = filters.butter_sos(*design)
    ref = scipy_sos(*design)
    assert sos.tobytes() == ref.tobytes()  # bit for bit, signed zeros included
    assert filters.sosfilt_zi(sos).tobytes() == signal.sosfilt_zi(ref).tobytes()


@pytest.mark.parametrize(
    "design", [(5, 0.5, 25.0), (5, 2.5, 100.0), (2, 6.0, 100.0), (3, 9.0, 25.0)]
)
def test_group_delay_equals_scipys(design: tuple[int, float, float]) -> None:
    b, a = signal.sos2tf(scipy_sos(*design))
    _, gd = signal.group_delay((b, a), w=[1e-4], fs=design[2])
    assert dc_group_delay_s(*design) == float(gd[0]) / design[2]


def test_group_delay_of_paper_filters() -> None:
    # 5th-order Butterworth: ~1 s at 0.5 Hz, ~0.2 s at 2.5 Hz (the gyro low-pass of eq. 1)
    assert 0.95 < dc_group_delay_s(5, 0.5, 25.0) < 1.1
    assert 0.18 < dc_group_delay_s(5, 2.5, 100.0) < 0.23


def test_bad_designs_are_refused() -> None:
    for args in [(5, 0.0, 25.0), (5, 12.5, 25.0), (0, 1.0, 25.0)]:
        with pytest.raises(ValueError):
            filters.butter_sos(*args)
    with pytest.raises(ValueError):
        filters.butter_sos(2, 1.0, 25.0, "bandpass")


def chunked(f: LowPass, x: np.ndarray, zi: np.ndarray, sizes: list[int]) -> np.ndarray:
    parts, i = [], 0
    for s in [*sizes, len(x)]:
        y, zi = f(x[i : i + s], zi)
        parts.append(y)
        i += s
    return np.concatenate(parts)


def assert_streams_equal_scipy(f: LowPass, x: np.ndarray, sizes: list[int]) -> None:
    """Whole and chunked output and final state equal scipy's sosfilt from the same state."""
    zi = f.initial_state(x[0])
    ref, ref_zf = signal.sosfilt(f.sos.copy(), x, axis=0, zi=zi)
    y, zf = f(x, zi)
    assert np.array_equal(y, ref) and np.array_equal(zf, ref_zf)
    assert np.array_equal(chunked(f, x, zi, sizes), ref)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 60), min_size=1, max_size=20))
def test_chunking_is_bit_identical_to_scipy(sizes: list[int]) -> None:
    assert_streams_equal_scipy(LP, X, sizes)


@pytest.mark.parametrize("design", DESIGNS[::7])
def test_random_state_and_data_equal_scipy(design: tuple[int, float, float, str]) -> None:
    rng = np.random.default_rng(len(DESIGNS) + design[0])
    f = LowPass(design[0], design[1], design[2], design[3])
    x = rng.normal(size=(500, 4)) * rng.uniform(1e-3, 1e3, size=4)
    zi = rng.normal(size=(len(f.sos), 2, 4))
    ref, ref_zf = signal.sosfilt(f.sos.copy(), x, axis=0, zi=zi)
    y, zf = f(x, zi)
    assert np.array_equal(y, ref) and np.array_equal(zf, ref_zf)


def test_simulated_streams_equal_scipy(short_session: Session) -> None:
    """The paper's gyro low-pass on the IMU stream and the grid's 0.5 Hz low-pass on the
    robot's wrist positions, in the messages' own chunks."""
    imu = [m for m in short_session.messages if isinstance(m, wire.ImuMessage)]
    gyr = np.concatenate([m.gyr for m in imu])
    assert_streams_equal_scipy(LowPass(5, 2.5, 100.0), gyr, [len(m.t) for m in imu[:-1]])
    rob = [m for m in short_session.messages if isinstance(m, wire.RobotMessage)]
    wrist = np.concatenate([m.wrist for m in rob])
    assert_streams_equal_scipy(LP, wrist, [len(m.t) for m in rob[:-1]])


BROAD_TRIAL = min(broad.trial_paths(), key=lambda p: p.stat().st_size, default=None)


@pytest.mark.skipif(BROAD_TRIAL is None, reason=f"BROAD data not found in {broad.data_dir()}")
def test_real_recording_equals_scipy() -> None:
    assert BROAD_TRIAL is not None
    trial = broad.load_trial(BROAD_TRIAL)
    x = np.concatenate([trial.gyr, trial.acc], axis=1)
    assert_streams_equal_scipy(LowPass(5, 2.5, trial.rate_hz), x, [1, 7, 100, 3, 1000])
    pad = 3 * (2 * 3 + 1)
    sos = filters.butter_sos(5, 6.0, trial.rate_hz)
    ref = signal.sosfiltfilt(sos.copy(), trial.acc, axis=0, padlen=pad)
    assert np.array_equal(filters.filtfilt(sos, trial.acc, pad), ref)
    v = np.linalg.norm(trial.gyr, axis=1)
    for floor in (0.01, 0.1, 1.0):
        assert np.array_equal(peaks.find_peaks(v, floor), signal.find_peaks(v, prominence=floor)[0])


def test_initial_state_is_steady() -> None:
    c = np.array([1.0, -2.0, 9.81])
    y, _ = LP(np.tile(c, (50, 1)), LP.initial_state(c))
    np.testing.assert_allclose(y, np.tile(c, (50, 1)), rtol=1e-9)


def test_lowpass_passes_slow_and_stops_fast_signals() -> None:
    """Butterworth magnitude: 1 well below the cut-off, 1/√2 at it, ~0 far above it."""
    fs, t = 25.0, np.arange(0, 400.0, 1 / 25.0)
    f = LowPass(5, 0.5, fs)
    for hz, gain, tol in [(0.05, 1.0, 1e-3), (0.5, 2**-0.5, 2e-3), (5.0, 0.0, 1e-4)]:
        x = np.sin(2 * np.pi * hz * t)[:, None]
        y, _ = f(x, np.zeros((3, 2, 1)))
        assert np.max(np.abs(y[len(y) // 2 :])) == pytest.approx(gain, abs=tol)


@pytest.mark.parametrize("n", [2, 3, 9, 10, 31, 500])
@pytest.mark.parametrize("order", [1, 2, 5])
def test_filtfilt_equals_scipys_sosfiltfilt(n: int, order: int) -> None:
    rng = np.random.default_rng(n * order)
    x = rng.normal(size=(n, 3)).cumsum(axis=0)
    sos = filters.butter_sos(order, 6.0, 100.0)
    pad = min(3 * (2 * len(sos) + 1), n - 1)
    ref = signal.sosfiltfilt(sos.copy(), x, axis=0, padlen=pad)
    assert np.array_equal(filters.filtfilt(sos, x, pad), ref)


def random_profiles() -> list[np.ndarray]:
    rng = np.random.default_rng(5)
    out = [rng.normal(size=n) for n in (0, 1, 2, 3, 5, 50, 1000)]
    out += [np.round(rng.normal(size=300), 1) for _ in range(5)]  # ties and flat tops
    out += [np.abs(np.sin(np.linspace(0, 9, 400))) + 0.05 * rng.normal(size=400)]
    out += [np.array([0.0, 1.0, 1.0, 1.0, 0.0, 2.0, 2.0, 0.0]), np.ones(10)]
    out += [np.array([0.0, 1.0, np.nan, 3.0, 1.0, 2.0, 0.0])]
    return out


@pytest.mark.parametrize("floor", [0.0, 0.05, 0.3, 1.0, 5.0])
def test_peaks_equal_scipys_find_peaks(floor: float) -> None:
    for v in random_profiles():
        ref = signal.find_peaks(v, prominence=floor)[0]
        assert np.array_equal(peaks.find_peaks(v, floor), ref), v


def test_weighted_sums_equal_the_sparse_product() -> None:
    """The grid's anti-alias sums equal scipy.sparse's CSR product, bit for bit."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(300, 15))
    w = rng.uniform(size=(120, 9))
    start = np.sort(rng.integers(0, 300 - 9, size=120))
    idx = start[:, None] + np.arange(9)
    kernel = sparse.csr_matrix(
        (w.ravel(), idx.ravel(), np.arange(0, 120 * 9 + 1, 9)), shape=(120, len(x))
    )
    ref = np.asarray(kernel @ x)
    for xs in (x, np.asfortranarray(x)):  # the channels come either way
        assert np.array_equal(imu_stage._weighted_sums(w, start, xs), ref)
