"""Bite alarm on the rod scenario suite (issue 10): the gateway's rules on its own fused pitch, next to the plain
10° rule on the same fused pitch and on the true pitch.

    python -m bench.bite_suite                      # seeds 1000-1023: 24 rods x 5 min = 2 rod-hours, never tuned on
    python -m bench.bite_suite --seeds 0-7          # the seeds the detector was tuned on
    python -m bench.bite_suite --seeds 1000-1001 --list   # quick look, every alarm listed

Each seed is one `devices.rod_scenarios` recording (bites, runs, nibbles, knocks, wind, handling, drop-backs;
MPU-6050 errors, ±2 g accelerometer). Its IMU samples go through `gateway.pipeline.Pipeline` (fusion and rod
rules exactly as the service runs them; 0.5 s packets, which give the same alarms as any other packetization:
tests/alarm/test_packetization.py). Scoring, in device time:

- a bite or run is caught by the first bite alarm in [start, end + 1 s]; latency = that alarm's sample time
  minus the first sample whose *true* pitch is θ1 below the true rest (one that never gets there, possible
  only at a θ1 above 12°, is not counted);
- every other bite alarm is false, charged to the event whose [start, end + 3 s] holds it (else "quiet");
- a drop-back is caught by a drop-back alarm in [start, end + 1 s]; any other drop-back alarm is false, and
  "on a release" when it falls within 3 s after a bite or run.

Plain rule (θ1 = 10° at the default sensitivity): a bite at the first sample ≥ θ1 below the median of the
previous 1 s; it re-arms after 5 s within 0.7·θ1 of that running median. At another sensitivity every θ1
(crossings, plain rule) is the effective one.
"""

from __future__ import annotations

import argparse
import math
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from devices.common import imu_payload
from devices.rod_scenarios import ALARMING, FAMILIES, Scenario, ScenarioEvent, ScenarioSettings, make_scenario
from gateway import schemas
from gateway.config import RodThresholds
from gateway.fusion.quaternion import to_euler
from gateway.pipeline import Pipeline, PipelineSettings

TUNED_SEEDS = range(0, 8)
REPORT_SEEDS = range(1000, 1024)
T0_US = 7_000_000  # device clock at the recording's start
PACKET = 50


@dataclass
class Score:
    """Counts and latencies of one detector over some recordings."""

    caught: Counter[str] = field(default_factory=Counter)  # family -> events caught
    total: Counter[str] = field(default_factory=Counter)  # family -> events
    latency_ms: list[float] = field(default_factory=list)
    false_bites: Counter[str] = field(default_factory=Counter)  # family (or "quiet") -> false bite alarms
    false_drops: Counter[str] = field(default_factory=Counter)  # ... false drop-back alarms ("release": after a bite)
    hours: float = 0.0
    below_theta1: int = 0  # bites and runs whose true pitch never reached theta1: neither owed nor false
    notes: list[str] = field(default_factory=list)

    def add(self, other: Score) -> None:
        self.caught.update(other.caught)
        self.total.update(other.total)
        self.latency_ms += other.latency_ms
        self.false_bites.update(other.false_bites)
        self.false_drops.update(other.false_drops)
        self.hours += other.hours
        self.below_theta1 += other.below_theta1
        self.notes += other.notes


def _holder(events: Sequence[ScenarioEvent], t: float, after_s: float) -> ScenarioEvent | None:
    return next((e for e in events if e.t_start_s <= t <= e.t_end_s + after_s), None)


