"""CSV text of numeric columns: ``fmt % row`` per row, NaN as an empty cell, built column by
column in numpy for many rows (an offline analysis formats ~10^4 rows at once; per-row
formatting dominated it). Shared by the robot mode's estimates/details and the wearable
mode's joints.csv."""

from __future__ import annotations

import operator
from typing import Any

import numpy as np

Column = np.ndarray | list[str]


def lines(fmt: str, cols: list[Column], first: list[str] | None = None) -> list[str]:
    """``fmt % row`` per row, NaN as an empty cell ("nan" cannot occur otherwise)."""
    if len(cols[0]) >= VECTOR_ROWS:
        return table_lines(fmt, cols, first)
    return format_rows(fmt, [c.tolist() if isinstance(c, np.ndarray) else c for c in cols])


def format_rows(fmt: str, cols: list[list[Any]]) -> list[str]:
    """``fmt % row`` per row, NaN as an empty cell ("nan" cannot occur otherwise): one
    C-level format per row."""
    return [(fmt % row).replace("nan", "") for row in zip(*cols, strict=True)]


# Below this many rows (a live poll's one or two) per-row formatting is cheaper than the
# fixed cost of the column-wise path; both give the same text.
VECTOR_ROWS = 64
_TEXT = ("%r", "%s")  # columns whose cells are Python strings


def table_lines(fmt: str, cols: list[Column], first: list[str] | None = None) -> list[str]:
    """The same text as :func:`format_rows`, built column by column as ASCII bytes in numpy
    (see the module docstring).

    A text column at either end (both files' t, the state) is added to the lines as
    strings: as a byte matrix it cost more than all the numeric columns together.
    ``first``: the first column's :func:`texts` if made already."""
    specs = fmt.split(",")
    n = len(cols[0])
    lo = 1 if specs[0] in _TEXT else 0
    hi = len(specs) - 1 if len(specs) > 1 and specs[-1] in _TEXT else len(specs)
    parts: list[np.ndarray] = []
    redo = np.zeros(n, dtype=bool)  # rows the shortcut cannot vouch for: formatted per row
    for k in range(lo, hi):
        if k:
            parts.append(np.full((n, 1), ord(","), np.uint8))
        spec, col = specs[k], cols[k]
        if spec in _TEXT:
            parts.append(_ascii(texts(spec, col), n))
        elif spec == "%d":
            cells, bad = _int_cells(np.asarray(col, dtype=np.int64))
            parts.append(cells)
            redo |= bad
        else:  # "%.<p>f"
            cells, bad = _fixed_cells(np.asarray(col, dtype=np.float64), int(spec[2:-1]))
            parts.append(cells)
            redo |= bad
    if hi < len(specs):
        parts.append(np.full((n, 1), ord(","), np.uint8))
    lines = [""] * n
    if parts:
        parts.append(np.full((n, 1), ord("\n"), np.uint8))
        body = np.concatenate(parts, axis=1).tobytes().translate(None, b"\0")  # no padding
        lines = body.decode("ascii").split("\n")
        lines.pop()  # after the last newline
    if lo:
        lines = list(map(operator.add, first or texts(specs[0], cols[0]), lines))
    if hi < len(specs):
        lines = list(map(operator.add, lines, texts(specs[-1], cols[-1])))
    for i in np.flatnonzero(redo).tolist():
        row = tuple(c[i].item() if isinstance(c, np.ndarray) else c[i] for c in cols)
        lines[i] = (fmt % row).replace("nan", "")
    return lines


def texts(spec: str, col: Column) -> list[str]:
    """``spec % v`` per value of a text column (NaN: an empty cell for ``%r``)."""
    if spec == "%s":
        return list(map(str, col))
    x = np.asarray(col, dtype=np.float64)
    text = list(map(repr, x.tolist()))
    for i in np.flatnonzero(np.isnan(x)).tolist():
        text[i] = ""
    return text


def _ascii(text: list[str], n: int) -> np.ndarray:
    """Strings as an (n, width) byte matrix, NUL-padded (NUL bytes are dropped at the end)."""
    a = np.array(text, dtype=np.bytes_)
    return a.view(np.uint8).reshape(n, a.dtype.itemsize)


def _fixed_cells(x: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """``"%.{p}f" % v`` per value as a NUL-padded byte matrix (NaN: an empty cell), and
    the values it leaves to ``%`` itself (exact ties, inf, beyond 2^52).

    ``%`` rounds the exact binary value. ``v = |x|·10^p`` (10^p exact) is that product
    rounded once; below 2^52 a ``v`` that is not a half-integer rounds (``rint``) the same
    way as the exact product, because ±0.5 is a multiple of ``v``'s ulp and the rounding
    error is half an ulp. A half-integer ``v`` (recorded 6-decimal values printed with 5
    are common) goes the way of the product's exact rounding error.
    """
    nan = np.isnan(x)
    a = np.abs(x)
    scale = 10.0**p
    with np.errstate(over="ignore", invalid="ignore"):
        v = a * scale
        ok = v < 2.0**52
        q = np.rint(np.where(ok, v, 0.0))
        half = np.flatnonzero(np.abs(v - q) == 0.5)
    if len(half):
        vh = v[half]
        err = _product_error(a[half], scale, vh)
        q[half] = np.floor(vh) + (err > 0)
        ok[half[err == 0]] = False  # an exact tie: left to %'s own tie rule
    cells = _digits(q.astype(np.int64), np.signbit(x), p)
    cells[nan] = 0
    return cells, ~ok & ~nan


def _product_error(a: np.ndarray, b: float, ab: np.ndarray) -> np.ndarray:
    """``a·b − ab`` exactly, for ``ab`` the rounded product (Dekker's two-product)."""

    def split(y: Any) -> tuple[Any, Any]:  # Veltkamp: halves of 26 and 27 bits
        c = 134217729.0 * y
        hi = c - (c - y)
        return hi, y - hi

    ah, al = split(a)
    bh, bl = split(b)
    return ((ah * bh - ab) + ah * bl + al * bh) + al * bl  # type: ignore[no-any-return]


def _int_cells(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    bad = x == np.iinfo(np.int64).min  # no absolute value in int64
    return _digits(np.abs(np.where(bad, 0, x)), x < 0, 0), bad


def _digits(q: np.ndarray, neg: np.ndarray, p: int) -> np.ndarray:
    """Cells ``[-]<q // 10^p>[.<q % 10^p, p digits>]``: a sign byte, the integer digits
    (leading zeros as NUL padding), then the point and the fraction."""
    # int32 division is several times faster than int64's; x - (x // 10) * 10 than x % 10
    q = q.astype(np.int32 if len(q) and q.max() < 2**31 else np.int64)
    ip, fp = np.divmod(q, 10**p)
    nd = len(str(int(ip.max()))) if len(ip) else 1
    width = 1 + nd + (1 + p if p else 0)
    # built a character position at a time: as rows of its transpose, each write is
    # contiguous (written as columns, strided, they cost more than the arithmetic)
    cells = np.zeros((width, len(q)), np.uint8)
    cells[0] = neg * np.uint8(ord("-"))
    for k in range(nd):  # right to left; the units digit is always written
        r = ip // 10
        d = ip - r * 10 + ord("0")
        cells[nd - k] = d if k == 0 else d * (ip > 0)
        ip = r
    if p:
        cells[nd + 1] = ord(".")
        for k in range(p):
            r = fp // 10
            cells[width - 1 - k] = fp - r * 10 + ord("0")
            fp = r
    return cells.T
