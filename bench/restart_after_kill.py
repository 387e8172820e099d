"""Gateway restart after SIGKILL (issue 13): how long until REST answers and the devices are seen again.

Starts `python -m gateway` and `python -m devices` (connected to it), waits until every device is online, then
SIGKILLs the gateway mid-stream and starts it again on the same data dir and ports (warm kernel cache: numba's
cache and the OS page cache are both warm from the first start). Printed per round: seconds from the restart to
the first `/api/health` answer and to every device online with fresh packets; plus the database check.

    python -m bench.restart_after_kill --rounds 3
"""

from __future__ import annotations

import argparse
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

from bench.bite_latency import REPO, free_port, start_gateway, stop_process


def _get(port: int, path: str) -> object:
    try:
        r = httpx.get(f"http://127.0.0.1:{port}{path}", timeout=0.5)
        return r.json() if r.status_code == 200 else None
    except httpx.HTTPError:
        return None


def _devices_live(port: int, n: int, fresh: bool = True) -> bool:
    """`n` devices online (liveliness), and with `fresh` also with a packet processed in the last 0.5 s."""
    devs = _get(port, "/api/devices")
    if not isinstance(devs, list):
        return False
    live = [d for d in devs if d["online"] and (not fresh or (d["last_packet_age_s"] is not None
                                                              and d["last_packet_age_s"] < 0.5))]  # fmt: skip
    return len(live) >= n


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _until(cond: object, timeout_s: float) -> float:
    t0 = time.monotonic()
    while not cond():  # type: ignore[operator]
        if time.monotonic() - t0 > timeout_s:
            raise TimeoutError(f"not within {timeout_s} s")
        time.sleep(0.05)
    return time.monotonic() - t0


def restart_round(data: Path, zport: int, hport: int, n_devices: int, log: Path) -> tuple[float, float, float, float]:
    """Start, measure, SIGKILL mid-stream: (s to REST, CPU s used by then, s to devices online, s to fresh data)."""
    gw = start_gateway(data, zport, hport, log)
    t0 = time.monotonic()
    try:
        _until(lambda: _get(hport, "/api/health") is not None, 300.0)
        t_http, cpu = time.monotonic() - t0, _cpu_s(gw.pid)
        _until(lambda: _devices_live(hport, n_devices, fresh=False), 120.0)
        t_online = time.monotonic() - t0
        _until(lambda: _devices_live(hport, n_devices), 120.0)
        t_dev = time.monotonic() - t0
        time.sleep(1.0)  # mid-stream
        gw.send_signal(signal.SIGKILL)
        gw.wait()
    except BaseException:
        stop_process(gw)
        raise
    return t_http, cpu, t_online, t_dev


def main(rounds: int, devices: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        data, zport, hport = Path(tmp) / "data", free_port(), free_port()
        dev = subprocess.Popen(
            [sys.executable, "-m", "devices", "--connect", f"tcp/127.0.0.1:{zport}", "--only", "rod",
             "--rod-args", f"--count {devices} --no-progress"],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, env=os.environ | {"PYTHONUNBUFFERED": "1"},
        )  # fmt: skip
        try:
            print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
            first = restart_round(data, zport, hport, devices, Path(tmp) / "gw0.log")
            print(f"first start: REST after {first[0]:.2f} s ({first[1]:.2f} s CPU), {devices} devices online after "
                  f"{first[2]:.2f} s, their data flowing after {first[3]:.2f} s")  # fmt: skip
            rows = []
            for i in range(rounds):
                rows.append(restart_round(data, zport, hport, devices, Path(tmp) / f"gw{i + 1}.log"))
                t_http, cpu, t_online, t_dev = rows[-1]
                print(f"after SIGKILL {i + 1}: REST after {t_http:.2f} s ({cpu:.2f} s CPU), devices online after "
                      f"{t_online:.2f} s, data flowing after {t_dev:.2f} s")  # fmt: skip
            worst = [max(r[k] for r in rows) for k in range(4)]
            print(f"worst of {rounds} restarts: REST {worst[0]:.2f} s ({worst[1]:.2f} s CPU), online {worst[2]:.2f} s, "
                  f"data {worst[3]:.2f} s (target 5 s); load average now {os.getloadavg()[0]:.1f}")  # fmt: skip
            with sqlite3.connect(data / "gateway.sqlite3") as db:
                print("database integrity:", db.execute("PRAGMA integrity_check").fetchone()[0])
        finally:
            dev.terminate()
            try:
                dev.wait(timeout=15)
            except subprocess.TimeoutExpired:
                dev.kill()


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--devices", type=int, default=2)
    a = ap.parse_args()
    main(a.rounds, a.devices)
