"""numba's ``njit`` for the few compiled kernels (cached on disk, typed for mypy), and the
kernels called from Python compiled ahead of time from the same source.

``NUMBA_DISABLE_JIT=1`` runs the same code interpreted (slow, same numbers); ``REHAB_AOT=0``
takes the kernels below from numba's JIT even when the built module holds them (an A/B).

Why ahead of time: numba's import and its first call of a kernel (even one from its disk
cache: it builds its typing registries, importing ``scipy.linalg`` and ``cffi``) cost
``rehab analyze`` 0.7–0.8 s of start-up (issues 19, 23). The kernels declared with :func:`aot`
(typed; they may call :func:`jit` helpers, compiled into them) are compiled by
``python -m estimators.aot`` (``./run``'s set-up, the Docker image) into one extension module,
``estimators._kernels``, which needs numpy only. A kernel is taken from that module only
when the module holds it under the key of its current source, its signature and the sources
of the whole package (a helper it calls may live in any module); otherwise (not built, or
built from older sources) every kernel is numba's JIT as before, so the module can never run
stale code.

The helpers (:func:`jit`) are created lazily: numba is imported on the first call of one from
Python (or of a kernel the module does not hold), not when their module is imported, so a
process served by the module never imports numba. From then on every kernel is numba's
dispatcher in its module's namespace (:func:`load`): compiled callers need dispatchers, not
the module's Python-level functions."""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.machinery
import importlib.util
import inspect
import os
import re
import sys
import threading
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
    base = os.environ.get("NUMBA_CACHE_DIR") or str(_ROOT / "__pycache__" / "numba")
    return os.path.join(base, sources_digest())


_ROOT = Path(__file__).resolve().parent


@functools.cache
def sources_digest() -> str:
    """A digest of every source file of the package (16 hex digits)."""
    digest = hashlib.sha256()
    for f in sorted(_ROOT.rglob("*.py")):
        digest.update(f.relative_to(_ROOT).as_posix().encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()[:16]


_numba: ModuleType | None = None


class _Lazy:
    """A kernel whose numba dispatcher is made on its first call (numba imported then)."""

    def __init__(self, fn: Callable[..., Any], options: dict[str, Any]) -> None:
        functools.update_wrapper(self, fn)
        self.fn = fn
        self.options = options
        self.dispatcher: Callable[..., Any] | None = None

    def __call__(self, *args: Any) -> Any:
        load()
        assert self.dispatcher is not None
        return self.dispatcher(*args)


# the kernels not yet numba's dispatchers (lazy helpers, the module's functions), by id
_PENDING: dict[int, Any] = {}


_LOCK = threading.Lock()


def load() -> ModuleType:
    """numba, imported and set up, with every kernel made numba's dispatcher in the namespace
    of every module of the package (for compiled callers and the build); once per process."""
    global _numba
    if _numba is not None:
        return _numba
    with _LOCK:  # a worker's threads may make their first calls together
        if _numba is None:
            import numba

            # set before any kernel is compiled; not in the environment, so that child
            # processes (the service's workers) derive the same directory from the same base
            numba.config.CACHE_DIR = _cache_dir()  # type: ignore[attr-defined]
            for k in _PENDING.values():
                _dispatch(numba, k)
            swap = {id(k): k.dispatcher for k in _PENDING.values()}
            for name, mod in list(sys.modules.items()):
                if mod is not None and (name == __package__ or name.startswith(__package__ + ".")):
                    ns = vars(mod)
                    for attr, value in list(ns.items()):
                        if id(value) in swap and _PENDING.get(id(value)) is value:
                            ns[attr] = swap[id(value)]
            _PENDING.clear()
            _numba = numba
    return _numba


def _dispatch(numba: Any, k: Any) -> None:
    if isinstance(k, _Lazy):
        k.dispatcher = numba.njit(cache=True, nogil=True, **k.options)(k.fn)
    else:  # a function of the built module: its JIT form (compiled callers need it)
        k.dispatcher = numba.njit(cache=True, nogil=True)(k.aot_fn)


def _njit(**options: Any) -> Callable[[_Fn], _Fn]:
    """numba's ``njit`` (cached on disk), made on the first call once numba is imported."""

    def deco(fn: _Fn) -> _Fn:
        if _numba is not None:
            return cast(_Fn, _numba.njit(cache=True, nogil=True, **options)(fn))
        lazy = _Lazy(fn, options)
        _PENDING[id(lazy)] = lazy
        return cast(_Fn, lazy)

    return deco


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
_DTYPES = {"f8": np.dtype(np.float64), "i8": np.dtype(np.int64), "b1": np.dtype(np.bool_)}
_ARG = re.compile(r"(\w+)(?:\[([^\]]*)\])?")
_built: ModuleType | bool | None = False  # False: not looked for yet


def export_name(fn: Callable[..., Any], signature: str) -> str:
    """``<module>__<function>_<key>``: the key hashes the function's source, signature and the
    package's sources (:func:`sources_digest`: the helpers it calls), so an edited kernel or
    helper never finds code compiled from its old source."""
    text = "\0".join((inspect.getsource(fn), signature, sources_digest()))
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    return f"{fn.__module__.rsplit('.', 1)[-1]}__{fn.__name__.lstrip('_')}_{key}"


def _arg_specs(signature: str) -> list[tuple[np.dtype[Any], int, bool] | None]:
    """Per argument of ``"ret(a, b, ...)"``: (dtype, ndim, C-contiguous) of an array, None
    for a scalar (the return type may be a ``Tuple((...))``)."""
    end = signature.rindex(")")
    depth = 0
    for start in range(end, -1, -1):  # the "(" that matches the last ")"
        depth += {")": 1, "(": -1}.get(signature[start], 0)
        if depth == 0:
            break
    args = signature[start + 1 : end]
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
    compiled: Callable[..., Any], signature: str, name: str, export: str, blas: bool = False
) -> Callable[..., Any]:
    """The compiled function behind a check of its array arguments: an ahead-of-time
    function converts nothing and checks nothing (a wrong dtype or layout would read wrong
    memory), where numba's dispatcher would compile for the new types."""
    specs = _arg_specs(signature)
    arrays = [(i, *s) for i, s in enumerate(specs) if s is not None]
    nargs = len(specs)

    def fits(a: Any, dtype: np.dtype[Any], ndim: int, c_order: bool) -> bool:
        return (
            isinstance(a, np.ndarray)
            and a.dtype == dtype
            and a.ndim == ndim
            and (not c_order or a.flags.c_contiguous)
        )

    def call(*args: Any) -> Any:
        if len(args) != nargs:
            raise TypeError(f"{name}: {len(args)} arguments for {signature}")
        for i, dtype, ndim, c_order in arrays:
            a = args[i]
            # the common case first, cheaply (a kernel of many arguments is called per message)
            if (
                a.__class__ is not np.ndarray
                or a.dtype is not dtype
                or a.ndim != ndim
                or (c_order and not a.flags.c_contiguous)
            ) and not fits(a, dtype, ndim, c_order):
                raise TypeError(f"{name}: argument {i} does not match {signature}")
        if blas and not _blas_ready:
            _scipy_blas()
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


