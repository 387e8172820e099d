"""Stopping the device launcher must stop its children: the gateway (`--with-devices`) and service managers send
SIGTERM, and a launcher killed by it would leave the simulators publishing forever."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time

import pytest


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its dead parent's adopter) counts as gone
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split(")")[-1].split()[0] != "Z"


@pytest.mark.timeout(120)
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_stopping_the_launcher_stops_every_device(sig: signal.Signals) -> None:
    # Started with SIGINT ignored, as a background job of a non-interactive shell is: the devices must still stop.
    endpoint = f"tcp/127.0.0.1:{_free_port()}"  # nobody listens: devices keep retrying, as without a gateway
    launcher = subprocess.Popen(
        [sys.executable, "-m", "devices", "--connect", endpoint, "--only", "rod", "--only", "ball"],
        stderr=subprocess.PIPE, text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    try:
        assert launcher.stderr is not None
        pids: list[int] = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not pids:
            line = launcher.stderr.readline()
            if "started" in line:
                pids = [int(p) for p in re.findall(r"pid (\d+)", line)]
        assert len(pids) == 2, "the launcher did not report its two children"
        time.sleep(2.0)  # let the children open their sessions and start publishing
        assert all(_alive(p) for p in pids)
        launcher.send_signal(sig)
        launcher.wait(timeout=20)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(_alive(p) for p in pids):
            time.sleep(0.2)
        assert not [p for p in pids if _alive(p)], "devices kept running after their launcher was stopped"
    finally:
        if launcher.poll() is None:
            launcher.kill()
