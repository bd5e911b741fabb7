"""The kernels compiled ahead of time (``python -m estimators.aot``) against numba's JIT of the
same Python source: bit for bit on random and structured data; a wrong argument is refused,
not read as wrong memory; a changed source is never served by the module built from the old one.

Uses the module built in the package when it is up to date, else builds one (~20 s)."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from types import ModuleType
from typing import Any

import numba
import numpy as np
import pytest

from estimators import aot, filters, imu_stage, jit, peaks

RNG = np.random.default_rng(3)


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> ModuleType:
    try:
        mod: ModuleType | None = importlib.import_module(jit.MODULE)
    except ImportError:
        mod = None
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
    return compiled, numba.njit(k.fn)


def test_every_kernel_is_built_and_declared_once() -> None:
    names = sorted(k.fn.__name__ for k in aot.kernels().values())
    assert names == ["_peaks", "_sosfilt", "_weighted_sums"]


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


def test_peaks_equal_the_jit(built: ModuleType) -> None:
    compiled, jitted = pair(built, peaks._peaks)
    flat = np.repeat(RNG.integers(0, 5, size=300).astype(float), RNG.integers(1, 4, size=300))
    for x in (RNG.normal(size=5000).cumsum(), flat, np.zeros(0), np.ones(2)):
        for floor in (0.0, 0.5, 3.0):
            a, j = compiled(x, floor), jitted(x, floor)
            assert a.dtype == j.dtype and a.tobytes() == j.tobytes()


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