def score(sc: Scenario, bite_s: Sequence[float], drop_s: Sequence[float] | None) -> Score:
    """Match alarm times (recording seconds) to the scenario's events (rules in the module docstring)."""
    out = Score(hours=sc.hours)
    used: set[int] = set()
    for e in sc.events:
        if e.family in ALARMING and math.isnan(e.cross_s):  # never reached theta1 (a higher one): nothing owed
            out.below_theta1 += 1
            used.update(i for i, t in enumerate(bite_s) if e.t_start_s <= t <= e.t_end_s + 1.0)
            continue
        out.total[e.family] += 1
        if e.family in ALARMING:
            hits = [i for i, t in enumerate(bite_s) if e.t_start_s <= t <= e.t_end_s + 1.0]
            if hits:
                out.caught[e.family] += 1
                used.add(hits[0])
                out.latency_ms.append(1e3 * (bite_s[hits[0]] - e.cross_s))
            else:
                out.notes.append(f"seed {sc.seed}: missed {e.family} at {e.t_start_s:.1f} s ({e.detail})")
        elif e.family == "drop_back" and drop_s is not None:
            if any(e.t_start_s <= t <= e.t_end_s + 1.0 for t in drop_s):
                out.caught[e.family] += 1
            else:
                out.notes.append(f"seed {sc.seed}: missed drop-back at {e.t_start_s:.1f} s ({e.detail})")
    for i, t in enumerate(bite_s):
        if i in used:
            continue
        e = _holder(sc.events, t, 3.0)
        out.false_bites[e.family if e else "quiet"] += 1
        out.notes.append(f"seed {sc.seed}: false bite at {t:.2f} s in {e.family if e else 'quiet'} "
                         f"({e.detail if e else ''})")  # fmt: skip
    for t in drop_s or ():
        e = _holder(sc.events, t, 1.0)
        if e is not None and e.family == "drop_back":
            continue
        e = _holder(sc.events, t, 3.0)
        where = "release" if e is not None and e.family in ALARMING else e.family if e else "quiet"
        out.false_drops[where] += 1
        out.notes.append(f"seed {sc.seed}: false drop-back at {t:.2f} s in {where}")
    return out


def plain_rule(t_s: np.ndarray, pitch_rad: np.ndarray, theta1_rad: float, quiet_s: float = 5.0) -> list[float]:
    """Times of the plain rule's alarms: pitch >= theta1 below the median of the previous 1 s (see the docstring)."""
    w = 100
    med = np.full(pitch_rad.size, np.nan)
    med[w:] = np.median(sliding_window_view(pitch_rad, w)[:-1], axis=1)
    below = pitch_rad - med <= -theta1_rad
    out: list[float] = []
    i = 0
    while True:
        hits = np.flatnonzero(below[i:])
        if hits.size == 0:
            return out
        k = i + int(hits[0])
        out.append(float(t_s[k]))
        near = np.abs(pitch_rad[k:] - med[k:]) < 0.7 * theta1_rad
        run = np.flatnonzero(~near)
        # re-arm at the end of the first 5 s spell inside the band
        starts = np.r_[0, run + 1]
        ends = np.r_[run, near.size]
        long = np.flatnonzero(ends - starts >= int(quiet_s * 100))
        if long.size == 0:
            return out
        i = k + int(starts[long[0]]) + int(quiet_s * 100)


@dataclass
class RodRun:
    """What the gateway did with one recording."""

    bite_s: list[float]
    drop_s: list[float]
    fused_pitch_rad: np.ndarray
    messages: list[str]


