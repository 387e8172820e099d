"""`python -m gateway --with-devices` (the README's run command) stopped with SIGTERM, as a service manager or
`kill` stops it, must take its simulated devices down with it instead of leaving them publishing."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except (ProcessLookupError, FileNotFoundError):
        return False


@pytest.mark.timeout(240)
def test_sigterm_stops_gateway_and_its_devices(tmp_path: Path) -> None:
    http, zport = _free_port(), _free_port()
    gw = subprocess.Popen(
        [sys.executable, "-m", "gateway", "--with-devices", "--port", str(http), "--listen", f"tcp/127.0.0.1:{zport}",
         "--data-dir", str(tmp_path), "--devices-args", "--only rod --only ball"],
        stderr=subprocess.PIPE, text=True,
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(gw.stderr.readline, "")), daemon=True)  # type: ignore[union-attr]
    reader.start()
    try:
        online, deadline = 0, time.monotonic() + 180  # the first start may compile the fusion kernels
        while time.monotonic() < deadline and online < 2:
            time.sleep(1.0)
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{http}/api/health", timeout=2) as r:
                    online = json.load(r)["devices_online"]
            except OSError:
                continue
        assert online == 2, f"devices did not come online; stderr:\n{''.join(lines)[-2000:]}"
        pids = [int(p) for line in lines if "started" in line for p in re.findall(r"pid (\d+)", line)]
        launcher = [int(p) for p in re.findall(r"^(\d+)", subprocess.run(
            ["pgrep", "-P", str(gw.pid)], capture_output=True, text=True).stdout, re.M)]
        assert len(pids) == 2 and launcher, f"could not find the device processes in: {lines}"
        gw.send_signal(signal.SIGTERM)
        gw.wait(timeout=30)
        deadline = time.monotonic() + 20
        everyone = pids + launcher
        while time.monotonic() < deadline and any(_alive(p) for p in everyone):
            time.sleep(0.2)
        assert not [p for p in everyone if _alive(p)], "device processes outlived the gateway"
    finally:
        if gw.poll() is None:
            gw.kill()
