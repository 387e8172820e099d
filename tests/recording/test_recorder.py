"""Recorder: survives SIGKILL mid-write, rotates by size and age, pauses or stops below the free-space floor."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gateway.recording.format import ReadStats, read_recording
from gateway.recording.recorder import LowDiskSpace, Recorder, RecorderSettings

REPO = Path(__file__).resolve().parents[2]

CHILD = """
import sys
from pathlib import Path
from gateway.recording.recorder import Recorder, RecorderSettings
s = RecorderSettings(Path(sys.argv[1]), block_records=25, block_s=1e9, rotate_bytes=2_000_000, min_free_bytes=0,
                     resume_free_bytes=0, compress=False)
rec = Recorder(s)
i = 0
while True:
    rec.append("rig/rod/r-1/imu", (b"%08d" % i) * 2500, t_us=i, encoding="application/json")
    i += 1
    if i % 25 == 0:  # the recorder has just fsynced this block
        print(i, flush=True)
"""


def payload(i: int) -> bytes:
    return (b"%08d" % i) * 2500


def test_sigkill_mid_write_loses_nothing_that_was_synced(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(out)], cwd=REPO, stdout=subprocess.PIPE, text=True,
                            env=os.environ | {"PYTHONPATH": str(REPO)})  # fmt: skip
    assert proc.stdout is not None
    synced = 0
    deadline = time.monotonic() + 60
    while synced < 400 and time.monotonic() < deadline:  # 400 × 20 kB = 8 MB: several rotated files
        synced = int(proc.stdout.readline())
    proc.send_signal(signal.SIGKILL)  # while it keeps writing the next blocks
    proc.wait()
    assert synced >= 400
    stats = ReadStats()
    got = list(read_recording(out, stats))
    assert len(got) >= synced
    assert [r.payload for r in got] == [payload(i) for i in range(len(got))]  # a clean prefix, in order
    assert [r.t_us for r in got] == list(range(len(got)))
    assert stats.files >= 3  # rotated at 2 MB


class FakeDisk:
    def __init__(self, free: int) -> None:
        self.free = free

    def __call__(self, path: Path) -> int:
        return self.free


class FakeClock:
    def __init__(self) -> None:
        self.t = 1_767_225_600.0

    def __call__(self) -> float:
        return self.t


def test_rotation_by_age_and_size_gives_time_ordered_names(tmp_path: Path) -> None:
    clock = FakeClock()
    s = RecorderSettings(tmp_path, rotate_s=10.0, rotate_bytes=10_000, min_free_bytes=0, resume_free_bytes=0,
                         compress=False)  # fmt: skip
    with Recorder(s, clock=clock, free_bytes=FakeDisk(10**12)) as rec:
        for i in range(30):
            clock.t += 1.0
            rec.append("k", b"x" * 100, t_us=i)
        assert len(rec.stats.files) == 3  # a new file every 10 s
        for i in range(30, 40):
            rec.append("k", b"y" * 3000, t_us=i)  # same second: size rotation only
    sizes = [f.stat().st_size for f in rec.stats.files]
    assert len(sizes) == 5  # file 3 (1.3 kB) takes 3 big records, then 4 + 3: a file closes once beyond 10 kB
    assert all(n >= 10_000 for n in sizes[2:-1]) and sizes[-1] < 10_000
    assert sorted(rec.stats.files) == rec.stats.files
    assert [r.t_us for r in read_recording(tmp_path)] == list(range(40))


def test_low_disk_pauses_then_resumes_with_a_count_of_dropped_samples(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:  # fmt: skip
    disk, clock = FakeDisk(10**9), FakeClock()
    s = RecorderSettings(tmp_path, block_records=1, block_s=0.5, min_free_bytes=100, resume_free_bytes=200)
    with Recorder(s, clock=clock, free_bytes=disk) as rec:
        assert rec.append("k", b"a", 1)
        disk.free = 50
        clock.t += 1
        assert rec.append("k", b"b", 2)  # written, then the check after its block pauses the recorder
        assert rec.paused
        clock.t += 1
        assert not rec.append("k", b"c", 3)
        disk.free = 150  # above the floor but below the resume level: still paused
        clock.t += 1
        assert not rec.append("k", b"d", 4)
        disk.free = 10**9
        clock.t += 1
        assert rec.append("k", b"e", 5)
        assert rec.stats.dropped_low_disk == 2
    assert [r.payload for r in read_recording(tmp_path)] == [b"a", b"b", b"e"]
    assert "PAUSED" in caplog.text and "RESUMED" in caplog.text


def test_low_disk_stop_raises_on_the_next_append(tmp_path: Path) -> None:
    disk = FakeDisk(50)
    s = RecorderSettings(tmp_path, min_free_bytes=100, on_low_disk="stop")
    rec = Recorder(s, free_bytes=disk)
    assert not rec.append("k", b"a", 1)  # refused before any file is opened
    assert rec.stopped and rec.stats.files == []
    with pytest.raises(LowDiskSpace):
        rec.append("k", b"b", 2)
