"""Speed of the hook EKF kernel (`HookFilter.run_with_length`), samples per CPU-second, optionally against another
source tree with the same samples, runs interleaved, and whether both trees gave the same estimates.

    python -m bench.hook_kernel_speed                          # this tree: suite crane seed 3, 60 s, 9D and 6D
    python -m bench.hook_kernel_speed --compare <tree>         # also another tree (e.g. a worktree of main)
    python -m bench.hook_kernel_speed --packet 10 --mode 9D    # fed as the gateway feeds it: 10 samples a call
    python -m bench.hook_kernel_speed --still --packet 10 --mode 9D --compare <tree>   # an idle crane's hook

The samples are `bench.hook_suite`'s crane of `--seed` (calibrated IMU errors), simulated once here. Each tree runs
in a child process (PYTHONPATH set to the tree, so its own `gateway` is imported) that starts the filter as the
suite does (`HookFilter.start` on the first 0.5 s, rope length told), runs it once untimed (numba compile or cache
load), then `--runs` times; the figure is the best run's samples per CPU-second (`time.process_time`, which a
shared machine inflates less than wall time). With `--compare` the trees' children alternate `--repeat` times, so
a burst of load hits both, and the best of each tree is compared. The estimates of the two trees are compared
sample by sample: the largest attitude difference (rad) and rope-length difference (relative).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
WARMUP_S = 0.5


def make_samples(seed: int, duration_s: float, path: Path, suite_version: int | None, still: bool = False) -> None:
    """Simulate the suite crane of `seed` (`bench.hook_suite.make_case`'s `suite_version`, None: its default), or
    with `still` that crane's hook hanging still (no swing, no event: an idle crane), and store its IMU samples and
    rope length in `path` (.npz)."""
    from bench.hook_suite import RATE_HZ, SUITE_VERSION, make_case, suite_board
    from devices.hook_physics import HookScenario, simulate

    case = make_case(seed, duration_s, suite_version=SUITE_VERSION if suite_version is None else suite_version)
    truth = simulate(case.physics, HookScenario(duration_s=duration_s) if still else case.scenario)
    sensor = suite_board(seed, "calibrated")
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, 1.0 / RATE_HZ)
    np.savez(path, gyr=gyr, acc=acc, mag=mag, dt_s=1.0 / RATE_HZ, rope_length_m=case.physics.rope_length_m)


def child(data: Path, mode: str, runs: int, packet: int, out: Path) -> dict[str, float]:
    """Time this interpreter's `HookFilter` on the samples in `data`; store its estimates in `out` (.npz)."""
    from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

    d = np.load(data)
    gyr, acc, dt_s = d["gyr"], d["acc"], float(d["dt_s"])
    mag = d["mag"] if mode == "9D" else None
    n0 = int(round(WARMUP_S / dt_s))

    def run() -> tuple[float, np.ndarray, np.ndarray]:
        f = HookFilter(HookFilterSettings(rope_length_m=float(d["rope_length_m"]), rope_length_known=True),
                       use_mag=mag is not None)  # fmt: skip
        f.start(gyr[:n0], acc[:n0], None if mag is None else mag[:n0], dt_s)
        step = packet if packet > 0 else gyr.shape[0]
        qs, ls = [], []
        t0 = time.process_time()
        for i in range(0, gyr.shape[0], step):
            q, length = f.run_with_length(gyr[i:i + step], acc[i:i + step], None if mag is None else mag[i:i + step],
                                          dt_s)  # fmt: skip
            qs.append(q)
            ls.append(length)
        return time.process_time() - t0, np.concatenate(qs), np.concatenate(ls)

    run()  # compile or load the numba cache
    best = math.inf
    for _ in range(runs):
        cpu_s, q, length = run()
        best = min(best, cpu_s)
    np.savez(out, q=q, length=length)
    return {"samples_per_cpu_s": gyr.shape[0] / best, "us_per_sample": 1e6 * best / gyr.shape[0]}


def _spawn(tree: Path, data: Path, mode: str, args: argparse.Namespace, out: Path) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", str(data), "--mode", mode, "--runs",
           str(args.runs), "--packet", str(args.packet), "--out", str(out)]  # fmt: skip
    res = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"child for {tree} failed:\n{res.stderr}")
    result: dict[str, float] = json.loads(res.stdout.strip().splitlines()[-1])
    return result


