"""The `.rigrec` recording format: an appendable log of zenoh samples that a crash cannot corrupt beyond its tail.

Byte layout (all integers little-endian; full description with examples in docs/recording.md):

    file   = header record*
    header = magic "\\x89RIG\\r\\n\\x1a\\n" (8) | version u16 = 1 | flags u16 = 0 | meta_len u32 | meta (JSON, UTF-8)
             | crc32(magic .. meta) u32
    record = body_len u32 | crc32(body) u32 | body
    body   = t_us i64 | flags u8 (bit 0: payload zlib-compressed) | reserved u8 = 0 | key_len u16 | enc_len u16
             | key (UTF-8) | encoding (UTF-8) | payload (the rest of the body)

`t_us` is the arrival time (unix µs) for live recordings, the synthetic send time for imported ones. Readers stop at
the first record that is incomplete, too long or fails its CRC (a torn tail after a crash) and report how many bytes
they skipped; a writer reopening the file truncates that tail before appending.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Final

MAGIC: Final = b"\x89RIG\r\n\x1a\n"
VERSION: Final = 1
SUFFIX: Final = ".rigrec"
MAX_BODY_BYTES: Final = 16 * 1024 * 1024
"""A record longer than this is treated as corruption (zenoh payloads here are at most 512 KiB)."""
FLAG_ZLIB: Final = 0x01

_HEAD = struct.Struct("<8sHHI")  # magic, version, flags, meta_len
_REC = struct.Struct("<II")  # body_len, crc32(body)
_BODY = struct.Struct("<qBBHH")  # t_us, flags, reserved, key_len, enc_len


class FormatError(Exception):
    """The file is not a recording (bad magic, unknown version, corrupt header)."""


@dataclass(frozen=True, slots=True)
class Record:
    """One recorded zenoh sample: key expression, encoding string, payload bytes, time in unix µs."""

    key: str
    payload: bytes
    t_us: int
    encoding: str = ""


@dataclass
class ReadStats:
    """What a reader found: records returned and bytes of torn or corrupt tail skipped (per file, summed)."""

    records: int = 0
    files: int = 0
    tail_bytes: int = 0
    torn_files: list[str] = field(default_factory=list)


def encode_header(meta: dict[str, Any]) -> bytes:
    """The file header bytes for a metadata dict (JSON-serialisable)."""
    meta_b = json.dumps(meta, separators=(",", ":"), sort_keys=True).encode()
    head = _HEAD.pack(MAGIC, VERSION, 0, len(meta_b)) + meta_b
    return head + struct.pack("<I", zlib.crc32(head))


def encode_record(rec: Record, compress: bool = False) -> bytes:
    """One record's bytes; `compress` zlib-compresses the payload (level 1) when that makes it smaller."""
    key_b, enc_b = rec.key.encode(), rec.encoding.encode()
    payload, flags = rec.payload, 0
    if compress:
        packed = zlib.compress(payload, 1)
        if len(packed) < len(payload):
            payload, flags = packed, FLAG_ZLIB
    body = _BODY.pack(rec.t_us, flags, 0, len(key_b), len(enc_b)) + key_b + enc_b + payload
    if len(body) > MAX_BODY_BYTES:
        raise ValueError(f"record of {len(body)} bytes exceeds {MAX_BODY_BYTES}")
    return _REC.pack(len(body), zlib.crc32(body)) + body


def decode_body(body: bytes) -> Record:
    """A record from its (CRC-checked) body bytes."""
    t_us, flags, _, key_len, enc_len = _BODY.unpack_from(body)
    i = _BODY.size
    key = body[i : i + key_len].decode()
    enc = body[i + key_len : i + key_len + enc_len].decode()
    payload = body[i + key_len + enc_len :]
    if flags & FLAG_ZLIB:
        payload = zlib.decompress(payload)
    return Record(key, bytes(payload), t_us, enc)


def read_header(f: BinaryIO) -> dict[str, Any]:
    """Read and check the header at the file position; returns the metadata. Raises FormatError."""
    head = f.read(_HEAD.size)
    if len(head) < _HEAD.size or head[:8] != MAGIC:
        raise FormatError("not a rig recording (bad magic)")
    _, version, _, meta_len = _HEAD.unpack(head)
    if version != VERSION:
        raise FormatError(f"unsupported recording version {version} (this reader knows {VERSION})")
    meta_b = f.read(meta_len)
    crc_b = f.read(4)
    if len(meta_b) < meta_len or len(crc_b) < 4 or struct.unpack("<I", crc_b)[0] != zlib.crc32(head + meta_b):
        raise FormatError("corrupt or torn header")
    meta: dict[str, Any] = json.loads(meta_b)
    return meta


