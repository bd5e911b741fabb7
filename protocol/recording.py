"""Contract recordings (§5): JSON Lines, one Zenoh message per line, plain or gzip.

``{"key": "<key expression>", "payload": <payload object>}`` in the order received.
Reading yields raw ``(key, payload)`` pairs and never raises on a bad line: a line that
is not such an object is yielded as ``(None, text)`` so the caller can count it.
"""

from __future__ import annotations

import gzip
import io
import json
import struct
import zlib
from collections.abc import Iterable, Iterator
from itertools import chain
from pathlib import Path
from typing import IO, Any, NamedTuple

import msgspec

Line = tuple[str | None, Any]


def _open_text(path: Path, mode: str) -> IO[str]:
    if path.suffix == ".gz":
        # mtime=0: the same messages give byte-identical files
        raw = gzip.GzipFile(path, mode + "b", compresslevel=6, mtime=0)
        return io.TextIOWrapper(raw, encoding="utf-8")
    return open(path, mode, encoding="utf-8")


class _Line(msgspec.Struct, gc=False):  # never in a cycle: not worth the collector's time
    key: str
    payload: msgspec.Raw  # left as JSON text for the typed decoder of its kind


_LINE = msgspec.json.Decoder(_Line)


def read(path: str | Path) -> Iterator[Line]:
    """Yield ``(key, payload)`` per line; ``(None, raw_line)`` for a line that is not valid.

    The payload comes back as its raw JSON bytes for :func:`protocol.wire.decode`.
    """
    for line in lines(path):
        yield parse(line)


def lines(path: str | Path) -> Iterator[bytes]:
    """The lines :func:`read` parses (those not blank), as bytes, newline stripped."""
    # strip(): empty for a blank line; chained in C, no generator step per line
    return chain.from_iterable(filter(bytes.strip, part) for part in _line_lists(Path(path)))


def parse(line: bytes) -> Line:
    """What :func:`read` yields for one of its :func:`lines`."""
    try:
        obj = _LINE.decode(line)
    except (msgspec.DecodeError, msgspec.ValidationError):
        # the line as read, its newline included, cut at 200 bytes
        return None, (line + b"\n")[:200].decode("utf-8", "replace")
    return obj.key, obj.payload


_CHUNK = 1 << 24  # decompressed bytes per read: large reads, bounded memory


def _line_lists(path: Path) -> Iterator[list[bytes]]:
    """Complete lines of a file (without their newline), a list at a time, read in large
    chunks: a line reader costs more than the decompression itself. A file may end
    mid-write (a killed recorder): a truncated gzip stream or a last line without its
    newline is where the recording stops, not an error."""
    gz = path.suffix == ".gz"
    done = 0  # bytes of the decompressed stream already split into lines
    tail = b""
    with gzip.open(path, "rb") if gz else open(path, "rb") as fh:
        while True:
            try:
                chunk = fh.read(_CHUNK)
            except (EOFError, OSError, zlib.error):
                if not gz:
                    raise
                # a truncated (or corrupt) gzip stream: this read returned nothing of what
                # it had decompressed before the end
                break
            if not chunk:
                return
            done += len(chunk)
            part = (tail + chunk).split(b"\n")
            tail = part.pop()  # no newline yet: completed by the next chunk, if any
            yield part
    # line by line from where the chunks stopped: every line the stream still completes,
    # then the same end (silent if truncated, else the same error) as a line reader's
    with gzip.open(path, "rb") as fh:
        fh.seek(done)
        for line in _lines(fh):
            yield [tail + line[:-1]]
            tail = b""


def _lines(fh: Iterable[bytes]) -> Iterator[bytes]:
    """Lines (with their newline) up to where a truncated gzip stream ends; an
    unterminated last line was cut by the crash and is dropped."""
    try:
        for line in fh:
            if line.endswith(b"\n"):
                yield line
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


class Mark(NamedTuple):
    """A file's first ``size`` bytes (CRC-32 ``crc``), holding ``lines`` lines; for a
    recording in gzip, the CRC and length of the member's data up to there."""

    size: int
    crc: int
    lines: int
    data_crc: int = 0
    data_size: int = 0


# An empty final deflate block (fixed Huffman: BFINAL, BTYPE 01, end-of-block code): after
# a sync flush the stream is byte-aligned, so these two bytes end it where it stands.
_FINAL_BLOCK = b"\x03\x00"


def copy_prefix(src: Path, dst: Path, mark: Mark) -> Mark:
    """``dst`` := the first ``mark.size`` bytes of ``src`` (raises ``ValueError`` if they
    are not those the mark describes); for gzip, ended as a complete member, to which a
    ``Writer(dst, "a", start=<returned mark>)`` appends members. No recompression: a
    takeover copies hours of recording in the time of a file copy."""
    crc = 0
    left = mark.size
    with open(src, "rb") as fi, open(dst, "wb") as fo:
        while left:
            chunk = fi.read(min(left, _CHUNK))
            if not chunk:
                raise ValueError(f"{src.name} is shorter than its mark")
            crc = zlib.crc32(chunk, crc)
            fo.write(chunk)
            left -= len(chunk)
        if crc != mark.crc:
            raise ValueError(f"{src.name} does not begin with the bytes of its mark")
        size = mark.size
        if src.suffix == ".gz" and mark.size:
            end = _FINAL_BLOCK + struct.pack("<II", mark.data_crc, mark.data_size & 0xFFFFFFFF)
            fo.write(end)
            crc = zlib.crc32(end, crc)
            size += len(end)
    return Mark(size, crc, mark.lines)