def differences(a: Path, b: Path) -> tuple[float, float]:
    """Largest attitude difference (rad, from the chord of sign-aligned quaternions) and relative rope-length
    difference between two children's estimates."""
    qa, qb = np.load(a)["q"], np.load(b)["q"]
    la, lb = np.load(a)["length"], np.load(b)["length"]
    sign = np.sign(np.sum(qa * qb, axis=1))[:, None]
    chord = np.linalg.norm(qa - sign * qb, axis=1)
    angle = 4.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0))
    return float(angle.max()), float(np.max(np.abs(la / lb - 1.0)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_kernel_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--seed", type=int, default=3, help="bench.hook_suite crane seed (default 3)")
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds (default 60)")
    p.add_argument("--mode", choices=["9D", "6D", "both"], default="both")
    p.add_argument("--runs", type=int, default=3, help="timed runs per child process, best counts (default 3)")
    p.add_argument("--repeat", type=int, default=2, help="child processes per tree and mode (default 2)")
    p.add_argument("--packet", type=int, default=0, help="samples per run_with_length call (default 0: all at once)")
    p.add_argument("--compare", type=Path, default=None, help="another source tree, e.g. a worktree of main")
    p.add_argument("--still", action="store_true",
                   help="the crane's hook hanging still for the whole run (an idle crane) instead of its events")
    p.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, default=None, help=argparse.SUPPRESS)
    p.add_argument("--suite-version", type=int, default=None,  # bench.hook_suite not imported here: see --child
                   help="bench.hook_suite's crane generator, 1 or 2 (default: its default, 2)")
    args = p.parse_args(argv)
    if args.child is not None:
        print(json.dumps(child(args.child, args.mode, args.runs, args.packet, args.out)))
        return 0
    trees: dict[str, Path] = {"this": ROOT}
    if args.compare is not None:
        trees = {"before": args.compare.resolve(), "after": ROOT}
    modes = ["9D", "6D"] if args.mode == "both" else [args.mode]
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "samples.npz"
        make_samples(args.seed, args.duration, data, args.suite_version, args.still)
        n = int(np.load(data)["gyr"].shape[0])
        feed = f"{args.packet} samples per call" if args.packet > 0 else "one call"
        what = "hanging still" if args.still else "its events"
        print(f"hook EKF kernel: suite crane seed {args.seed} ({what}), {args.duration:g} s ({n} samples), {feed}; "
              f"best of {args.runs} runs x {args.repeat} processes per tree; samples per CPU-second")
        for mode in modes:
            best: dict[str, dict[str, Any]] = {}
            for r in range(args.repeat):
                for name, tree in trees.items():
                    res = _spawn(tree, data, mode, args, Path(tmp) / f"{name}-{mode}-{r}.npz")
                    if name not in best or res["samples_per_cpu_s"] > best[name]["samples_per_cpu_s"]:
                        best[name] = res
            line = "  ".join(f"{name} {b['samples_per_cpu_s']:>9,.0f} ({b['us_per_sample']:.1f} µs)"
                             for name, b in best.items())  # fmt: skip
            if args.compare is not None:
                ratio = best["after"]["samples_per_cpu_s"] / best["before"]["samples_per_cpu_s"]
                angle, rope = differences(Path(tmp) / f"before-{mode}-0.npz", Path(tmp) / f"after-{mode}-0.npz")
                line += f"  after/before {ratio:.2f}x; estimates differ by <= {angle:.1e} rad, rope {rope:.1e} rel"
            print(f"{mode}: {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