def run_gateway(sc: Scenario, th: RodThresholds | None = None, packet: int = PACKET,
                lost: np.ndarray | None = None, bridge: bool = False) -> RodRun:  # fmt: skip
    """Feed the recording to a fresh Pipeline as packets of `packet` samples (default 0.5 s), but those `lost` (bool
    per packet) marks; alarms in recording seconds, every fused pitch (NaN where lost). `bridge`: the lost samples
    bridged for the filter (`gateway.fusion.gaps`, the rod kind's default), else fed back to back."""
    p = Pipeline(PipelineSettings(attitude_blocks=True), {"rod": th} if th else None)
    if bridge:
        p.bank.bridge_kinds.add("rod")
    else:
        p.bank.bridge_kinds.discard("rod")
    n = sc.t_s.size
    bite_s, drop_s, msgs = [], [], []
    quats = np.full((n, 4), np.nan)
    for seq, i in enumerate(range(0, n, packet)):
        if lost is not None and lost[seq]:
            continue
        j = min(i + packet, n)
        t0_us = T0_US + int(round(sc.t_s[i] * 1e6))
        payload = imu_payload(device_id="rod-1", kind="rod", boot_id=1, seq=seq, t0_us=t0_us, rate_hz=100.0,
                              gyr_rad_s=sc.gyr_rad_s[i:j], acc_m_s2=sc.acc_m_s2[i:j], mag_uT=sc.mag_uT[i:j],
                              wall_t0_us=t0_us + 1_700_000_000_000_000)  # fmt: skip
        out = p.process([schemas.decode(schemas.imu_key("rod", "rod-1"), payload)], now_wall_s=1.7e9 + i / 100)
        for a in out.alarms:
            if a.change.kind != "raised":
                continue
            t = (a.t_us - T0_US) * 1e-6
            msgs.append(f"{t:8.2f} s {a.change.alarm.message}")
            kind = a.change.alarm.type
            (bite_s if kind == "bite" else drop_s if kind == "drop_back" else []).append(t)
        for b in out.attitude_blocks:
            k = int(round((b.t0_us - T0_US) * 1e-4 - sc.t_s[0] * 100))  # sample k is at t_s[0] + k * 10 ms
            quats[k : k + len(b.quat_wxyz)] = b.quat_wxyz
    return RodRun(bite_s, drop_s, to_euler(quats)[:, 1], msgs)


def parse_seeds(text: str) -> list[int]:
    """'1000-1023' or '3,5,9' or a mix."""
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def pct(xs: list[float], q: float) -> float:
    return float(np.percentile(xs, q)) if xs else math.nan


