"""Bite-alarm latency end to end over zenoh: simulated rod process -> gateway process -> alarm on `gw/rod/*/alarm`.

The rod (devices.sim_rod) runs a script of bites with distractors (rod handling: roll/yaw; wind; waves) between
them and publishes ground truth. An observer session here records truth and alarms with its own wall clock;
all three processes share the machine's clock. Printed per bite:

- from fish pull onset: truth `bite/start` event (device wall clock) -> alarm received here;
- from true θ1 crossing: first truth sample whose pitch is θ1 below the true rest pitch -> alarm received here.

p50 / p99 / max over all bites, plus misses (a bite without a bite alarm) and false alarms (any alarm outside
a bite window). Target: p99 <= 100 ms from the θ1 crossing.

    python -m bench.bite_latency --bites 12
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from tqdm import tqdm

from gateway import schemas
from gateway.config import RodThresholds
from gateway.fusion.quaternion import to_euler

REPO = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_gateway(
    data_dir: Path, zenoh_port: int, http_port: int, log_path: Path | None = None
) -> subprocess.Popen[bytes]:
    """`python -m gateway` listening on tcp/127.0.0.1:zenoh_port, REST on http_port."""
    out = open(log_path, "wb") if log_path else subprocess.DEVNULL  # noqa: SIM115
    return subprocess.Popen(
        [sys.executable, "-m", "gateway", "--data-dir", str(data_dir), "--port", str(http_port),
         "--listen", f"tcp/127.0.0.1:{zenoh_port}", "--log-level", "WARNING"],
        cwd=REPO, stdout=out, stderr=subprocess.STDOUT, env=os.environ | {"PYTHONUNBUFFERED": "1"},
    )  # fmt: skip


def stop_gateway(gw: subprocess.Popen[bytes]) -> None:
    """SIGTERM (graceful: the gateway closes its zenoh session and stops its devices), SIGKILL after 15 s."""
    gw.terminate()
    try:
        gw.wait(timeout=15)
    except subprocess.TimeoutExpired:
        gw.kill()


def wait_http(port: int, timeout_s: float = 180.0) -> None:
    """Wait until the gateway's /api/health answers."""
    import httpx

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=1.0).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise TimeoutError(f"gateway on port {port} did not answer within {timeout_s} s")


def _stats(http_port: int) -> dict[str, Any]:
    import httpx

    try:
        stats: dict[str, Any] = httpx.get(f"http://127.0.0.1:{http_port}/api/stats", timeout=5.0).json()
        return stats
    except httpx.HTTPError:
        return {}


def observer_config(zenoh_port: int) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zenoh_port}"]))
    return conf


