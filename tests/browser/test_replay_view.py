"""Replay view in headless Chromium: open a small recording, scrub with the time input, see the pose readout follow."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import urlparse

import pytest

from bench.bite_latency import stop_process
from gateway.recording.format import Record, write_recording
from tests.browser.conftest import CHROMIUM_ARGS, OUT, REPO, free_port
from tests.gateway.conftest import rod_messages

pytestmark = pytest.mark.browser


def test_replay_view_scrubs_a_recording(chromium_path: Path, tmp_path: Path) -> None:
    from playwright.sync_api import sync_playwright

    rec = tmp_path / "rod.rigrec"
    msgs = rod_messages(3.0)
    write_recording(rec, [Record(k, p, i * 1000) for i, (k, p) in enumerate(msgs)], {"source": "browser test"})
    port = free_port()
    log = open(tmp_path / "replay.log", "wb")  # noqa: SIM115 - closed below
    cmd = [sys.executable, "-m", "gateway.replay_view", str(rec), "--filter", "mahony", "--mode", "6D"]
    cmd += ["--port", str(port)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 90
        while b"replay view on" not in (tmp_path / "replay.log").read_bytes():
            assert proc.poll() is None, (tmp_path / "replay.log").read_text()
            assert time.monotonic() < deadline, "replay view did not start"
            time.sleep(0.2)
        with sync_playwright() as pw:
            b = pw.chromium.launch(executable_path=str(chromium_path), args=CHROMIUM_ARGS)
            page = b.new_page(viewport={"width": 1400, "height": 1000})
            requests: list[str] = []
            console: list[str] = []
            page.on("request", lambda r: requests.append(r.url))
            page.on("console", lambda m: console.append(f"{m.type}: {m.text}"))
            page.goto(f"http://127.0.0.1:{port}/")
            page.get_by_text("t = 0.00 s").first.wait_for(timeout=30_000)
            # the slider's number box: type a time, the pose readout follows (2.5 s into the 3 s recording)
            box = page.locator("input.mantine-NumberInput-input").first
            box.fill("2.5")
            page.keyboard.press("Enter")
            page.get_by_text("t = 2.50 s").first.wait_for(timeout=15_000)
            time.sleep(2.0)
            page.screenshot(path=str(OUT / "replay_view.png"), timeout=90_000)  # software WebGL can be slow
            assert not [c for c in console if c.startswith("error")], console
            hosts = {urlparse(u).hostname for u in requests if not u.startswith(("blob:", "data:"))}
            assert hosts == {"127.0.0.1"}, requests
            b.close()
    finally:
        stop_process(proc, 10.0)
        log.close()
