"""The kernels compiled ahead of time (``python -m estimators.aot``) against numba's JIT of the
same Python source: bit for bit on random and structured data; a wrong argument is refused,
not read as wrong memory; a changed source is never served by the module built from the old one.

Uses the module built in the package when it is up to date, else builds one (~90 s)."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numba
import numpy as np
import pytest

from estimators import aot, filters, heading, imu_stage, jit, peaks, rows
from estimators.output import COL, NCOL
from estimators.wearable import kernel, steps, tracker
from estimators.wearable.params import WearableParams
from simulator import wearable as w

RNG = np.random.default_rng(3)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> ModuleType:
    mod = aot.built()
    if mod is not None and not aot.missing(mod):
        return mod
    path = aot.build(tmp_path_factory.mktemp("aot"))
    spec = importlib.util.spec_from_file_location(jit.MODULE, path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    # a single-phase extension registers itself in sys.modules: keep this one out of the
    # process's kernels (and other tests' view of what is built)
    sys.modules.pop(jit.MODULE, None)
    assert not aot.missing(mod)
    return mod


def pair(built: ModuleType, fn: Any) -> tuple[Callable[..., Any], Callable[..., Any]]:
    """(ahead of time behind its argument check, numba's JIT) of the kernel ``fn``."""
    (k,) = [k for k in aot.kernels().values() if k.fn.__name__ == fn.__name__]
    compiled = jit._checked(getattr(built, k.export), k.signature, k.fn.__name__, k.export)
    jit.load()  # the helpers it calls as numba's dispatchers
    return compiled, numba.njit(k.fn)


def test_every_kernel_is_built_and_declared_once() -> None:
    names = sorted(k.fn.__name__ for k in aot.kernels().values())
    assert names == [
        "_fit_kernel",
        "_peaks",
        "_sosfilt",
        "_store",
        "_weighted_sums",
        "compute",
        "feed",
        "pose",
    ]


def test_sosfilt_equals_the_jit(built: ModuleType) -> None:
    compiled, jitted = pair(built, filters._sosfilt)
    for design in [
        (5, 0.5, 25.0, "lowpass"),
        (5, 2.5, 100.0, "lowpass"),
        (8, 40.0, 100.0, "highpass"),
    ]:
        sos = filters.butter_sos(*design)
        for n, c in [(1, 3), (7, 1), (5000, 6)]:
            x = RNG.normal(size=(n, c)) * 10.0 ** RNG.integers(-8, 8, size=c)
            zi = RNG.normal(size=(len(sos), 2, c))
            xa, za, xj, zj = x.copy(), zi.copy(), x.copy(), zi.copy()
            compiled(sos, xa, za)
            jitted(sos, xj, zj)
            assert xa.tobytes() == xj.tobytes() and za.tobytes() == zj.tobytes()


def test_weighted_sums_equal_the_jit(built: ModuleType) -> None:
    compiled, jitted = pair(built, imu_stage._weighted_sums)
    for n, m, c in [(1, 1, 1), (40, 9, 15), (3000, 29, 15)]:
        x = RNG.normal(size=(n + m + 50, c + 1))
        w = RNG.random((n, m)) * (RNG.random((n, m)) > 0.2)
        start = np.sort(RNG.integers(0, 50, size=n))
        for xs in (x[:, :c].copy(), x[:, 1:]):  # C order and a strided view
            assert compiled(w, start, xs).tobytes() == jitted(w, start, xs).tobytes()


def test_heading_fit_equals_the_jit(built: ModuleType) -> None:
    compiled, jitted = pair(built, heading._fit_kernel)
    params = heading.HeadingParams()
    for n, with_cl, block_s in [(2, False, 0.0), (500, False, 4.0), (1000, True, 4.0)]:
        tau = np.linspace(-40.0, 0.0, n)
        a = RNG.normal(size=(n, 3))
        # a noisier stretch, so that the block refit weights it
        b = a[:, [1, 0, 2]] + RNG.normal(size=(n, 3)) * np.where(tau < -30.0, 1.0, 0.05)[:, None]
        cl = RNG.normal(size=(n, 18)) if with_cl else heading._NO_CL
        par = heading._kernel_params(params, 0.001, 3, 2, block_s)
        results = []
        for fn in (compiled, jitted):
            x, out = np.full(6, 0.01), np.empty(4)
            fn(a, b, tau, cl, x, par, out)
            results.append(x.tobytes() + out.tobytes())
        assert results[0] == results[1]


def test_peaks_equal_the_jit(built: ModuleType) -> None:
    compiled, jitted = pair(built, peaks._peaks)
    flat = np.repeat(RNG.integers(0, 5, size=300).astype(float), RNG.integers(1, 4, size=300))
    for x in (RNG.normal(size=5000).cumsum(), flat, np.zeros(0), np.ones(2)):
        for floor in (0.0, 0.5, 3.0):
            a, j = compiled(x, floor), jitted(x, floor)
            assert a.dtype == j.dtype and a.tobytes() == j.tobytes()


def test_store_equals_the_jit(built: ModuleType) -> None:
    compiled, jitted = pair(built, imu_stage._store)
    cols = imu_stage.ImuStage.COLUMNS
    for n, v_rows in [(1, 0), (7, 7), (300, 0)]:
        t = np.cumsum(RNG.random(n) * 0.02 + 1e-3)
        x = [RNG.normal(size=(n, c)) for c in (4, 4, 3, 3, 3)]
        v = x[3] if v_rows else np.zeros((0, 3))
        for prev in (np.full(4, np.nan), np.r_[t[0] - 0.01, RNG.normal(size=3)]):
            a = np.full((n, imu_stage.ImuStage.WIDTH), -1.0)
            j, pa, pj = a.copy(), prev.copy(), prev.copy()
            compiled(a, t, 2.0, x[0], x[1], x[2], v, x[4], pa, cols)
            jitted(j, t, 2.0, x[0], x[1], x[2], v, x[4], pj, cols)
            assert a.tobytes() == j.tobytes() and pa.tobytes() == pj.tobytes()


def test_rows_equal_the_jit(built: ModuleType) -> None:
    """Every branch: rows with and without the IMU, decided before it arrived, before the
    first sample and the first heading update, across a segment change, in each timing mode;
    the automatic nominal shoulder's exact mean."""
    compiled, jitted = pair(built, rows.compute)
    ni, n = 400, 600
    imu = np.zeros((ni, imu_stage.ImuStage.WIDTH))
    imu[:, 0] = np.arange(ni) * 0.01
    imu[:, 1] = (imu[:, 0] > 2.0).astype(float)
    q = RNG.normal(size=(ni, 4))
    imu[:, 2:6] = q / np.linalg.norm(q, axis=1)[:, None]
    imu[:, 6:12] = RNG.normal(size=(ni, 6))
    t = np.sort(RNG.uniform(-0.5, 4.5, n))
    rin = np.stack(
        [
            t,
            (RNG.random(n) > 0.1).astype(float),
            (t > 3.0).astype(float),
            np.where(RNG.random(n) > 0.8, t - 0.03, np.inf),
            np.full(n, 0.3),
        ],
        axis=1,
    )
    robot = RNG.normal(size=(n, 9))
    snaps = np.array(
        [
            [0.5, 0.3, 0.01, 0.4, 0.02, 0.0, 0.0, 0.05],
            [1.0, 0.31, 0.01, 0.9, 0.01, 1.0, 0.0, -0.1],
            [2.5, np.nan, 0.0, 2.5, np.inf, 0.0, 1.0, np.nan],
            [3.0, 7.0, -0.02, 2.9, 0.01, 1.0, 1.0, 0.04],
        ]
    )
    specs = np.array([[np.nan, np.nan, np.nan, 1.0], [0.1, 0.2, 0.3, 0.0]])
    col = np.concatenate((imu_stage.ImuStage.LOOKUP, [COL[c] for c in rows.OUT])).astype(np.int64)
    for timing in rows.TIMING:
        for norm in ("horizontal", "3d"):
            st, part = rows.new_state(0.02, 0.1, 0.5, norm, timing)
            sa, pa, sj, pj = st.copy(), part.copy(), st.copy(), part.copy()
            oa, oj = np.zeros((n, NCOL)), np.zeros((n, NCOL))
            compiled(rin, robot, imu, snaps, specs, sa, pa, col, oa)
            jitted(rin, robot, imu, snaps, specs, sj, pj, col, oj)
            assert oa.tobytes() == oj.tobytes() and sa.tobytes() == sj.tobytes()
            assert pa.tobytes() == pj.tobytes()
            assert np.isfinite(oa[:, COL["nominal_shoulder"]]).any()


def test_a_wrong_argument_is_refused(built: ModuleType) -> None:
    compiled, _ = pair(built, peaks._peaks)
    for bad in (np.zeros(5, dtype=np.float32), np.zeros((5, 2))[:, 0], np.zeros((5, 1)), [0.0]):
        with pytest.raises(TypeError, match="_peaks"):
            compiled(bad, 1.0)


def test_a_changed_source_or_signature_is_not_served(built: ModuleType) -> None:
    k = next(iter(aot.kernels().values()))
    assert jit.export_name(k.fn, k.signature) == k.export
    assert jit.export_name(k.fn, k.signature.replace("f8", "i8", 1)) != k.export

    def _sosfilt(sos: Any, x: Any, zi: Any) -> None:  # an edited kernel of the same name
        x[0, 0] = 0.0

    edited = jit.export_name(_sosfilt, k.signature)
    assert not hasattr(built, edited)
    try:
        assert not jit.uses_aot(jit.aot(k.signature)(_sosfilt))  # numba's JIT instead
    finally:
        del jit.KERNELS[edited]


def test_pose_equals_the_jit(built: ModuleType) -> None:
    compiled, jitted = pair(built, kernel.pose)
    for theta in RNG.uniform(-3.5, 3.5, size=(50, 5)):
        lu, lf = RNG.uniform(0.2, 0.4, size=2)
        for a, j in zip(compiled(theta, lu, lf), jitted(theta, lu, lf), strict=True):
            assert a.dtype == j.dtype and a.flags.c_contiguous and a.tobytes() == j.tobytes()


@pytest.mark.parametrize("camera", [False, True])
def test_the_wearable_tracker_equals_the_jit(
    built: ModuleType, camera: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """steps.feed (the pairing, the EKF with the mounting states, the monitors, the σ's
    widening) over a whole session, through the tracker: the same bytes as numba's JIT."""
    sim = w.simulate(w.WearableSimConfig(move="rom", duration_s=20.0, seed=4, camera=camera))
    inputs = w.tracker_inputs(sim.messages)
    blocks = []
    for variant in (0, 1):
        monkeypatch.setattr(steps, "feed", pair(built, steps.feed)[variant])
        for side in ("right", "left"):  # the left arm's inputs are mirrored copies
            p = WearableParams.from_json(sim.params, side=side)
            rows, state = tracker.run(p, inputs)
            block = rows.block  # type: ignore[attr-defined]
            blocks.append((block.tobytes(), state.x.tobytes(), state.P.tobytes()))
            if side == "right":
                assert block.shape[1] > 1000 and np.isfinite(block[1:6]).all()
    assert blocks[:2] == blocks[2:]


def test_a_changed_helper_is_not_served(monkeypatch: pytest.MonkeyPatch) -> None:
    """A kernel's key covers every source of the package (the helpers it calls): an edit
    anywhere gives every kernel a new name, which an older module does not hold."""
    k = next(k for k in aot.kernels().values() if k.fn.__name__ == "feed")
    assert jit.export_name(k.fn, k.signature) == k.export
    monkeypatch.setattr(jit, "sources_digest", lambda: "0" * 16)
    assert jit.export_name(k.fn, k.signature) != k.export


def test_the_helpers_do_not_import_numba() -> None:
    """Importing the wearable tracker (its helpers declared with ``jit``) loads no numba:
    numba comes with the first call of a kernel the built module does not hold."""
    code = (
        "import sys; from estimators.wearable import kernel, mounting, steps, tracker; "
        "print('numba' in sys.modules)"
    )
    for env in ("0", "1"):
        out = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "REHAB_AOT": env},
        ).stdout
        assert out.split() == ["False"]


def test_the_mode_says_how_the_kernels_run(built: ModuleType) -> None:
    """``aot.mode()`` (the service's ``/api/health``): ahead of time with the module current,
    numba's JIT without it (``REHAB_AOT=0``, or a module built into another directory), and
    interpreted with numba's JIT off."""

    def mode(env: dict[str, str]) -> str:
        return subprocess.run(
            [sys.executable, "-c", "from estimators import aot; print(aot.mode())"],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, **env},
        ).stdout.strip()

    assert mode({"REHAB_AOT": "0"}) == "jit"
    assert mode({"NUMBA_DISABLE_JIT": "1"}) == "interpreted"
    if Path(built.__file__ or "").resolve().parent == aot.PACKAGE_DIR:
        assert mode({"REHAB_AOT": "1"}) == "ahead-of-time"
    else:  # built by the fixture elsewhere: the package holds none (or a stale one)
        assert mode({"REHAB_AOT": "1"}) == "jit"
