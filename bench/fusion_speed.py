"""Throughput of the default attitude filter against VQF's C++ (pip `vqf`) on the same samples, in one run.

Each case of ours has a VQF twin fed exactly the same samples the same way, and the ratio is taken per CPU-second of
this process (CPU time is less disturbed than wall time on a shared machine; for the multi-threaded batched step it is
summed over threads, the wall figure is aggregate):

- one device, per sample: `DefaultFilter.update()` vs `VQF.update()` (both pay a Python call per sample);
- one device, 10-sample packets: `update_block()` vs `VQF.updateBatch()` on the same 10 samples;
- one device, whole trial: `run()` vs `VQF.updateBatch()` over the trial;
- N devices (1, 100, 1000; half 9D, half 6D), 10-sample rounds: one `DefaultFilterBatch.step` per round vs N
  `VQF.updateBatch()` calls per round (VQF has no multi-device call).

numba compiles on first call: every case is warmed up first and compile time is excluded. Each figure is the best of
`--repeats` runs (best-of is the least disturbed). Without the BROAD trial a synthetic stand-in of the same length is
used (said on the first line). Usage: `python -m bench.fusion_speed [--help]`.
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


Pair = tuple[Rate, Rate]  # (ours, VQF C++) on the same samples


def bench_single(gyr: FloatArray, acc: FloatArray, mag: FloatArray | None, dt_s: float, repeats: int,
                 n_update: int) -> dict[str, Pair]:
    """{case: (ours, VQF)} for one device: per sample, 10-sample packets, whole trial."""
    from vqf import VQF

    use_mag = mag is not None
    n_update = min(n_update, int(gyr.shape[0]))  # a short recording must not index past its end
    n_blocks = int(gyr.shape[0] - gyr.shape[0] % 10)
    # rows and packets sliced once, outside the timed loops, so both sides get the same ready arrays
    rows = [(gyr[i], acc[i], None if mag is None else mag[i]) for i in range(n_update)]
    packets = [(gyr[i : i + 10], acc[i : i + 10], None if mag is None else mag[i : i + 10])
               for i in range(0, n_blocks, 10)]

    def ours_sample() -> int:
        f = DefaultFilter(use_mag=use_mag)
        for g, a, m in rows:
            f.update(g, a, m, dt_s)
        return n_update

    def vqf_sample() -> int:
        v = VQF(dt_s)
        for g, a, m in rows:
            if m is None:
                v.update(g, a)
            else:
                v.update(g, a, m)
        return n_update

    def ours_blocks() -> int:
        f = DefaultFilter(use_mag=use_mag)
        for g, a, m in packets:
            f.update_block(g, a, m, dt_s)
        return n_blocks

    def vqf_blocks() -> int:
        v = VQF(dt_s)
        for g, a, m in packets:
            v.updateBatch(g, a, m)
        return n_blocks

    def ours_whole() -> int:
        DefaultFilter(use_mag=use_mag).run(gyr, acc, mag, dt_s)
        return int(gyr.shape[0])

    def vqf_whole() -> int:
        VQF(dt_s).updateBatch(gyr, acc, mag)
        return int(gyr.shape[0])

    cases = {"per sample: update()": (ours_sample, vqf_sample),
             "10-sample packets: update_block() / updateBatch()": (ours_blocks, vqf_blocks),
             "whole trial: run() / updateBatch()": (ours_whole, vqf_whole)}
    out: dict[str, Pair] = {}
    for name, (ours, vqf) in cases.items():
        ours()  # warm-up: numba compile / cache load excluded
        vqf()
        out[name] = (best_rate(ours, repeats), best_rate(vqf, repeats))
    return out


def bench_batch(gyr: FloatArray, acc: FloatArray, mag: FloatArray, dt_s: float, n_dev: int, rounds: int,
                repeats: int) -> Pair:
    """Aggregate samples/s with 10-sample rounds, half the devices 9D, half 6D: one `DefaultFilterBatch.step` per
    round, against one VQF object per device fed the same 10 samples by `updateBatch` each round."""
    from vqf import VQF

    block = 10
    batch = DefaultFilterBatch()
    for i in range(n_dev):
        batch.add(f"d{i}", dt_s=dt_s, use_mag=i % 2 == 0, acc_m_s2=acc[0], mag_uT=mag[0])
    n = gyr.shape[0] - block
    offsets = (np.arange(n_dev) * 997) % n  # each device replays the trial from its own point
    idx = (offsets[:, None] + np.arange(rounds * block)[None, :]) % gyr.shape[0]
    g, a, m = gyr[idx], acc[idx], mag[idx]
    batch.step(g[:, :block], a[:, :block], m[:, :block])  # warm-up
    vqfs = [VQF(dt_s) for _ in range(n_dev)]
    # per device and round, contiguous (10, 3) arrays, prepared outside the timed loop as for the batch
    per_dev = [[(np.ascontiguousarray(g[d, r * block : (r + 1) * block]),
                 np.ascontiguousarray(a[d, r * block : (r + 1) * block]),
                 np.ascontiguousarray(m[d, r * block : (r + 1) * block]) if d % 2 == 0 else None)
                for r in range(rounds)] for d in range(n_dev)]

    def ours() -> int:
        for r in range(rounds):
            s = np.s_[:, r * block : (r + 1) * block]
            batch.step(g[s], a[s], m[s])
        return n_dev * rounds * block

    def vqf() -> int:
        for r in range(rounds):
            for v, dev_rows in zip(vqfs, per_dev, strict=True):
                gg, aa, mm = dev_rows[r]
                v.updateBatch(gg, aa, mm)
        return n_dev * rounds * block

    vqf()  # warm-up
    return best_rate(ours, repeats), best_rate(vqf, repeats)


def main(data_dir: Path, trial: str, repeats: int, n_update: int, devices: list[int], batch_samples: int) -> None:
    gyr, acc, mag, dt_s, label = load_data(data_dir, trial)
    print(f"data: {label}, dt = {dt_s * 1e3:.3f} ms; best of {repeats}; JIT compile excluded (warm-up first)")
    rows: list[tuple[str, Pair]] = []
    for mode, m in (("9D", mag), ("6D", None)):
        res = bench_single(gyr, acc, m, dt_s, repeats, n_update)
        rows += [(f"{mode} {k}", v) for k, v in res.items()]
    for n_dev in tqdm(devices, desc="batched step", unit="config"):
        rounds = max(2, batch_samples // (10 * n_dev))
        rows.append((f"{n_dev} devices, 10-sample rounds, half 9D",
                     bench_batch(gyr, acc, mag, dt_s, n_dev, rounds, repeats)))
    print(f"\n{'case (same samples for both)':54s} {'ours/s':>11s} {'VQF/s':>11s} {'ours/CPU-s':>11s} "
          f"{'VQF/CPU-s':>11s} {'ratio CPU':>9s}")
    for name, ((wall, cpu), (v_wall, v_cpu)) in rows:
        print(f"{name:54s} {wall:11,.0f} {v_wall:11,.0f} {cpu:11,.0f} {v_cpu:11,.0f} {cpu / v_cpu:8.2f}x")


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
