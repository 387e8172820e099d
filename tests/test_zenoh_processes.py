"""Two processes over a real zenoh session on loopback: a simulated rod fleet and this test as the 'gateway'.

Multicast is off and endpoints are explicit: the test listens on a free port, the device connects to it.
"""

from __future__ import annotations

import json
import os
import queue
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
import zenoh

from devices.common import zenoh_config
from gateway import schemas
from gateway.ingest.sequence import SequenceTracker

REPO = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_rod(endpoint: str, *args: str) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "devices.sim_rod", "--connect", endpoint, "--count", "2", "--seed", "3",
           "--no-progress", *args]
    return subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def wait_for_line(proc: subprocess.Popen[bytes], text: str, timeout_s: float = 30.0) -> list[str]:
    """Read the child's stderr until a line contains `text`; returns the lines read."""
    lines: list[str] = []
    deadline = time.monotonic() + timeout_s
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline().decode()
        if not line:
            break
        lines.append(line)
        if text in line:
            return lines
    raise AssertionError(f"child never printed {text!r}: {''.join(lines)[-2000:]}")


@pytest.mark.timeout(60)
def test_rod_process_publishes_data_truth_and_liveliness_and_obeys_a_reel_command() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    inbox: queue.SimpleQueue[tuple[str, bytes, str]] = queue.SimpleQueue()
    presence: queue.SimpleQueue[tuple[str, str]] = queue.SimpleQueue()
    with zenoh.open(zenoh_config("peer", connect=(), listen=(endpoint,))) as session:
        session.declare_subscriber("rig/**", lambda s: inbox.put(
            (str(s.key_expr), s.payload.to_bytes(), str(s.encoding))))
        session.liveliness().declare_subscriber(
            "rig/*/*", lambda s: presence.put((str(s.key_expr), "PUT" if s.kind == zenoh.SampleKind.PUT else "DELETE")),
            history=True)
        proc = start_rod(endpoint, "--duration", "6")
        try:
            packets: list[schemas.Packet] = []
            encodings: dict[str, str] = {}
            alive: set[str] = set()
            sent_cmd = False
            deadline = time.monotonic() + 30
            acked: schemas.ReelStatus | None = None
            while time.monotonic() < deadline and acked is None:
                try:
                    key, payload, enc = inbox.get(timeout=0.5)
                except queue.Empty:
                    continue
                while not presence.empty():
                    k, kind = presence.get()
                    if kind == "PUT":
                        alive.add(k)
                if key.endswith("/cmd"):
                    continue  # our own command
                p = schemas.decode(key, payload)
                packets.append(p)
                encodings[key.rsplit("/", 1)[1]] = enc
                kinds = Counter(type(x).__name__ for x in packets)
                if not sent_cmd and kinds["ImuPacket"] >= 20:
                    cmd = schemas.ReelCommand(v=1, cmd_id=77, action="in", speed_m_s=0.4,
                                              sent_wall_us=time.time_ns() // 1000, sender="test")
                    session.put(schemas.reel_cmd_key("rod-2"), cmd.to_json(),
                                encoding=zenoh.Encoding(schemas.ENCODING_REEL_CMD),
                                congestion_control=zenoh.CongestionControl.BLOCK)
                    sent_cmd = True
                if (isinstance(p, schemas.ReelStatus) and p.device_id == "rod-2" and p.last_cmd_id == 77
                        and p.motor == "reeling_in"):
                    acked = p
        finally:
            out, err = proc.communicate(timeout=20)
        gone: set[str] = set()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and len(gone) < 2:
            try:
                k, kind = presence.get(timeout=0.5)
            except queue.Empty:
                continue
            (alive if kind == "PUT" else gone).add(k)
    assert proc.returncode == 0, err.decode()[-2000:]
    assert alive == {"rig/rod/rod-1", "rig/rod/rod-2"}
    assert gone == alive  # tokens vanish when the device process exits
    assert acked is not None, f"no acknowledgement; got {Counter(type(x).__name__ for x in packets)}"
    assert acked.mode == "in" and acked.cmd_speed_m_s == pytest.approx(0.4)
    imus = [p for p in packets if isinstance(p, schemas.ImuPacket)]
    truths = [p for p in packets if isinstance(p, schemas.RodTruth)]
    assert {p.device_id for p in imus} == {"rod-1", "rod-2"} and truths
    assert encodings["imu"] == schemas.ENCODING_IMU and encodings["truth"] == schemas.ENCODING_TRUTH
    for dev in ("rod-1", "rod-2"):
        tracker = SequenceTracker()
        for p in imus:
            if p.device_id == dev:
                tracker.update(p.boot_id, p.seq)
        assert tracker.ok >= 8 and tracker.duplicates == 0 and tracker.reordered == 0
        assert tracker.lost <= 2  # loopback, DROP congestion control: essentially no loss
    assert "ticks" in err.decode()  # the device logged its counters on a clean exit


@pytest.mark.timeout(60)
def test_device_keeps_publishing_until_the_gateway_appears() -> None:
    """Start the device first; the 'gateway' session opens 2 s later and still receives data."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = start_rod(endpoint, "--duration", "8", "--no-truth", "--loss", "0.2")
    try:
        wait_for_line(proc, "publishing")
        time.sleep(2.0)
        got: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        with zenoh.open(zenoh_config("peer", connect=(), listen=(endpoint,))) as session:
            session.declare_subscriber(schemas.SEL_IMU, lambda s: got.put(s.payload.to_bytes()))
            deadline = time.monotonic() + 10
            packets = []
            while time.monotonic() < deadline and len(packets) < 40:
                try:
                    packets.append(schemas.decode("rig/rod/rod-1/imu", got.get(timeout=0.5)))
                except (queue.Empty, schemas.DecodeError):
                    continue
    finally:
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err.decode()[-2000:]
    assert len(packets) >= 40
    seqs = [p.seq for p in packets]  # type: ignore[union-attr]
    assert min(seqs) > 20  # the first 2 s (40 packets) went out before anyone listened
    tracker = SequenceTracker()
    for s in seqs:
        tracker.update(1, s)
    assert tracker.lost > 0  # --loss 0.2 shows up as sequence gaps
    summary = json.dumps({"lost": tracker.lost, "ok": tracker.ok})
    assert 0.05 < tracker.lost / (tracker.lost + tracker.ok) < 0.4, summary
