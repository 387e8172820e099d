"""Whether the hook filter's torsion 1σ (`HookFilter.torsion_std_rad`, published as a Swing's `torsion_std_rad`) is
honest: the torsion error over the σ the filter gives with it, on bench.hook_suite's cranes and boards.

For a Gaussian error, 68 % of samples fall within 1σ, 95 % within 2σ and 99.7 % within 3σ. The figures are split
at `--early-s` (default 5 s): the first seconds are where an uncalibrated compass's hard iron is still being learnt
and the torsion can be tens of degrees off (the σ should say so), after that it holds ~1° (the σ should not claim
less). The torsion is the absolute one (the rest heading configured, as bench.hook_suite scores it); the filter is
told the rope length and run on 10-sample calls, read after each.

    python -m bench.hook_torsion_std                                  # tuning cranes 1-30, four more boards each
    python -m bench.hook_torsion_std --seeds 3544-3583 --draws 5-8    # cranes and boards never tuned on
    python -m bench.hook_torsion_std --imu uncalibrated               # a raw board (hard iron tens of µT)
    python -m bench.hook_torsion_std --settings torsion_std_floor_deg=0  # the covariance alone
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from bench.hook_suite import WARMUP_S, parse_seeds, parse_settings, simulate_seed
from gateway.fusion import hook
from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

CALL_SAMPLES = 10


def torsion_errors(seed: int, draw: int, imu: str, duration_s: float, overrides: dict[str, float], rate_hz: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """(t_s, torsion error rad, torsion σ rad) at the end of each `CALL_SAMPLES` call, for crane `seed` on board
    `draw` (bench.hook_suite's `sensor_draw`)."""
    case, truth, gyr, acc, mag = simulate_seed(seed, duration_s, imu, True, sensor_draw=draw, rate_hz=rate_hz)
    dt = 1.0 / rate_hz
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True, **overrides))
    n = int(WARMUP_S * rate_hz)
    assert mag is not None
    f.start(gyr[:n], acc[:n], mag[:n], dt)
    t, err, std = [], [], []
    for k in range(0, gyr.shape[0] - CALL_SAMPLES + 1, CALL_SAMPLES):
        j = k + CALL_SAMPLES
        q, _ = f.run_with_length(gyr[k:j], acc[k:j], mag[k:j], dt)
        t.append(float(truth.t_s[j - 1]))
        err.append(float(hook.torsion(np.asarray(q)[-1], truth.torsion_rad[j - 1])))
        std.append(f.torsion_std_rad)
    return np.array(t), np.array(err), np.array(std)


def coverage(err: np.ndarray, std: np.ndarray) -> tuple[float, float, float]:
    """Shares of |err| within 1, 2 and 3 σ."""
    z = np.abs(err) / std
    return float(np.mean(z <= 1.0)), float(np.mean(z <= 2.0)), float(np.mean(z <= 3.0))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_torsion_std", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--seeds", default="1-30", help="bench.hook_suite cranes, e.g. 1-30 (tuning) or 3544-3583")
    p.add_argument("--draws", default="1-4", help="boards per crane (bench.hook_suite --sensor-draw; 0 is the "
                   "suite's own), e.g. 1-4")
    p.add_argument("--imu", default="legacy", choices=("calibrated", "legacy", "uncalibrated"),
                   help="the board's error preset (default legacy: MPU-6050/HMC5883L class)")
    p.add_argument("--duration", type=float, default=120.0, help="seconds per crane (default 120)")
    p.add_argument("--early-s", type=float, default=5.0, help="the early window's end, s (default 5)")
    p.add_argument("--rate-hz", type=float, default=100.0, help="IMU rate (default 100)")
    p.add_argument("--settings", default="", help="hook filter settings on top, name=value,... "
                   "(bench.hook_suite --settings)")
    p.add_argument("--worst", type=int, default=5, help="list this many crane/board runs with the lowest 2σ share")
    args = p.parse_args(argv)
    overrides = parse_settings(args.settings)
    seeds, draws = parse_seeds(args.seeds), parse_seeds(args.draws)
    runs: list[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]] = []
    t0 = time.perf_counter()
    for i, seed in enumerate(seeds):
        for draw in draws:
            runs.append((seed, draw, *torsion_errors(seed, draw, args.imu, args.duration, overrides, args.rate_hz)))
        print(f"\r  {i + 1}/{len(seeds)} cranes ({time.perf_counter() - t0:.0f} s)", end="", flush=True)
    print()
    t = np.concatenate([r[2] for r in runs])
    err, std = np.concatenate([r[3] for r in runs]), np.concatenate([r[4] for r in runs])
    print(f"{len(seeds)} cranes x {len(draws)} boards ({args.imu}), {args.duration:.0f} s each, σ read every "
          f"{CALL_SAMPLES} samples; torsion error within 1σ / 2σ / 3σ (Gaussian: 68 / 95 / 99.7 %)")
    for name, sel in ((f"first {args.early_s:g} s", t <= args.early_s), (f"after {args.early_s:g} s", t > args.early_s),
                      ("whole run", t > 0.0)):  # fmt: skip
        c1, c2, c3 = coverage(err[sel], std[sel])
        print(f"  {name:>12}: {100 * c1:5.1f} / {100 * c2:5.1f} / {100 * c3:5.1f} %   median σ "
              f"{math.degrees(float(np.median(std[sel]))):6.2f}°   error RMS "
              f"{math.degrees(float(np.sqrt(np.mean(err[sel] ** 2)))):6.2f}°")
    worst = sorted(runs, key=lambda r: coverage(r[3], r[4])[1])[: args.worst]
    print("  lowest 2σ shares (crane/board: 2σ share, torsion RMS, median σ):")
    for seed, draw, _, e, s in worst:
        rms_deg, std_deg = math.degrees(float(np.sqrt(np.mean(e**2)))), math.degrees(float(np.median(s)))
        print(f"    {seed}/{draw}: {100 * coverage(e, s)[1]:5.1f} %, {rms_deg:6.2f}°, {std_deg:5.2f}°")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
