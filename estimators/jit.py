"""numba's ``njit`` for the few compiled kernels (cached on disk, typed for mypy).

``NUMBA_DISABLE_JIT=1`` runs the same code interpreted (slow, same numbers)."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast


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


import numba  # noqa: E402

# set before any kernel is defined; not in the environment, so that child processes (the
# service's workers) derive the same directory from the same base, not a nested one
numba.config.CACHE_DIR = _cache_dir()  # type: ignore[attr-defined]

_Fn = TypeVar("_Fn", bound=Callable[..., Any])


def jit(fn: _Fn) -> _Fn:
    """numba's ``njit`` (cached on disk), typed for mypy as the function itself."""
    return cast(_Fn, numba.njit(cache=True, nogil=True)(fn))


def jit_inline(fn: _Fn) -> _Fn:
    """:func:`jit` for the small helpers, inlined into their callers."""
    return cast(_Fn, numba.njit(cache=True, nogil=True, inline="always")(fn))
