"""Alarm-layer figures: per-block cost of the rod rules, and bite detection on the physics rod (true pitch + noise).
For the bite alarm on the rod scenario suite (fusion included, untuned seeds) see `python -m bench.bite_suite`.

    python -m bench.bench_alarm --help
    python -m bench.bench_alarm                         # cost on 1000 rods, detection on 50 rods x 10 min
    python -m bench.bench_alarm --rods 20 --minutes 3   # quicker

Cost: `RodAlarms.update` on blocks of `--block` samples (quiet rods, the common case, and rods in a bite), as
microseconds per block and the share of one core that 1000 rods at 100 Hz would need.

Detection: `devices.rod_physics.RodBank` rods get bites (depth 12-30 deg, 0.5-3 s) every 40-80 s, with wind,
waves and handling (roll/yaw turns) in between. The detector sees the true tip pitch plus 0.2 deg noise and the
tip's earth-frame vertical acceleration (gravity removed) plus 0.1 m/s^2 noise, in blocks. A bite alarm within
1.5 s after a bite starts is a hit (latency = alarm sample time - bite start, not the theta1 crossing); any other
bite alarm is false.
Latency excludes transport and block buffering: add up to (block - 1) / rate for a block-buffering device.
"""

from __future__ import annotations

import argparse
import math
import time
import timeit

import numpy as np
from tqdm import tqdm

from devices.common import G_M_S2
from devices.rod_physics import Bite, Handling, RodBank, RodSettings, Waves, Wind
from gateway.alarm.bite import tip_acc_up
from gateway.alarm.rules import RodAlarms
from gateway.config import RodThresholds

RATE_HZ = 100.0


def bench_cost(n_rods: int, n_blocks: int, block: int, seed: int) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    t = np.arange(n_blocks * block) / RATE_HZ
    quiet = math.radians(30.0) + math.radians(0.2) * rng.standard_normal((n_rods, t.size))
    acc = 0.1 * rng.standard_normal((n_rods, t.size))
    rods = [RodAlarms(f"rod-{i}") for i in range(n_rods)]
    out = {}
    for label, pitch in (("quiet", quiet), ("bite", quiet - np.radians(15.0) * (t > t[-1] / 2))):
        for r in rods:
            r.detector.rebaseline(math.radians(30.0))
        per_round = []
        for b in tqdm(range(n_blocks), desc=f"cost ({label})", leave=False):
            sl = slice(b * block, (b + 1) * block)
            ts = t[sl]
            start = time.perf_counter()
            for i, r in enumerate(rods):
                r.update(ts, pitch[i, sl], None, None, acc[i, sl])
            per_round.append((time.perf_counter() - start) / n_rods * 1e6)
        out[f"{label}_us_median"] = float(np.median(per_round))
        out[f"{label}_us_min"] = float(np.min(per_round))
    x = rng.standard_normal(block)
    out["numpy_max_us"] = min(timeit.repeat(x.max, number=2000, repeat=5)) / 2000 * 1e6
    return out