_blas_ready = False


def _scipy_blas() -> None:
    """numba's BLAS and LAPACK calls (``@``, ``np.linalg``) in the built module look their
    routines up in SciPy's ``scipy.linalg.cython_blas`` and ``cython_lapack`` on first use;
    imported normally, those bring the whole ``scipy.linalg`` package first (0.2–0.4 s of
    ``rehab analyze``'s start-up). Each is a self-contained extension module, so it is loaded
    here from its file on its own, unless ``scipy.linalg`` is imported already; when SciPy's
    layout differs, nothing is done (the lookup then imports them the usual way)."""
    global _blas_ready
    with _LOCK:  # once, even when a worker's threads make their first calls together
        if _blas_ready or "scipy.linalg" in sys.modules:
            _blas_ready = True
            return
        spec = importlib.util.find_spec("scipy")
        base = Path(next(iter(spec.submodule_search_locations or ()), "")) if spec else None
        for name in ("cython_blas", "cython_lapack"):
            full = f"scipy.linalg.{name}"
            if base is None or full in sys.modules:
                continue
            files = [base / "linalg" / (name + s) for s in importlib.machinery.EXTENSION_SUFFIXES]
            path = next((f for f in files if f.is_file()), None)
            ext = importlib.util.spec_from_file_location(full, path) if path else None
            if ext is None or ext.loader is None:
                continue
            module = importlib.util.module_from_spec(ext)
            sys.modules[full] = module
            try:
                ext.loader.exec_module(module)
            except ImportError:
                del sys.modules[full]
        _blas_ready = True


def aot(signature: str, blas: bool = False) -> Callable[[_Fn], _Fn]:
    """A kernel compiled ahead of time for numba ``signature`` (e.g. ``"void(f8[:, ::1])"``;
    arrays f8/i8/b1, ``::1`` last for C order; a tuple returned as ``Tuple((...))``) when the
    built module holds it for these sources, else :func:`jit`. It may call :func:`jit`
    helpers and other kernels (compiled into it); once numba is loaded in the process
    (:func:`load`) it is numba's dispatcher like them. ``blas``: it (or a helper) calls
    numba's BLAS/LAPACK (``@``, ``np.linalg``; see :func:`_scipy_blas`)."""

    def deco(fn: _Fn) -> _Fn:
        name = export_name(fn, signature)
        KERNELS[name] = Kernel(fn, signature, name)
        if (
            _numba is None
            and os.environ.get("NUMBA_DISABLE_JIT", "0") == "0"
            and os.environ.get("REHAB_AOT") != "0"
        ):
            built = _module()
            compiled = getattr(built, name, None) if built is not None else None
            if compiled is not None:
                call = _checked(compiled, signature, fn.__name__, name, blas)
                call.aot_fn = fn  # type: ignore[attr-defined]
                _PENDING[id(call)] = call
                return cast(_Fn, call)
        return jit(fn)

    return deco


def uses_aot(fn: Callable[..., Any]) -> bool:
    """Whether ``fn`` (a kernel as its module holds it) is the ahead-of-time compiled one."""
    return hasattr(fn, "aot_export")
