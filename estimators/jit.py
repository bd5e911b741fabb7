"""numba's ``njit`` for the few compiled kernels (cached on disk, typed for mypy), and the
robot pipeline's kernels compiled ahead of time from the same source.

``NUMBA_DISABLE_JIT=1`` runs the same code interpreted (slow, same numbers); ``REHAB_AOT=0``
takes the kernels below from numba's JIT even when the built module holds them (an A/B).

Why ahead of time: numba's import and its first call of a kernel (even one from its disk
cache: it builds its typing registries, importing ``scipy.linalg`` and ``cffi``) cost
``rehab analyze`` 0.7–0.8 s of start-up (issue 23: ≤ 1.1 s wall for 8 minutes). The kernels
declared with :func:`aot` (typed, calling no other kernel) are compiled by
``python -m estimators.aot`` (``./run``'s set-up, the Docker image) into one extension module,
``estimators._kernels``, which needs numpy only. A kernel is taken from that module only
when the module holds it under the key of its current source and signature; otherwise (not
built, or built from an older source) it is numba's JIT as before, so the module can never
run stale code."""

from __future__ import annotations

import hashlib
import importlib
import inspect
import os
import re
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple, TypeVar, cast

import numpy as np

_Fn = TypeVar("_Fn", bound=Callable[..., Any])


def _cache_dir() -> str:
    """numba's disk cache checks only the defining file of each function: a kernel that calls
    another module's compiled code (``steps`` -> ``kernel``, ``mounting``) would keep running
    the old callee after an upgrade. The cache therefore lives in a directory named for the
    estimators' sources (``$NUMBA_CACHE_DIR``, else the package's ``__pycache__``), so a
    changed source never meets code compiled from an older one."""
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        digest.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    base = os.environ.get("NUMBA_CACHE_DIR") or str(root / "__pycache__" / "numba")
    return os.path.join(base, digest.hexdigest()[:16])


_numba: ModuleType | None = None


def _njit(**options: Any) -> Callable[[_Fn], _Fn]:
    """numba's ``njit`` with its cache set up (numba imported on the first use only)."""
    global _numba
    if _numba is None:
        import numba

        # set before any kernel is defined; not in the environment, so that child processes
        # (the service's workers) derive the same directory from the same base, not a nested one
        numba.config.CACHE_DIR = _cache_dir()  # type: ignore[attr-defined]
        _numba = numba
    return cast(Callable[[_Fn], _Fn], _numba.njit(cache=True, nogil=True, **options))


def jit(fn: _Fn) -> _Fn:
    """numba's ``njit`` (cached on disk), typed for mypy as the function itself."""
    return _njit()(fn)


def jit_inline(fn: _Fn) -> _Fn:
    """:func:`jit` for the small helpers, inlined into their callers."""
    return _njit(inline="always")(fn)


# --- ahead of time ---------------------------------------------------------------------


class Kernel(NamedTuple):
    """A kernel to compile ahead of time: its Python function, numba signature and the name
    the extension module exports it under (which carries the key of source and signature)."""

    fn: Callable[..., Any]
    signature: str
    export: str


# every kernel declared with :func:`aot` in the modules imported so far, by export name
KERNELS: dict[str, Kernel] = {}
MODULE = "estimators._kernels"
_DTYPES = {"f8": np.dtype(np.float64), "i8": np.dtype(np.int64)}
_ARG = re.compile(r"(\w+)(?:\[([^\]]*)\])?")
_built: ModuleType | bool | None = False  # False: not looked for yet


def export_name(fn: Callable[..., Any], signature: str) -> str:
    """``<module>__<function>_<key>``: the key hashes the function's source and signature, so
    an edited kernel never finds code compiled from its old source."""
    key = hashlib.sha256((inspect.getsource(fn) + "\0" + signature).encode()).hexdigest()[:16]
    return f"{fn.__module__.rsplit('.', 1)[-1]}__{fn.__name__.lstrip('_')}_{key}"


def _arg_specs(signature: str) -> list[tuple[np.dtype[Any], int, bool] | None]:
    """Per argument of ``"ret(a, b, ...)"``: (dtype, ndim, C-contiguous) of an array, None
    for a scalar."""
    args = signature[signature.index("(") + 1 : signature.rindex(")")]
    specs: list[tuple[np.dtype[Any], int, bool] | None] = []
    for m in _ARG.finditer(args):
        dims = m.group(2)
        if dims is None:
            specs.append(None)
        else:
            parts = [d.strip() for d in dims.split(",")]
            specs.append((_DTYPES[m.group(1)], len(parts), parts[-1] == "::1"))
    return specs


def _checked(
    compiled: Callable[..., Any], signature: str, name: str, export: str
) -> Callable[..., Any]:
    """The compiled function behind a check of its array arguments: an ahead-of-time
    function converts nothing and checks nothing (a wrong dtype or layout would read wrong
    memory), where numba's dispatcher would compile for the new types."""
    specs = _arg_specs(signature)

    def call(*args: Any) -> Any:
        for a, spec in zip(args, specs, strict=True):
            if spec is not None and not (
                isinstance(a, np.ndarray)
                and a.dtype == spec[0]
                and a.ndim == spec[1]
                and (a.flags.c_contiguous or not spec[2])
            ):
                raise TypeError(f"{name}: argument does not match {signature}")
        return compiled(*args)

    call.__name__ = name
    call.aot_export = export  # type: ignore[attr-defined]
    return call


def _module() -> ModuleType | None:
    global _built
    if _built is False:
        try:
            _built = importlib.import_module(MODULE)
        except ImportError:  # not built here (or for another Python/numpy)
            _built = None
    return cast(ModuleType | None, _built)


def aot(signature: str) -> Callable[[_Fn], _Fn]:
    """A kernel compiled ahead of time for numba ``signature`` (e.g. ``"void(f8[:, ::1])"``;
    arrays f8/i8, ``::1`` last for C order) when the built module holds it for this source,
    else :func:`jit`. The kernel must call no other compiled function."""

    def deco(fn: _Fn) -> _Fn:
        name = export_name(fn, signature)
        KERNELS[name] = Kernel(fn, signature, name)
        if os.environ.get("NUMBA_DISABLE_JIT", "0") == "0" and os.environ.get("REHAB_AOT") != "0":
            built = _module()
            compiled = getattr(built, name, None) if built is not None else None
            if compiled is not None:
                return cast(_Fn, _checked(compiled, signature, fn.__name__, name))
        return jit(fn)

    return deco


def uses_aot(fn: Callable[..., Any]) -> bool:
    """Whether ``fn`` (a kernel as its module holds it) is the ahead-of-time compiled one."""
    return hasattr(fn, "aot_export")