def bench_detection(
    n_rods: int, minutes: float, block: int, seed: int, use_acc: bool, sensitivity: int = 3
) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    bank = RodBank(RodSettings(), n_rods, seed=seed)
    horizon = minutes * 60.0
    truth: list[list[float]] = [[] for _ in range(n_rods)]
    for i in range(n_rods):
        t = 15.0 + rng.uniform(0, 20)
        while t < horizon - 10:
            dur = rng.uniform(0.5, 3.0)
            bank.inject(Bite(t, dur, math.radians(rng.uniform(12, 30))), i)
            truth[i].append(t)
            gap = rng.uniform(40, 80)
            mid = t + dur + 8.0
            kind = rng.integers(3)
            if kind == 0:
                bank.inject(Wind(mid, gap - 20, rng.uniform(0.5, 2.0)), i)
            elif kind == 1:
                bank.inject(Waves(mid, gap - 20, rng.uniform(0.2, 0.6), rng.uniform(3, 8)), i)
            else:
                bank.inject(Handling(mid, 4.0, math.radians(rng.uniform(-40, 40)), math.radians(rng.uniform(-25, 25))),
                            i)  # fmt: skip
            t += gap
    rods = [RodAlarms(f"rod-{i}", RodThresholds(sensitivity=sensitivity)) for i in range(n_rods)]
    alarms: list[list[float]] = [[] for _ in range(n_rods)]
    n_blocks = int(horizon * RATE_HZ) // block
    for _ in tqdm(range(n_blocks), desc=f"detection ({'pitch+acc' if use_acc else 'pitch only'})", leave=False):
        blk = bank.run_block(block, 1.0 / RATE_HZ)
        pitch = blk.euler_rad[..., 1] + math.radians(0.2) * rng.standard_normal((n_rods, block))
        acc = tip_acc_up(blk.quat_wxyz, blk.acc_m_s2, G_M_S2) + 0.1 * rng.standard_normal((n_rods, block))
        for i, r in enumerate(rods):
            _, conds = r.update(blk.t_s, pitch[i], None, None, acc[i] if use_acc else None)
            alarms[i] += [c.t_s for c in conds if c.type == "bite" and c.severity is not None]
    latencies, false, n_bites = [], 0, 0
    for i in range(n_rods):
        n_bites += len(truth[i])
        for a in alarms[i]:
            hits = [a - b for b in truth[i] if 0.0 <= a - b <= 1.5]
            if hits:
                latencies.append(min(hits))
            else:
                false += 1
    lat = np.array(latencies) * 1e3
    hours = n_rods * horizon / 3600.0
    return {
        "bites": n_bites, "detected": len(latencies), "false_alarms": false, "false_per_rod_h": false / hours,
        "p50_ms": float(np.percentile(lat, 50)) if lat.size else math.nan,
        "p99_ms": float(np.percentile(lat, 99)) if lat.size else math.nan,
        "max_ms": float(lat.max()) if lat.size else math.nan,
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cost-rods", type=int, default=1000, help="rods in the cost benchmark")
    ap.add_argument("--cost-blocks", type=int, default=20, help="blocks per rod in the cost benchmark")
    ap.add_argument("--rods", type=int, default=50, help="simulated rods in the detection benchmark")
    ap.add_argument("--minutes", type=float, default=10.0, help="simulated minutes per rod")
    ap.add_argument("--block", type=int, default=10, help="samples per block (100 Hz)")
    ap.add_argument("--seed", type=int, default=5, help="physics seed (nothing is tuned on this bench)")
    ap.add_argument("--sensitivity", type=int, default=3, choices=range(1, 6), help="bite sensitivity step")
    ap.add_argument("--skip-cost", action="store_true")
    ap.add_argument("--skip-detection", action="store_true")
    a = ap.parse_args()
    if not a.skip_cost:
        c = bench_cost(a.cost_rods, a.cost_blocks, a.block, a.seed)
        share = c["quiet_us_median"] * 1e-6 * 1000 * RATE_HZ / a.block
        print(f"cost per RodAlarms.update (block {a.block}), median / best round: quiet {c['quiet_us_median']:.1f} / "
              f"{c['quiet_us_min']:.1f} us, in a bite {c['bite_us_median']:.1f} / {c['bite_us_min']:.1f} us "
              f"(= {c['quiet_us_min'] / c['numpy_max_us']:.1f} x one numpy max() of {c['numpy_max_us']:.2f} us); "
              f"1000 rods x 100 Hz need {share:.0%} of one core at the median")  # fmt: skip
    if not a.skip_detection:
        for use_acc in (True, False):
            d = bench_detection(a.rods, a.minutes, a.block, a.seed, use_acc, a.sensitivity)
            print(f"detection (sensitivity {a.sensitivity}, {'pitch + accel cue' if use_acc else 'pitch only'}): "
                  f"{d['detected']}/{d['bites']} "
                  f"bites, latency p50 {d['p50_ms']:.0f} ms, p99 {d['p99_ms']:.0f} ms, max {d['max_ms']:.0f} ms; "
                  f"{d['false_alarms']} false alarms ({d['false_per_rod_h']:.2f} per rod-hour)")  # fmt: skip


if __name__ == "__main__":
    main()
