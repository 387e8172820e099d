"""Bite-alarm figures end to end over zenoh: simulated rod process -> gateway process -> alarm on `gw/rod/*/alarm`.

Default (issue 10): the rod scenario suite through zenoh. One `devices.sim_rod --scenario SEED --count N` process
plays N recordings of `devices.rod_scenarios` at once in real time (5 samples per packet); an observer session
records the alarms and the truth packets. Printed: the same table as `python -m bench.bite_suite` (scored in
device time: the alarm's sample against the true theta1 crossing), a check that the alarms equal those of the
offline pipeline on the same recordings, and the wall-clock latency from the true crossing to the alarm's
arrival at the observer (adds packetising, transport and the gateway's batching).

    python -m bench.bite_latency                          # seeds 1000-1023: 24 rods x 5 min = 2 rod-hours
    python -m bench.bite_latency --rods 4 --minutes 2     # quicker

`--scripted`: the older run of one physics rod (devices.rod_physics) with a script of bites and distractors
(handling, wind, waves), scored on its truth windows.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import signal
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
         "--listen", f"tcp/127.0.0.1:{zenoh_port}", "--log-level", "WARNING",
         "--shards", "1"],  # one process: these benches read one gateway's /api/stats
        cwd=REPO, stdout=out, stderr=subprocess.STDOUT, env=os.environ | {"PYTHONUNBUFFERED": "1"},
    )  # fmt: skip


def stop_process(p: subprocess.Popen[bytes], timeout_s: float = 15.0, sig: int = signal.SIGTERM) -> None:
    """`sig` (SIGTERM: the gateway closes its zenoh session and stops its devices), SIGKILL after `timeout_s`;
    returns once the process is gone. Nothing to do for one that has ended."""
    if p.poll() is not None:
        return
    p.send_signal(sig)
    try:
        p.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


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


def wait_caught_up(http_port: int, still_s: float = 0.5, timeout_s: float = 30.0) -> None:
    """Return once the gateway's `received` count has not moved for `still_s` (a gateway that ran behind on a loaded
    machine has taken in the last packets), at most `timeout_s`."""
    deadline, last, since = time.monotonic() + timeout_s, None, time.monotonic()
    while time.monotonic() < deadline:
        n = _stats(http_port).get("received")
        if n != last:
            last, since = n, time.monotonic()
        elif time.monotonic() - since >= still_s:
            return
        time.sleep(0.1)


def _stats(http_port: int, timeout_s: float = 5.0) -> dict[str, Any]:
    """The gateway's /api/stats, {} if it does not answer within `timeout_s`."""
    import httpx

    try:
        stats: dict[str, Any] = httpx.get(f"http://127.0.0.1:{http_port}/api/stats", timeout=timeout_s).json()
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

    def wait_quiet(self, quiet_s: float = 1.0, timeout_s: float = 30.0) -> None:
        """Return once nothing has arrived for `quiet_s` (the device has stopped and a gateway that ran behind, on a
        loaded machine, has caught up and published the rest), at most `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                last = self.samples[-1][0] if self.samples else 0.0
            if time.time() - last >= quiet_s:
                return
            time.sleep(0.1)

    def decoded(self, suffix: str) -> list[tuple[float, Any]]:
        with self.lock:
            items = list(self.samples)
        out = []
        for t, k, p in items:
            if k.endswith(suffix):
                out.append((t, schemas.decode(k, p) if k.startswith("rig/") else json.loads(p)))
        return out


def run_rod(zenoh_port: int, script: Sequence[dict[str, Any]], duration_s: float, seed: int,
            extra: Sequence[str] = (), start_s: float = 60.0) -> subprocess.CompletedProcess[bytes]:  # fmt: skip
    """Run one simulated rod process to completion (`start_s`: allowance for its start-up)."""
    cmd = [sys.executable, "-m", "devices.sim_rod", "--connect", f"tcp/127.0.0.1:{zenoh_port}", "--seed", str(seed),
           "--duration", str(duration_s), "--no-progress", "--script", json.dumps(list(script)), *extra]  # fmt: skip
    return subprocess.run(cmd, cwd=REPO, capture_output=True, timeout=duration_s + start_s)


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
        cues.append("accel" if "accel cue" in a["message"] else "pitch")
        if w.cross_wall_s is not None:
            cross.append(1e3 * (t - w.cross_wall_s))
    false = []
    for i, (t, a) in enumerate(alarms):
        in_bite = any(w.start_wall_s - 0.2 <= t <= min(w.end_wall_s, w.start_wall_s + 10) + grace_s for w in bites)
        if i not in used and not in_bite:
            false.append(a)
    return BiteReport(len(bites), onset, cross, missed, false, pipe, cues)


def run_session(script: list[dict[str, Any]], duration_s: float, seed: int, work: Path,
                rod_args: Sequence[str] = (), start_s: float = 60.0
                ) -> tuple[Recorder, subprocess.CompletedProcess[bytes]]:  # fmt: skip
    """Gateway + rod processes with an observer; returns what the observer recorded."""
    zport, hport = free_port(), free_port()
    gw = start_gateway(work / "data", zport, hport, work / "gateway.log")
    rec = Recorder()
    try:
        wait_http(hport)
        with zenoh.open(observer_config(zport)) as session:
            subs = [session.declare_subscriber(sel, rec) for sel in ("gw/rod/*/alarm", "rig/rod/*/truth")]
            time.sleep(0.5)
            rod = run_rod(zport, script, duration_s, seed, rod_args, start_s)
            wait_caught_up(hport)
            rec.wait_quiet(0.5)
            rec.gateway_stats = _stats(hport)
            for s in subs:
                s.undeclare()  # type: ignore[no-untyped-call]
    finally:
        stop_process(gw)
    return rec, rod


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(xs, q)) if xs else math.nan


@dataclass
class SuiteReport:
    """The suite through zenoh: device-time score, offline agreement, wall latency from the true crossing."""

    score: Any  # bench.bite_suite.Score
    same_as_offline: int  # rods whose raised alarms equal the offline pipeline's
    rods: int
    wall_ms: list[float]
    differences: list[str]


def analyse_suite(rec: Recorder, first_seed: int, n_rods: int, samples_per_packet: int, offline: bool,
                  played_s: float) -> SuiteReport:  # fmt: skip
    """Score each rod's raised alarms against its recording (device time); compare with the offline pipeline.
    Only the first `played_s` of each recording count (events that end 3 s before, alarms before)."""
    from bench.bite_suite import Score, run_gateway, score
    from devices.rod_scenarios import make_scenario

    truths = [p for _, p in rec.decoded("/truth") if isinstance(p, schemas.RodTruth)]
    alarms = [(t, a) for t, a in rec.decoded("/alarm") if a["state"] == "raised"]
    total, same, wall, diffs = Score(), 0, [], []
    for i in range(n_rods):
        dev, sc = f"rod-{i + 1}", make_scenario(first_seed + i)
        cut_s = min([played_s - 0.5] + [e.t_start_s for e in sc.events if e.t_end_s + 3.0 >= played_s])
        sc = dataclasses.replace(sc, events=tuple(e for e in sc.events if e.t_start_s < cut_s))
        mine = [p for p in truths if p.device_id == dev]
        if not mine:
            diffs.append(f"{dev}: no truth received")
            continue
        p0 = mine[0]
        offset_us = p0.t0_us - int(round(sc.t_s[p0.seq * samples_per_packet] * 1e6))  # device clock at recording 0
        wall_offset_us = (p0.wall_t0_us or 0) - p0.t0_us
        got = [(t, a["alarm"], (a["t_us"] - offset_us) * 1e-6, a["message"])
               for t, a in alarms if a["device_id"] == dev and (a["t_us"] - offset_us) * 1e-6 < cut_s]  # fmt: skip
        bite_s = [t for _, kind, t, _ in got if kind == "bite"]
        drop_s = [t for _, kind, t, _ in got if kind == "drop_back"]
        s = score(sc, bite_s, drop_s)
        total.add(s)
        for e in sc.events:
            if e.family in ("bite", "run"):
                hit = next((rx for rx, kind, t, _ in got if kind == "bite" and e.t_start_s <= t <= e.t_end_s + 1), None)
                if hit is not None:
                    wall.append(1e3 * (hit - (offset_us + wall_offset_us) * 1e-6 - e.cross_s))
        if offline:
            ref = run_gateway(sc)
            mine_msgs = sorted((round(t, 2), kind, m) for _, kind, t, m in got if kind in ("bite", "drop_back"))
            ref_msgs = sorted((round(float(x.split(" s ")[0]), 2), "bite" if " bite: " in x else "drop_back",
                               x.split(" s ", 1)[1]) for x in ref.messages
                              if (" bite: " in x or " drop-back: " in x) and float(x.split(" s ")[0]) < cut_s)
            if mine_msgs == ref_msgs:
                same += 1
            else:
                diffs.append(f"{dev}: through zenoh {mine_msgs[:6]} vs offline {ref_msgs[:6]}")
    return SuiteReport(total, same, n_rods, wall, diffs)


def main_suite(first_seed: int, n_rods: int, minutes: float, offline: bool) -> int:
    """Run the rod scenario suite through zenoh and print its table."""
    from bench.bite_suite import row

    spp = 5
    duration = 60.0 * minutes
    with tempfile.TemporaryDirectory() as tmp:
        rec, rod = run_session([], duration, first_seed, Path(tmp), ["--scenario", str(first_seed), "--count",
                               str(n_rods), "--samples-per-packet", str(spp)], start_s=60.0 + 6.0 * n_rods)  # fmt: skip
    if rod.returncode != 0:
        print(rod.stderr.decode()[-2000:])
    r = analyse_suite(rec, first_seed, n_rods, spp, offline, duration)
    d = rec.gateway_stats.get("batch_delay_ms")
    print(f"rod scenario suite through zenoh: seeds {first_seed}-{first_seed + n_rods - 1}, {n_rods} rods x "
          f"{minutes:g} min in real time, {spp} samples per packet ({r.score.hours:.2f} rod-hours)")  # fmt: skip
    if d:
        print(f"gateway batch delay (packet arrival -> results to zenoh): p50 {d['p50']:.2f} ms, "
              f"p99 {d['p99']:.2f} ms, max {d['max']:.2f} ms over {d['n']} batches")
    devs = {c["device_id"]: c for c in rec.gateway_stats.get("devices", [])}
    gaps = {k: (c["lost"], c["reordered"], c["duplicates"]) for k, c in devs.items() if any(
        (c["lost"], c["reordered"], c["duplicates"]))}  # fmt: skip
    print(f"gateway ingest: {sum(c['ok'] for c in devs.values())} rod packets in order, queue drops "
          f"{rec.gateway_stats.get('queue_drops', '?')}; (lost, reordered, duplicate) packets by rod: {gaps or 'none'}")
    rod_log = [ln for ln in rod.stderr.decode(errors="replace").splitlines() if "ticks" in ln and "sent" in ln]
    if rod_log:
        print("rod process:", rod_log[-1].removeprefix("INFO "))
    print(f"{'':34s} {'bites':7s} {'runs':7s} {'latency from true θ1 ms (device time)':38s} false bite alarms, "
          "drop-backs, false")
    print(f"{'':34s} {'':7s} {'':7s} {'p50':>5s} {'p99':>5s} {'max':>5s}")
    print(row("gateway through zenoh", r.score, True))
    w = r.wall_ms
    print(f"true θ1 crossing -> alarm received by the observer (wall clock): p50 {pct(w, 50):.0f} ms, "
          f"p99 {pct(w, 99):.0f} ms, max {max(w, default=math.nan):.0f} ms (n={len(w)})")
    if offline:
        print(f"raised alarms equal to the offline pipeline's (bench.bite_suite): {r.same_as_offline}/{r.rods} rods")
    for line in (r.score.notes + r.differences)[:20]:
        print("  ", line)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.bite_latency", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--first-seed", type=int, default=1000, help="suite: first recording (default 1000, untuned)")
    p.add_argument("--rods", type=int, default=24, help="suite: rods, one recording each (default 24)")
    p.add_argument("--minutes", type=float, default=5.0, help="suite: minutes played (default 5, the whole recording)")
    p.add_argument("--no-offline", action="store_true", help="suite: skip the comparison with the offline pipeline")
    p.add_argument("--scripted", action="store_true", help="the older scripted physics-rod run instead of the suite")
    p.add_argument("--bites", type=int, default=12, help="scripted: bites per session (default: 12)")
    p.add_argument("--sessions", type=int, default=1, help="sessions (fresh processes each), default 1")
    p.add_argument("--spacing", type=float, default=12.0, help="seconds between bites (default: 12)")
    p.add_argument("--depth-deg", type=float, default=15.0, help="bite depth, degrees (default: 15)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    if not args.scripted:
        return main_suite(args.first_seed, args.rods, args.minutes, not args.no_offline)
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
