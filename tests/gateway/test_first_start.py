"""`python -m gateway` as a user starts it: the HTTP server answers before or while the gateway warms up, every
URL is printed when it is ready, and the 3-D view runs with the gateway (not only after the dashboard link)."""

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

from bench.bite_latency import stop_process

REPO = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.timeout(240)
def test_first_start_prints_every_url_and_starts_the_3d_view(tmp_path: Path) -> None:
    http, zport, vport = _free_port(), _free_port(), _free_port()
    env = {**os.environ, "RIG_VISER_PORT": str(vport), "PYTHONUNBUFFERED": "1"}
    t0 = time.monotonic()
    gw = subprocess.Popen(
        [sys.executable, "-m", "gateway", "--port", str(http), "--listen", f"tcp/127.0.0.1:{zport}",
         "--data-dir", str(tmp_path), "--log-level", "WARNING"],  # the URLs show at any log level
        cwd=REPO, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(gw.stderr.readline, "")), daemon=True)  # type: ignore[union-attr]
    reader.start()
    try:
        served_s = ready_s = None
        deadline = t0 + 180  # generous: the kernels may still need compiling on a fresh checkout
        while ready_s is None and time.monotonic() < deadline:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{http}/api/health", timeout=2) as r:
                    served_s = served_s or time.monotonic() - t0
                    if json.load(r)["ready"]:
                        ready_s = time.monotonic() - t0
            except OSError:
                assert gw.poll() is None, "".join(lines)
            time.sleep(0.1)
        assert ready_s is not None, "".join(lines)[-2000:]
        assert served_s is not None and served_s <= ready_s
        time.sleep(0.3)  # the ready lines follow the flag within a few ms
        text = "".join(lines)
        base = f"http://127.0.0.1:{http}"
        for url in (f"{base}/", f"{base}/docs", f"{base}/redoc", f"{base}/metrics"):
            assert url in text, text
        [v3d] = re.findall(r"3D view\s+(http://127\.0\.0\.1:\d+/)", text)
        with urllib.request.urlopen(v3d, timeout=5) as r:  # viser is up without anyone opening /view3d
            assert r.status == 200
        with urllib.request.urlopen(f"{base}/api/view3d", timeout=5) as r:
            assert json.load(r)["running"] is True
        print(f"served after {served_s:.1f} s, ready after {ready_s:.1f} s")
    finally:
        stop_process(gw, 30.0, signal.SIGINT)
