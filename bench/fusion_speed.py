"""Throughput of the default attitude filter, printed as samples/s, with VQF's C++ on the same data for the ratio.

Measures: per-sample `update()`, `update_block()` with 10-sample packets, `run()` over a whole BROAD trial, and the
batched step (`DefaultFilterBatch.step`, 10-sample rounds) for 1, 100 and 1000 devices. numba compiles on first
call: every case is warmed up first and compile time is excluded. Each figure is the best of `--repeats` runs
(the machine is shared; best-of is the least disturbed). Two columns: wall-clock samples/s, and samples per CPU-second
of this process (less sensitive to other load; for the batched step it is per core, the wall figure is aggregate).
Usage: `python -m bench.fusion_speed [--help]`.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gateway.fusion.base import FloatArray
from gateway.fusion.batch import DefaultFilterBatch
from gateway.fusion.default import DefaultFilter

DEFAULT_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "broad"
DEFAULT_TRIAL = "06_undisturbed_fast_rotation_A"


def load_data(data_dir: Path, trial: str) -> tuple[FloatArray, FloatArray, FloatArray, float, str]:
    """gyr, acc, mag (N, 3) and dt_s from a BROAD trial, or 200 s of synthetic 285.7 Hz data if it is absent (the
    trial has 56 380 samples; the synthetic stand-in is about as long, so every case has enough samples)."""
    path = data_dir / f"{trial}.mat"
    if path.is_file():
        from gateway.fusion import broad

        t = broad.load_trial(path)
        return t.gyr_rad_s, t.acc_m_s2, t.mag_uT, t.dt_s, f"BROAD {trial} ({t.n} samples)"
    rng = np.random.default_rng(0)
    n = 200 * 286
    gyr = 0.5 * rng.normal(size=(n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + 0.3 * rng.normal(size=(n, 3))
    mag = np.array([0.0, 18.0, -46.0]) + rng.normal(size=(n, 3))
    return gyr, acc, mag, 1 / 285.714, (f"synthetic noise, {n} samples ({path} not found: pass --data-dir, or put "
                                        "the BROAD trials in ../shared/data/broad beside the repo)")


Rate = tuple[float, float]


def best_rate(fn: Callable[[], int], repeats: int) -> Rate:
    """(wall, CPU) samples/s of the fastest of `repeats` calls; `fn` returns the number of samples it processed."""
    wall = cpu = 0.0
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        n = fn()
        wall = max(wall, n / (time.perf_counter() - t0))
        cpu = max(cpu, n / max(time.process_time() - c0, 1e-9))
    return wall, cpu


def bench_single(gyr: FloatArray, acc: FloatArray, mag: FloatArray | None, dt_s: float, repeats: int,
                 n_update: int) -> dict[str, Rate]:
    out: dict[str, Rate] = {}
    use_mag = mag is not None

    n_update = min(n_update, int(gyr.shape[0]))  # a short recording must not index past its end

    def per_sample() -> int:
        f = DefaultFilter(use_mag=use_mag)
        for i in range(n_update):
            f.update(gyr[i], acc[i], None if mag is None else mag[i], dt_s)
        return n_update

    def blocks() -> int:
        f = DefaultFilter(use_mag=use_mag)
        n = gyr.shape[0] - gyr.shape[0] % 10
        for i in range(0, n, 10):
            f.update_block(gyr[i : i + 10], acc[i : i + 10], None if mag is None else mag[i : i + 10], dt_s)
        return n

    def whole() -> int:
        DefaultFilter(use_mag=use_mag).run(gyr, acc, mag, dt_s)
        return int(gyr.shape[0])

    def vqf() -> int:
        from vqf import VQF

        VQF(dt_s).updateBatch(gyr, acc, mag)
        return int(gyr.shape[0])

    cases = {"update() per sample": per_sample, "update_block() 10 samples": blocks, "run() whole trial": whole,
             "VQF C++ updateBatch (whole trial)": vqf}
    for name, fn in cases.items():
        fn()  # warm-up: numba compile / cache load excluded
        out[name] = best_rate(fn, repeats)
    return out


def bench_batch(gyr: FloatArray, acc: FloatArray, mag: FloatArray, dt_s: float, n_dev: int, rounds: int,
                repeats: int) -> Rate:
    """Aggregate samples/s of `DefaultFilterBatch.step` with 10-sample rounds; half the devices 9D, half 6D."""
    block = 10
    batch = DefaultFilterBatch()
    for i in range(n_dev):
        batch.add(f"d{i}", dt_s=dt_s, use_mag=i % 2 == 0, acc_m_s2=acc[0], mag_uT=mag[0])
    n = gyr.shape[0] - block
    offsets = (np.arange(n_dev) * 997) % n  # each device replays the trial from its own point
    idx = (offsets[:, None] + np.arange(rounds * block)[None, :]) % gyr.shape[0]
    g, a, m = gyr[idx], acc[idx], mag[idx]
    batch.step(g[:, :block], a[:, :block], m[:, :block])  # warm-up

    def run() -> int:
        for r in range(rounds):
            s = np.s_[:, r * block : (r + 1) * block]
            batch.step(g[s], a[s], m[s])
        return n_dev * rounds * block

    return best_rate(run, repeats)


def main(data_dir: Path, trial: str, repeats: int, n_update: int, devices: list[int], batch_samples: int) -> None:
    gyr, acc, mag, dt_s, label = load_data(data_dir, trial)
    print(f"data: {label}, dt = {dt_s * 1e3:.3f} ms; best of {repeats}; JIT compile excluded (warm-up first)")
    rows: list[tuple[str, Rate]] = []
    for mode, m in (("9D", mag), ("6D", None)):
        res = bench_single(gyr, acc, m, dt_s, repeats, n_update)
        rows += [(f"{mode} {k}", v) for k, v in res.items()]
        print(f"{mode}: " + ", ".join(f"{k}: {v[0] / 1e6:.3f} M/s" for k, v in res.items()), flush=True)
    vqf9 = dict(rows)["9D VQF C++ updateBatch (whole trial)"][0]
    for n_dev in tqdm(devices, desc="batched step", unit="config"):
        rounds = max(2, batch_samples // (10 * n_dev))
        rows.append((f"batch {n_dev} devices (10-sample rounds, half 9D)",
                     bench_batch(gyr, acc, mag, dt_s, n_dev, rounds, repeats)))
    print(f"\n{'case':54s} {'samples/s':>12s} {'vs VQF C++ 9D':>14s} {'per CPU-s':>12s}")
    for name, (wall, cpu) in rows:
        print(f"{name:54s} {wall:12,.0f} {wall / vqf9:13.2f}x {cpu:12,.0f}")


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA, help="BROAD folder (default: %(default)s)")
    p.add_argument("--trial", default=DEFAULT_TRIAL, help="trial name without .mat (default: %(default)s)")
    p.add_argument("--repeats", type=int, default=3, help="runs per case; the best is reported (default: 3)")
    p.add_argument("--n-update", type=int, default=20000, help="samples for the per-sample update() case")
    p.add_argument("--devices", type=int, nargs="+", default=[1, 100, 1000], help="batch sizes (default: 1 100 1000)")
    p.add_argument("--batch-samples", type=int, default=200_000,
                   help="aggregate samples per batched run (default: %(default)s)")
    args = p.parse_args()
    main(args.data_dir, args.trial, args.repeats, args.n_update, args.devices, args.batch_samples)