@dataclass
class Recorder:
    """Everything the observer saw: (receipt wall s, key, payload)."""

    samples: list[tuple[float, str, bytes]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    gateway_stats: dict[str, Any] = field(default_factory=dict)

    def __call__(self, sample: zenoh.Sample) -> None:
        t = time.time()
        item = (t, str(sample.key_expr), sample.payload.to_bytes())
        with self.lock:
            self.samples.append(item)

    def decoded(self, suffix: str) -> list[tuple[float, Any]]:
        with self.lock:
            items = list(self.samples)
        out = []
        for t, k, p in items:
            if k.endswith(suffix):
                out.append((t, schemas.decode(k, p) if k.startswith("rig/") else json.loads(p)))
        return out


def run_rod(zenoh_port: int, script: Sequence[dict[str, Any]], duration_s: float, seed: int,
            extra: Sequence[str] = ()) -> subprocess.CompletedProcess[bytes]:  # fmt: skip
    """Run one simulated rod process to completion."""
    cmd = [sys.executable, "-m", "devices.sim_rod", "--connect", f"tcp/127.0.0.1:{zenoh_port}", "--seed", str(seed),
           "--duration", str(duration_s), "--no-progress", "--script", json.dumps(list(script)), *extra]  # fmt: skip
    return subprocess.run(cmd, cwd=REPO, capture_output=True, timeout=duration_s + 60)


def bite_script(
    n_bites: int, spacing_s: float = 12.0, first_s: float = 6.0, depth_deg: float = 15.0
) -> list[dict[str, Any]]:
    """Bites every `spacing_s`, with a distractor (handling, wind, waves in turn) between each pair."""
    script: list[dict[str, Any]] = []
    distractors = [
        {"type": "handling", "duration_s": 3.0, "roll_deg": 25.0, "yaw_deg": 20.0},
        {"type": "wind", "duration_s": 4.0, "strength": 1.0},
        {"type": "waves", "duration_s": 5.0},
    ]
    for i in range(n_bites):
        t = first_s + i * spacing_s
        script.append({"type": "bite", "t_s": t, "depth_deg": depth_deg, "duration_s": 1.5})
        script.append(distractors[i % len(distractors)] | {"t_s": t + 4.0})
    return script


@dataclass
class Window:
    label: str
    start_wall_s: float
    end_wall_s: float
    cross_wall_s: float | None = None


def truth_windows(truths: list[schemas.RodTruth], theta1_rad: float) -> list[Window]:
    """Labelled event windows in wall time; bites get the time the true pitch first fell θ1 below rest."""
    truths = sorted(truths, key=lambda p: p.t0_us)
    open_: dict[str, Window] = {}
    windows: list[Window] = []
    for p in truths:
        off_s = ((p.wall_t0_us or 0) - p.t0_us) * 1e-6
        for e in p.events:
            t = e.t_us * 1e-6 + off_s
            if e.phase == "start":
                open_[e.label] = Window(e.label, t, math.inf)
                windows.append(open_[e.label])
            elif e.phase == "end" and e.label in open_:
                open_.pop(e.label).end_wall_s = t
        w = open_.get("bite") or (windows[-1] if windows and windows[-1].label == "bite" else None)
        if w is not None and w.cross_wall_s is None:
            pitch = to_euler(np.array(p.quat_wxyz))[:, 1]
            t_s = p.t0_us * 1e-6 + off_s + np.arange(len(pitch)) / p.rate_hz
            hit = np.nonzero((pitch - p.rest_pitch_rad <= -theta1_rad) & (t_s >= w.start_wall_s))[0]
            if hit.size:
                w.cross_wall_s = float(t_s[hit[0]])
    return windows


@dataclass
class BiteReport:
    bites: int
    onset_ms: list[float]
    cross_ms: list[float]
    missed: int
    false_alarms: list[dict[str, Any]]
    pipeline_ms: list[float] = field(default_factory=list)  # triggering sample (device wall) -> alarm received
    cues: list[str] = field(default_factory=list)


def analyse(rec: Recorder, theta1_rad: float, grace_s: float = 1.0) -> BiteReport:
    """Match bite alarms to truth bite windows; any raised alarm outside a bite window is a false alarm."""
    truths = [p for _, p in rec.decoded("/truth") if isinstance(p, schemas.RodTruth)]
    windows = truth_windows(truths, theta1_rad)
    bites = [w for w in windows if w.label == "bite"]
    # presence alarms are not judged here: the rod process ending raises device_offline by design
    alarms = [(t, a) for t, a in rec.decoded("/alarm") if a["state"] == "raised" and a["alarm"] != "device_offline"]
    onset, cross, missed, used = [], [], 0, set()
    pipe: list[float] = []
    cues: list[str] = []
    for w in bites:
        hits = [(t, i) for i, (t, a) in enumerate(alarms) if a["alarm"] == "bite" and w.start_wall_s - 0.2 <= t
                <= min(w.end_wall_s, w.start_wall_s + 10) + grace_s]  # fmt: skip
        if not hits:
            missed += 1
            continue
        t, i = hits[0]
        used.add(i)
        onset.append(1e3 * (t - w.start_wall_s))
        a = alarms[i][1]
        if a.get("source_wall_us") is not None:
            pipe.append(1e3 * t - a["source_wall_us"] * 1e-3)
        cues.append("accel" if "by accel" in a["message"] else "pitch")
        if w.cross_wall_s is not None:
            cross.append(1e3 * (t - w.cross_wall_s))
    false = []
    for i, (t, a) in enumerate(alarms):
        in_bite = any(w.start_wall_s - 0.2 <= t <= min(w.end_wall_s, w.start_wall_s + 10) + grace_s for w in bites)
        if i not in used and not in_bite:
            false.append(a)
    return BiteReport(len(bites), onset, cross, missed, false, pipe, cues)


def run_session(script: list[dict[str, Any]], duration_s: float, seed: int, work: Path,
                rod_args: Sequence[str] = ()) -> tuple[Recorder, subprocess.CompletedProcess[bytes]]:  # fmt: skip
    """Gateway + rod processes with an observer; returns what the observer recorded."""
    zport, hport = free_port(), free_port()
    gw = start_gateway(work / "data", zport, hport, work / "gateway.log")
    rec = Recorder()
    try:
        wait_http(hport)
        with zenoh.open(observer_config(zport)) as session:
            subs = [session.declare_subscriber(sel, rec) for sel in ("gw/rod/*/alarm", "rig/rod/*/truth")]
            time.sleep(0.5)
            rod = run_rod(zport, script, duration_s, seed, rod_args)
            time.sleep(1.0)
            rec.gateway_stats = _stats(hport)
            for s in subs:
                s.undeclare()  # type: ignore[no-untyped-call]
    finally:
        stop_gateway(gw)
    return rec, rod


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(xs, q)) if xs else math.nan


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.bite_latency", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--bites", type=int, default=12, help="bites per session (default: 12)")
    p.add_argument("--sessions", type=int, default=1, help="sessions (fresh processes each), default 1")
    p.add_argument("--spacing", type=float, default=12.0, help="seconds between bites (default: 12)")
    p.add_argument("--depth-deg", type=float, default=15.0, help="bite depth, degrees (default: 15)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    theta1 = math.radians(RodThresholds().effective_bite_deg)
    onset: list[float] = []
    cross: list[float] = []
    missed = bites = 0
    false: list[dict[str, Any]] = []
    pipe: list[float] = []
    cues: list[str] = []
    for k in tqdm(range(args.sessions), desc="sessions", unit="session"):
        script = bite_script(args.bites, args.spacing, depth_deg=args.depth_deg)
        duration = 6.0 + args.bites * args.spacing + 2.0
        with tempfile.TemporaryDirectory() as tmp:
            rec, _ = run_session(script, duration, args.seed + k, Path(tmp))
        r = analyse(rec, theta1)
        d = rec.gateway_stats.get("batch_delay_ms")
        if d:
            print(f"gateway batch delay (packet arrival -> results to zenoh): p50 {d['p50']:.2f} ms, "
                  f"p99 {d['p99']:.2f} ms, max {d['max']:.2f} ms over {d['n']} batches")
        onset += r.onset_ms
        cross += r.cross_ms
        missed += r.missed
        bites += r.bites
        false += r.false_alarms
        pipe += r.pipeline_ms
        cues += r.cues
    print(f"bites {bites}, alarmed {bites - missed}, missed {missed}, false alarms {len(false)}")
    rows = (("from fish pull onset", onset), ("from true theta1 crossing", cross),
            ("triggering sample -> alarm received (packetising + transport + gateway)", pipe))  # fmt: skip
    for name, xs in rows:
        worst = max(xs, default=math.nan)
        print(f"latency {name}: p50 {pct(xs, 50):.1f} ms, p99 {pct(xs, 99):.1f} ms, max {worst:.1f} ms (n={len(xs)})")
    print(f"detections by cue: pitch {cues.count('pitch')}, accel {cues.count('accel')}")
    for a in false[:10]:
        print("false alarm:", a["alarm"], a["message"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