def _scan(f: BinaryIO) -> Iterator[tuple[int, bytes]]:
    """(end offset, body) of each intact record from the current position; stops at the first bad one."""
    while True:
        head = f.read(_REC.size)
        if len(head) < _REC.size:
            return
        body_len, crc = _REC.unpack(head)
        if body_len < _BODY.size or body_len > MAX_BODY_BYTES:
            return
        body = f.read(body_len)
        if len(body) < body_len or zlib.crc32(body) != crc:
            return
        yield f.tell(), body


def iter_file(path: str | Path, stats: ReadStats | None = None) -> Iterator[Record]:
    """Records of one file in order; a torn or corrupt tail ends the iteration (counted in `stats`)."""
    stats = stats if stats is not None else ReadStats()
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        read_header(f)
        end = f.tell()
        stats.files += 1
        for rec_end, body in _scan(f):
            end = rec_end
            stats.records += 1
            yield decode_body(body)
        if end < size:
            stats.tail_bytes += size - end
            stats.torn_files.append(str(path))


def recording_files(path: str | Path) -> list[Path]:
    """A recording is one `.rigrec` file or a directory of them (time-named, so name order is time order)."""
    p = Path(path)
    if p.is_dir():
        return sorted(q for q in p.iterdir() if q.suffix == SUFFIX)
    return [p]


def read_recording(path: str | Path, stats: ReadStats | None = None) -> Iterator[Record]:
    """Records of a file or of every file in a directory, in order."""
    for p in recording_files(path):
        yield from iter_file(p, stats)


def read_meta(path: str | Path) -> dict[str, Any]:
    """Metadata of the first file of a recording."""
    with open(recording_files(path)[0], "rb") as f:
        return read_header(f)


def valid_length(path: str | Path) -> int:
    """Bytes of the file up to the end of its last intact record (the header must be intact)."""
    with open(path, "rb") as f:
        read_header(f)
        end = f.tell()
        for rec_end, _ in _scan(f):
            end = rec_end
    return end


class RecordWriter:
    """Appends records to one file, buffered into blocks; `flush()` writes the block and fsyncs it.

    Opening an existing file checks its header and truncates a torn tail first, so appending after a crash
    never leaves garbage between records.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any] | None = None, *, compress: bool = False,
                 fsync: bool = True) -> None:  # fmt: skip
        self.path = Path(path)
        self.compress = compress
        self.fsync = fsync
        self._buf = bytearray()
        self.pending_records = 0
        self._f: BinaryIO
        if self.path.exists() and self.path.stat().st_size > 0:
            keep = valid_length(self.path)
            self._f = open(self.path, "r+b")  # noqa: SIM115 (closed in close())
            self._f.truncate(keep)
            self._f.seek(keep)
        else:
            self._f = open(self.path, "wb")  # noqa: SIM115
            self._f.write(encode_header(meta or {}))
            self._sync()
        self.size_bytes = self._f.tell()

    def append(self, rec: Record) -> int:
        """Buffer one record; returns its encoded size in bytes."""
        data = encode_record(rec, self.compress)
        self._buf += data
        self.pending_records += 1
        self.size_bytes += len(data)
        return len(data)

    def flush(self) -> None:
        """Write the buffered block and make it durable (fsync)."""
        if self._buf:
            self._f.write(self._buf)
            self._buf.clear()
            self.pending_records = 0
        self._sync()

    def _sync(self) -> None:
        self._f.flush()
        if self.fsync:
            os.fsync(self._f.fileno())

    def close(self) -> None:
        if not self._f.closed:
            self.flush()
            self._f.close()

    def __enter__(self) -> RecordWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_recording(path: str | Path, records: Iterator[Record] | list[Record], meta: dict[str, Any] | None = None,
                    *, compress: bool = True, block_records: int = 1000) -> int:  # fmt: skip
    """Write records to a new file (fsync every `block_records`); returns the count."""
    n = 0
    with RecordWriter(path, meta, compress=compress) as w:
        for rec in records:
            w.append(rec)
            n += 1
            if w.pending_records >= block_records:
                w.flush()
    return n
