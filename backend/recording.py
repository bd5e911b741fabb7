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
    """Append-only recorder of contract lines.

    ``flush()`` pushes everything appended so far to the OS. For ``.gz`` each flush ends a
    deflate block with a sync marker, so a file cut by ``kill -9`` still yields every line
    up to the last flush (:func:`read` tolerates the missing gzip trailer). Crash safety is
    the caller's: flush often enough (the live service flushes every 0.25 s).
    """

    def __init__(self, path: str | Path, mode: str = "a", compresslevel: int = 6) -> None:
        if mode not in ("a", "w", "x"):
            raise ValueError("mode must be 'a', 'w' or 'x'")
        self.path = Path(path)
        self.lines = 0
        self._raw: IO[bytes] = open(self.path, mode + "b")  # noqa: SIM115
        self._fh: IO[bytes] = self._raw
        if self.path.suffix == ".gz":
            # mtime=0: the same messages give byte-identical files
            self._fh = gzip.GzipFile(  # type: ignore[assignment]
                fileobj=self._raw, mode="ab", compresslevel=compresslevel, mtime=0
            )

    def append(self, key: str, payload: Any) -> None:
        """One line from a payload object (encoded like :func:`write`)."""
        self.append_raw(key, json.dumps(payload, separators=(",", ":")).encode("utf-8"))

    def append_raw(self, key: str, payload: bytes) -> None:
        """One line from a payload that is already one JSON value without line breaks
        (the live service records payloads byte for byte as received)."""
        self._fh.write(b'{"key":' + json.dumps(key).encode("utf-8") + b',"payload":')
        self._fh.write(payload)
        self._fh.write(b"}\n")
        self.lines += 1

    def flush(self) -> None:
        self._fh.flush()  # GzipFile: Z_SYNC_FLUSH, then flushes the file object
        if self._fh is not self._raw:
            self._raw.flush()

    def close(self) -> None:
        if self._fh is not self._raw:
            self._fh.close()  # writes the gzip trailer; leaves fileobj open
        self._raw.close()
