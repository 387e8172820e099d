"""Replay: record -> replay -> record is the identity on keys, encodings, payloads and order (real zenoh, two
processes, free ports, multicast off); pacing follows the recorded time line; devices appear via liveliness."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from bench.bite_latency import free_port
from gateway import schemas
from gateway.fusion import broad
from gateway.recording import replay as replay_mod
from gateway.recording.format import Record, read_recording, write_recording
from gateway.recording.importers import broad_records
from gateway.recording.replay import Publisher, device_token, replay, select

pytestmark = pytest.mark.timeout(120)
REPO = Path(__file__).resolve().parents[2]


def source_records(broad_dir: Path) -> list[Record]:
    trial = broad.load_trial(broad_dir / "24_disturbed_tapping_A.mat").slice(0, 600)
    recs = list(broad_records(trial, "tap-1", samples_per_packet=10))
    extra = [
        Record("rig/ball/ball-1/env", b'{"not":"validated by replay"}', recs[3].t_us, schemas.ENCODING_ENV),
        Record("rig/rod/tap-1/reel/cmd", b"{}", recs[5].t_us, schemas.ENCODING_REEL_CMD),  # a command: never replayed
        Record("gw/rod/tap-1/attitude", b"{}", recs[7].t_us, schemas.ENCODING_GW),  # gateway output: never replayed
        Record("rig/hook/h-2/imu", b"\x00\x01binary", recs[9].t_us, ""),  # no encoding given
    ]
    return sorted([*recs, *extra], key=lambda r: r.t_us)


def test_replay_then_record_is_the_identity(tmp_path: Path, broad_dir: Path) -> None:
    src = tmp_path / "src.rigrec"
    records = source_records(broad_dir)
    write_recording(src, records)
    expected = list(select(records, replay_mod.DEVICE_KEYS))
    assert len(expected) == len(records) - 2
    port = free_port()
    out = tmp_path / "out"
    rec = subprocess.Popen(
        [sys.executable, "-m", "gateway.recording.record", "-o", str(out), "--connect", "none", "--listen",
         f"tcp/127.0.0.1:{port}", "--count", str(len(expected)), "--no-progress", "--min-free-mb", "0"],
        cwd=REPO, stderr=subprocess.PIPE, text=True, env=os.environ | {"PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    try:
        assert rec.stderr is not None
        while "recording" not in rec.stderr.readline():
            assert rec.poll() is None, "recorder exited early"
        assert replay_mod.main([str(src), "--fast", "--no-progress", "--connect", f"tcp/127.0.0.1:{port}",
                                "--linger-s", "0.2"]) == 0  # fmt: skip
        assert rec.wait(timeout=30) == 0
    finally:
        if rec.poll() is None:
            rec.kill()
    got = list(read_recording(out))
    assert [(r.key, r.encoding or "", r.payload) for r in got] == [
        (r.key, r.encoding or "zenoh/bytes", r.payload) for r in expected
    ]
    imu = [schemas.decode(r.key, r.payload) for r in got if r.key == "rig/rod/tap-1/imu"]
    assert [p.seq for p in imu] == list(range(60))  # original sequence numbers and device times
    assert all(isinstance(p, schemas.ImuPacket) and p.t0_us == 1_000_000 + round(p.seq * 10e6 / p.rate_hz)
               for p in imu)  # fmt: skip


def test_pacing_follows_the_recorded_time_line_scaled_by_speed() -> None:
    recs = [Record("rig/rod/r/imu", b"%d" % i, 5_000_000 + t) for i, t in enumerate((0, 100_000, 100_000, 1_000_000))]

    class Clock:
        t = 0.0

        def now(self) -> float:
            return self.t

        def sleep(self, s: float) -> None:
            self.t += s

    for speed, expect in ((1.0, [0.0, 0.1, 0.1, 1.0]), (10.0, [0.0, 0.01, 0.01, 0.1]), (None, [0.0] * 4)):
        clock, sent = Clock(), []
        stats = replay(lambda r: sent.append(clock.t), recs, speed, sleep=clock.sleep, clock=clock.now)  # noqa: B023
        assert sent == pytest.approx(expect, abs=1e-12)
        assert stats.published == 4 and stats.recorded_s == pytest.approx(1.0)


def test_replayed_devices_are_online_while_the_replay_runs() -> None:
    port = free_port()
    listen, connect = zenoh.Config(), zenoh.Config()
    listen.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    connect.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    for c in (listen, connect):
        c.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(listen) as watcher, zenoh.open(connect) as device:
        seen: list[tuple[str, bool]] = []
        sub = watcher.liveliness().declare_subscriber(
            "rig/*/*", lambda s: seen.append((str(s.key_expr), s.kind == zenoh.SampleKind.PUT)), history=True)
        time.sleep(0.5)
        pub = Publisher(device)
        pub.put(Record("rig/rod/rod-7/imu", b"{}", 0))
        pub.put(Record("rig/ball/ball-3/env", b"{}", 0))
        deadline = time.monotonic() + 5
        while len(seen) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert sorted(seen) == [("rig/ball/ball-3", True), ("rig/rod/rod-7", True)]
        pub.close()
        deadline = time.monotonic() + 5
        while len(seen) < 4 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert sorted(seen[2:]) == [("rig/ball/ball-3", False), ("rig/rod/rod-7", False)]
        sub.undeclare()


def test_device_token_of_keys() -> None:
    assert device_token("rig/rod/rod-1/imu") == "rig/rod/rod-1"
    assert device_token("rig/rod/rod-1/reel/cmd") == "rig/rod/rod-1"
    assert device_token("gw/rod/rod-1/attitude") is None
    assert device_token("rig/rod") is None
