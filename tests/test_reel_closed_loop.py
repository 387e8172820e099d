"""Reel control closed over real zenoh on loopback: a simulated rod PROCESS (`python -m devices.sim_rod`) with a
scripted bite and then a fish fight -> the gateway PROCESS (`python -m gateway`) -> bite alarm -> auto mode via
REST (bearer token), with the default rod thresholds (they fit the sim rod) -> fish-walking ReelCommands on
`rig/rod/{id}/reel/cmd` -> the sim reel obeys (its status echoes `last_cmd_id` and the commanded motion) and the
line holds; a manual REST command then stops auto mode. Multicast off, explicit endpoints, free ports."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
import zenoh

from bench.bite_latency import REPO, Recorder, free_port, observer_config, start_gateway, stop_process, wait_http
from gateway import schemas

pytestmark = pytest.mark.timeout(240)

ROD = "rod-1"
BREAKING_N = 40.0  # devices.sim_rod default line
SCRIPT = [
    {"type": "bite", "t_s": 6.0, "depth_deg": 20.0, "duration_s": 2.0},
    {"type": "fight", "t_s": 9.0, "mass_kg": 3.0, "stamina": 0.6},
]


def _wait(cond: Callable[[], Any], timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = cond()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def test_auto_reel_drives_the_sim_reel_and_manual_takes_over(tmp_path: Path) -> None:
    zport, hport = free_port(), free_port()
    gw = start_gateway(tmp_path / "data", zport, hport, tmp_path / "gateway.log")
    rod: subprocess.Popen[bytes] | None = None
    rec = Recorder()
    try:
        wait_http(hport)
        api = httpx.Client(base_url=f"http://127.0.0.1:{hport}/api", timeout=10.0, headers={
            "Authorization": f"Bearer {(tmp_path / 'data' / 'api_token').read_text().strip()}"})
        # No threshold set: the defaults are the sim rod's (40 N line), and the controller sets the drag to 60 % of it.
        assert api.get("/thresholds/rod").json()["line_breaking_n"] == BREAKING_N
        with zenoh.open(observer_config(zport)) as session:
            subs = [session.declare_subscriber(sel, rec) for sel in (
                "gw/rod/*/alarm", "rig/rod/*/reel", "rig/rod/*/reel/cmd", "rig/rod/*/truth")]
            time.sleep(0.5)
            rod = subprocess.Popen(
                [sys.executable, "-m", "devices.sim_rod", "--connect", f"tcp/127.0.0.1:{zport}", "--seed", "5",
                 "--duration", "40", "--no-progress", "--script", json.dumps(SCRIPT)],
                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip

            def bite() -> bool:
                return any(a["alarm"] == "bite" and a["state"] == "raised" for _, a in rec.decoded("/alarm"))

            _wait(bite, 30.0, "the bite alarm")
            r = api.post(f"/rods/{ROD}/reel", json={"action": "auto"})
            assert r.status_code == 200 and r.json()["auto"] is True and r.json()["controller_available"], r.text

            def auto_cmds() -> list[schemas.ReelCommand]:
                return [c for _, c in rec.decoded("/reel/cmd") if c.sender == "auto"]

            def obeyed() -> list[schemas.ReelStatus]:
                ids = {c.cmd_id: c for c in auto_cmds() if c.action == "speed"}
                return [s for _, s in rec.decoded(f"{ROD}/reel") if s.last_cmd_id in ids and s.mode == "speed"
                        and s.cmd_speed_m_s == pytest.approx(ids[s.last_cmd_id].speed_m_s)]

            # The fight starts at 9 s; give the controller 12 s of it, then check what reached the reel.
            _wait(lambda: len(obeyed()) >= 5, 25.0, "the sim reel acknowledging auto speed commands")
            time.sleep(8.0)
            cmds = auto_cmds()
            assert all(c.drag_n == pytest.approx(0.6 * BREAKING_N) for c in cmds if c.action == "speed"), cmds[:3]
            statuses = [s for _, s in rec.decoded(f"{ROD}/reel")]
            assert any(s.drag_n == pytest.approx(0.6 * BREAKING_N) for s in statuses), "the drag request arrived"
            assert any(s.motor == "reeling_in" for s in obeyed()), "the reel moved as commanded"

            # Manual takeover: stop via REST ends auto mode; no further auto commands, the reel stops.
            r = api.post(f"/rods/{ROD}/reel", json={"action": "stop"})
            assert r.status_code == 200 and r.json()["auto"] is False, r.text
            stop_id = r.json()["command"]["cmd_id"]
            n_auto = len(auto_cmds())
            _wait(lambda: any(s.last_cmd_id == stop_id and s.mode == "stop"
                              for _, s in rec.decoded(f"{ROD}/reel")), 5.0, "the reel acknowledging the stop")
            time.sleep(2.0)
            assert len(auto_cmds()) == n_auto, "auto mode kept commanding after manual takeover"
            last = rec.decoded(f"{ROD}/reel")[-1][1]
            assert last.mode == "stop" and last.last_cmd_id == stop_id

            truths = [t for _, t in rec.decoded(f"{ROD}/truth")]
            assert truths, "no truth stream"
            labels = {e.label for t in truths for e in t.events}
            assert "line_break" not in labels
            assert all(t.fish_state != "escaped" for t in truths)
            assert any(t.fish_state in ("hooked", "fighting", "tired", "landed") for t in truths), "a fish was on"
            for s in subs:
                s.undeclare()  # type: ignore[no-untyped-call]
    finally:
        if rod is not None:
            stop_process(rod, 10.0)
        stop_process(gw)
