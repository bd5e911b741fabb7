"""Contract recordings (§5): JSON Lines, one Zenoh message per line, plain or gzip.

``{"key": "<key expression>", "payload": <payload object>}`` in the order received.
Reading yields raw ``(key, payload)`` pairs and never raises on a bad line: a line that
is not such an object is yielded as ``(None, text)`` so the caller can count it.
"""

from __future__ import annotations

import gzip
import io
import json
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

import msgspec

Line = tuple[str | None, Any]


def _open_text(path: Path, mode: str) -> IO[str]:
    if path.suffix == ".gz":
        # mtime=0: the same messages give byte-identical files
        raw = gzip.GzipFile(path, mode + "b", compresslevel=6, mtime=0)
        return io.TextIOWrapper(raw, encoding="utf-8")
    return open(path, mode, encoding="utf-8")


class _Line(msgspec.Struct):
    key: str
    payload: msgspec.Raw  # left as JSON text for the typed decoder of its kind


_LINE = msgspec.json.Decoder(_Line)


def read(path: str | Path) -> Iterator[Line]:
    """Yield ``(key, payload)`` per line; ``(None, raw_line)`` for a line that is not valid.

    The payload comes back as its raw JSON bytes for :func:`backend.wire.decode`.
    """
    p = Path(path)
    with gzip.open(p, "rb") if p.suffix == ".gz" else open(p, "rb") as fh:
        for line in _lines(fh):
            if not line.strip():
                continue
            try:
                obj = _LINE.decode(line)
            except (msgspec.DecodeError, msgspec.ValidationError):
                yield None, line[:200].decode("utf-8", "replace")
                continue
            yield obj.key, obj.payload


def _lines(fh: Iterable[bytes]) -> Iterator[bytes]:
    """Lines of a file that may end mid-write (a killed recorder): a truncated gzip stream
    or a last line without its newline is where the recording stops, not an error."""
    try:
        for line in fh:
            if line.endswith(b"\n"):
                yield line
            # an unterminated last line was cut by the crash: dropped
    except EOFError:
        return


def write(path: str | Path, messages: Iterable[tuple[str, Any]]) -> int:
    """Write ``(key, payload)`` pairs; return how many were written."""
    n = 0
    with _open_text(Path(path), "w") as fh:
        for key, payload in messages:
            fh.write(json.dumps({"key": key, "payload": payload}, separators=(",", ":")))
            fh.write("\n")
            n += 1
    return n


class Writer:
    """Append-only recorder that flushes to the OS on demand (crash safety is the caller's)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fh = _open_text(self.path, "a")

    def append(self, key: str, payload: Any) -> None:
        self._fh.write(json.dumps({"key": key, "payload": payload}, separators=(",", ":")))
        self._fh.write("\n")

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()