def row(name: str, s: Score, drops: bool) -> str:
    lat = s.latency_ms
    fb = " ".join(f"{s.false_bites[f]}" for f in (*FAMILIES[2:], "quiet"))
    dcol = (f"{s.caught['drop_back']}/{s.total['drop_back']:<4d} {sum(s.false_drops.values()):3d} "
            f"({s.false_drops['release']} on release)") if drops else "-"  # fmt: skip
    return (f"{name:34s} {s.caught['bite']:3d}/{s.total['bite']:<3d} {s.caught['run']:3d}/{s.total['run']:<3d} "
            f"{pct(lat, 50):5.0f} {pct(lat, 99):5.0f} {max(lat, default=math.nan):5.0f}   "
            f"{sum(s.false_bites.values()):3d} ({fb})   {dcol}")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.bite_suite", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--seeds", default=f"{REPORT_SEEDS.start}-{REPORT_SEEDS.stop - 1}",
                    help=f"recordings (default: the untuned {REPORT_SEEDS.start}-{REPORT_SEEDS.stop - 1}; "
                         f"tuned on {TUNED_SEEDS.start}-{TUNED_SEEDS.stop - 1})")  # fmt: skip
    ap.add_argument("--sensitivity", type=int, default=3, choices=range(1, 6))
    ap.add_argument("--list", action="store_true", help="print every alarm and every miss")
    ap.add_argument("--packet", type=int, default=PACKET, help=f"samples per packet (default {PACKET})")
    ap.add_argument("--loss", type=float, default=0.0,
                    help="packets lost on a Gilbert-Elliott link (devices.common.LinkSim), long-run share (default 0)")
    ap.add_argument("--burst", type=float, default=2.0, help="with --loss: mean burst length, packets (default 2)")
    ap.add_argument("--bridge", action="store_true",
                    help="bridge lost samples for the filter (gateway.fusion.gaps, the rod kind's default: gyro "
                         "tapered); without it they are fed back to back")
    a = ap.parse_args(argv)
    seeds = parse_seeds(a.seeds)
    th = RodThresholds(sensitivity=a.sensitivity)
    theta1 = math.radians(th.effective_bite_deg)
    gw, plain_fused, plain_true = Score(), Score(), Score()
    err_all: list[np.ndarray] = []
    err_by: dict[str, float] = {}
    clipped = 0
    start = time.perf_counter()
    for seed in seeds:
        sc = make_scenario(seed, ScenarioSettings(theta1_deg=th.effective_bite_deg))  # crossings of this theta1
        lost = None
        if a.loss > 0:
            from bench.link_loss import lost_packets

            lost = lost_packets(-(-sc.t_s.size // a.packet), a.loss, a.burst, 5_000 + seed)
        r = run_gateway(sc, th, a.packet, lost, a.bridge)
        gw.add(score(sc, r.bite_s, r.drop_s))
        plain_fused.add(score(sc, plain_rule(sc.t_s, r.fused_pitch_rad, theta1), None))
        plain_true.add(score(sc, plain_rule(sc.t_s, sc.euler_rad[:, 1], theta1), None))
        err = np.degrees(r.fused_pitch_rad - sc.euler_rad[:, 1])
        settled = (sc.t_s > 3.0) & np.isfinite(err)  # lost samples have no fused pitch
        err -= np.median(err[settled])  # the constant tilt of the accelerometer offset is not a deviation
        err_all.append(np.abs(err[settled]))
        clipped += int((np.abs(sc.acc_m_s2) >= 0.999 * 2 * 9.80665).any(axis=1).sum())
        for e in sc.events:
            w = (sc.t_s >= e.t_start_s) & (sc.t_s <= e.t_end_s + 2.0)
            err_by[e.family] = max(err_by.get(e.family, 0.0), float(np.fmax.reduce(np.abs(err[w]), initial=0.0)))
        if a.list:
            print(f"-- seed {seed}:", *r.messages, sep="\n   ")
    errs = np.concatenate(err_all)
    if a.loss > 0:
        print(f"link: {a.loss:.1%} of {a.packet}-sample packets lost in bursts of {a.burst:g} on average, "
              + ("bridged (gateway.fusion.gaps, the rod default)" if a.bridge else "fed back to back"))  # fmt: skip
    print(f"rod scenario suite, seeds {a.seeds}: {len(seeds)} rods, {gw.hours:.2f} rod-hours, sensitivity "
          f"{a.sensitivity} (θ1 {th.effective_bite_deg:g}°); tuned on seeds {TUNED_SEEDS.start}-"
          f"{TUNED_SEEDS.stop - 1} ({time.perf_counter() - start:.0f} s)")  # fmt: skip
    print(f"fused - true pitch, less its median (a constant offset moves the rest too): p99 "
          f"{np.percentile(errs, 99):.2f}°, max {errs.max():.2f}° (after the first 3 s) "
          f"({clipped} samples with the ±2 g accelerometer clipped); worst during (and 2 s after) each family: "
          + ", ".join(f"{f} {err_by.get(f, math.nan):.2f}°" for f in FAMILIES))  # fmt: skip
    print(f"{'':34s} {'bites':7s} {'runs':7s} {'latency from true θ1 ms':23s} "
          f"{'false bite alarms (' + ' '.join(FAMILIES[2:]) + ' quiet)':54s} drop-backs, false")
    print(f"{'':34s} {'':7s} {'':7s} {'p50':>5s} {'p99':>5s} {'max':>5s}")
    if gw.below_theta1:
        print(f"({gw.below_theta1} bites or runs never took the true pitch θ1 below rest: not counted)")
    print(row("gateway rules, fused pitch", gw, True))
    print(row(f"plain {th.effective_bite_deg:g}° rule, same fused pitch", plain_fused, False))
    print(row(f"plain {th.effective_bite_deg:g}° rule, true pitch", plain_true, False))
    if a.list or gw.notes:
        print("gateway misses and false alarms:", *gw.notes[:40], sep="\n  ")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