# The recorder's deflate state: a 4 KiB window and a small hash (zlib's memLevel 4) instead
# of gzip's 32 KiB and memLevel 8: ~25 KiB per stream instead of ~260. A live service writes
# one stream per session, each flush a few KiB; with fifty of them the large states no longer
# fitted in the caches and compression ran ~3x slower. A flush's lines are a few KiB, so the
# smaller window loses nothing (the files came out slightly smaller).
_WBITS = 12
_MEM_LEVEL = 4


class Writer:
    """Append-only recorder of contract lines.

    Appended lines wait in memory (at most ``BUFFER_BYTES``) and are compressed together,
    once per flush (three small writes per line were most of a live session's recording
    cost). ``flush()`` pushes everything appended so far to the OS. For ``.gz`` each flush
    ends a deflate block with a sync marker, so a file cut by ``kill -9`` still yields every
    line up to the last flush (:func:`read` tolerates the missing gzip trailer). Crash safety
    is the caller's: flush often enough (the live service flushes every 0.25 s).

    The ``.gz`` file is a standard gzip member (mtime 0, no name: the same lines flushed at
    the same points give byte-identical files); mode ``"a"`` adds a member to an existing
    file, which gzip readers read as one stream.
    """

    BUFFER_BYTES = 1 << 20  # appended bytes held before they go to the compressor anyway
    _HEADS = 4096  # line openings remembered, one per key

    def __init__(
        self,
        path: str | Path,
        mode: str = "a",
        compresslevel: int = 6,
        start: Mark | None = None,
    ) -> None:
        """``start``: the file already holds that much (mode ``"a"``; a takeover's copy of
        a recording's prefix): :meth:`mark` goes on counting from it."""
        if mode not in ("a", "w", "x"):
            raise ValueError("mode must be 'a', 'w' or 'x'")
        self.path = Path(path)
        self.lines = start.lines if start else 0
        # the file's bytes and their CRC-32 (what a snapshot's mark checks a file against)
        self.written = start.size if start else 0
        self.written_crc = start.crc if start else 0
        self._raw: IO[bytes] = open(self.path, mode + "b", buffering=0)  # noqa: SIM115
        self._z: zlib._Compress | None = None  # for .gz
        self._crc = 0
        self._size = 0
        self._unsynced = False  # compressed since the last sync flush
        if self.path.suffix == ".gz":
            self._z = zlib.compressobj(compresslevel, zlib.DEFLATED, -_WBITS, _MEM_LEVEL)
            xfl = b"\x02" if compresslevel == 9 else b"\x04" if compresslevel == 1 else b"\x00"
            # magic, deflate, no flags, mtime 0, extra flags, OS unknown
            self._put(b"\x1f\x8b\x08\x00\x00\x00\x00\x00" + xfl + b"\xff")
        self._pending: list[bytes] = []
        self._pending_bytes = 0
        self._heads: dict[str, bytes] = {}  # key -> b'{"key":<key>,"payload":'
        self._closed = False

    def append(self, key: str, payload: Any) -> None:
        """One line from a payload object (encoded like :func:`write`)."""
        self.append_raw(key, json.dumps(payload, separators=(",", ":")).encode("utf-8"))

    def append_raw(self, key: str, payload: bytes) -> None:
        """One line from a payload that is already one JSON value without line breaks
        (the live service records payloads byte for byte as received)."""
        head = self._heads.get(key)
        if head is None:
            head = b'{"key":' + json.dumps(key).encode("utf-8") + b',"payload":'
            if len(self._heads) < self._HEADS:
                self._heads[key] = head
        line = head + payload + b"}\n"
        self._pending.append(line)
        self.lines += 1
        self._pending_bytes += len(line)
        if self._pending_bytes >= self.BUFFER_BYTES:
            self._write(sync=False)

    def _write(self, sync: bool) -> None:
        """The pending lines into the file (``sync``: all of them readable from it)."""
        data = b"".join(self._pending) if self._pending else b""
        self._pending.clear()
        self._pending_bytes = 0
        z = self._z
        if z is None:
            if data:
                self._put(data)
            return
        out = b""
        if data:
            self._crc = zlib.crc32(data, self._crc)
            self._size += len(data)
            out = z.compress(data)
            self._unsynced = True
        if sync and self._unsynced:
            out += z.flush(zlib.Z_SYNC_FLUSH)
            self._unsynced = False
        if out:
            self._put(out)

    def _put(self, data: bytes) -> None:
        self.written += len(data)
        self.written_crc = zlib.crc32(data, self.written_crc)
        view = memoryview(data)
        while view:  # an unbuffered write may take less than all
            view = view[self._raw.write(view) :]

    def flush(self) -> None:
        if not self._closed:
            self._write(sync=True)

    def mark(self) -> Mark:
        """Flush, then where the file stands: its bytes, their CRC, the lines in them, and
        (``.gz``) the member's data so far, which :func:`copy_prefix` needs to end it."""
        self.flush()
        return Mark(self.written, self.written_crc, self.lines, self._crc, self._size)

    def close(self) -> None:
        """Flush, end the gzip member (its trailer) and close."""
        if self._closed:
            return
        self._closed = True
        try:
            self._write(sync=False)
            if self._z is not None:
                self._put(
                    self._z.flush(zlib.Z_FINISH)
                    + struct.pack("<II", self._crc, self._size & 0xFFFFFFFF)
                )
        finally:
            self._raw.close()
