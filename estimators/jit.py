"""numba's ``njit`` for the few compiled kernels (cached on disk, typed for mypy).

``NUMBA_DISABLE_JIT=1`` runs the same code interpreted (slow, same numbers)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

_Fn = TypeVar("_Fn", bound=Callable[..., Any])


def jit(fn: _Fn) -> _Fn:
    """numba's ``njit`` (cached on disk), typed for mypy as the function itself."""
    return cast(_Fn, numba.njit(cache=True, nogil=True)(fn))


def jit_inline(fn: _Fn) -> _Fn:
    """:func:`jit` for the small helpers, inlined into their callers."""
    return cast(_Fn, numba.njit(cache=True, nogil=True, inline="always")(fn))
