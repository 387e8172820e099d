"""`Recorder`: time-named `.rigrec` files with block fsync, rotation by size or age, and a free-disk-space guard.

Not thread-safe: one thread calls `append` (the `record` command hands samples over from zenoh's threads through a
queue; the gateway may call it from its ingest task). Time is passed in (`t_us`), the clock is injectable.
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from gateway.recording.format import SUFFIX, Record, RecordWriter

log = logging.getLogger("gateway.recording")

LowDiskAction = Literal["pause", "stop"]


@dataclass(frozen=True)
class RecorderSettings:
    """Where and how to record; sizes in bytes, times in seconds."""

    directory: Path
    prefix: str = "rig"
    rotate_bytes: int = 256 * 1024 * 1024  # start a new file beyond this size
    rotate_s: float = 3600.0  # ... or when the file is this old (0 = never)
    block_s: float = 1.0  # fsync at least this often while records arrive
    block_records: int = 1000  # ... or after this many records
    min_free_bytes: int = 512 * 1024 * 1024  # below this free space the recorder pauses (or stops)
    resume_free_bytes: int = 768 * 1024 * 1024  # a pause ends when free space is back above this
    on_low_disk: LowDiskAction = "pause"
    compress: bool = True
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass
class RecorderStats:
    records: int = 0
    bytes: int = 0
    files: list[Path] = field(default_factory=list)
    dropped_low_disk: int = 0


def file_name(prefix: str, wall_s: float) -> str:
    """`{prefix}-YYYYmmddTHHMMSS.ffffffZ.rigrec` (UTC), so name order is time order (a second file opened in the
    same microsecond gets `_0001`, which sorts after it)."""
    stamp = datetime.fromtimestamp(wall_s, UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    return f"{prefix}-{stamp}{SUFFIX}"


def disk_free_bytes(path: Path) -> int:
    """Free bytes for an unprivileged writer on the file system holding `path`."""
    return shutil.disk_usage(path).free


class LowDiskSpace(RuntimeError):
    """Raised by `append` once the recorder has stopped for lack of disk space (`on_low_disk="stop"`)."""


class Recorder:
    """Appends zenoh samples to rotating time-named files; `append(key, payload, t_us, encoding)`."""

    def __init__(
        self,
        settings: RecorderSettings,
        clock: Callable[[], float] = time.time,
        free_bytes: Callable[[Path], int] = disk_free_bytes,
    ) -> None:
        self.settings = settings
        self.clock = clock
        self.free_bytes = free_bytes
        self.stats = RecorderStats()
        self.paused = False
        self.stopped = False
        self._writer: RecordWriter | None = None
        self._opened_s = 0.0
        self._last_flush_s = 0.0
        self._last_check_s = -float("inf")
        settings.directory.mkdir(parents=True, exist_ok=True)

    @property
    def path(self) -> Path | None:
        """The file being written, if any."""
        return self._writer.path if self._writer is not None else None

    def append(self, key: str, payload: bytes, t_us: int | None = None, encoding: str = "") -> bool:
        """Record one sample (t_us: arrival time, unix µs; default now). False if dropped for lack of disk space."""
        now = self.clock()
        if self.stopped:
            raise LowDiskSpace(f"recording stopped: free space below {self.settings.min_free_bytes} bytes")
        if self.paused and (now - self._last_check_s < self.settings.block_s or not self._check_disk()):
            self.stats.dropped_low_disk += 1
            return False
        w = self._writer_for(now)
        if w is None:
            self.stats.dropped_low_disk += 1
            return False
        self.stats.bytes += w.append(Record(key, bytes(payload), int(now * 1e6) if t_us is None else t_us, encoding))
        self.stats.records += 1
        if w.pending_records >= self.settings.block_records or now - self._last_flush_s >= self.settings.block_s:
            self.flush()
        return True

    def tick(self) -> None:
        """Flush a block that is older than `block_s` (call when idle so quiet streams still reach the disk)."""
        if self._writer is not None and self._writer.pending_records and (
                self.clock() - self._last_flush_s >= self.settings.block_s):  # fmt: skip
            self.flush()

    def flush(self) -> None:
        """Write and fsync the current block; checks free space first."""
        if self._writer is None:
            return
        self._last_flush_s = self.clock()
        self._writer.flush()
        self._check_disk()

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def _check_disk(self) -> bool:
        """Update the pause/stop state from the free space; True when recording may go on."""
        self._last_check_s = self.clock()
        free = self.free_bytes(self.settings.directory)
        if not self.paused and free < self.settings.min_free_bytes:
            self.paused = True
            mb = free / 1e6
            if self.settings.on_low_disk == "stop":
                self.stopped = True
                log.error("recording STOPPED: %.0f MB free in %s, below the floor of %.0f MB",
                          mb, self.settings.directory, self.settings.min_free_bytes / 1e6)  # fmt: skip
                self.close()
            else:
                log.warning("recording PAUSED: %.0f MB free in %s, below the floor of %.0f MB; resumes above %.0f MB",
                            mb, self.settings.directory, self.settings.min_free_bytes / 1e6,
                            self.settings.resume_free_bytes / 1e6)  # fmt: skip
                self.close()
        elif self.paused and not self.stopped and free >= self.settings.resume_free_bytes:
            self.paused = False
            log.warning("recording RESUMED: %.0f MB free (%d samples dropped while paused)", free / 1e6,
                        self.stats.dropped_low_disk)  # fmt: skip
        return not self.paused

    def _writer_for(self, now: float) -> RecordWriter | None:
        w = self._writer
        s = self.settings
        too_old = s.rotate_s > 0 and now - self._opened_s >= s.rotate_s
        if w is not None and (w.size_bytes >= s.rotate_bytes or too_old):
            self.close()
            w = None
        if w is None:
            if not self._check_disk():
                return None
            path = s.directory / file_name(s.prefix, now)
            n = 1
            while path.exists():
                path = s.directory / f"{file_name(s.prefix, now)[: -len(SUFFIX)]}_{n:04d}{SUFFIX}"  # sorts after
                n += 1
            meta = {"created_wall_us": int(now * 1e6), "format": "rigrec", **s.meta}
            w = self._writer = RecordWriter(path, meta, compress=s.compress)
            self._opened_s = self._last_flush_s = now
            self.stats.files.append(path)
        return w

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
