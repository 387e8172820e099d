"""Throughput of every registered attitude filter: per-sample `update()` (streaming) vs whole-array `run()`.

Figures are samples per second measured in this one run, next to VQF's C++ on the same data, because absolute
numbers on a shared 2-core machine are noisy. JIT compile time is excluded (each filter is run once first).

    python -m bench.filter_speed                       # all registered filters, 9D, BROAD trial 06
    python -m bench.filter_speed --filter kf --filter ekf --mode 6D
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gateway.fusion import broad
from gateway.fusion.registry import FILTERS, make_filter

DEFAULT_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "broad"


def _rate(fn: object, n: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        best = min(best, time.perf_counter() - t0)
    return n / best


def measure(name: str, trial: broad.Trial, mode: broad.Mode, n_update: int, repeats: int) -> tuple[float, float]:
    """(update() samples/s over the first `n_update` samples, run() samples/s over the whole trial)."""
    use_mag = mode == "9D"
    mag = trial.mag_uT if use_mag else None
    acc0, mag0 = broad.rest_means(trial)

    def fresh():  # type: ignore[no-untyped-def]
        f = make_filter(name, use_mag=use_mag)
        f.initialise(acc0, mag0 if use_mag else None)
        return f

    def stream() -> None:
        f = fresh()
        for i in range(n_update):
            f.update(trial.gyr_rad_s[i], trial.acc_m_s2[i], None if mag is None else mag[i], trial.dt_s)

    def batch() -> None:
        fresh().run(trial.gyr_rad_s, trial.acc_m_s2, mag, trial.dt_s)

    # warm-up of both paths (numba compile or cache load is not counted)
    fresh().run(trial.gyr_rad_s[:200], trial.acc_m_s2[:200], None if mag is None else mag[:200], trial.dt_s)
    fresh().update(trial.gyr_rad_s[0], trial.acc_m_s2[0], None if mag is None else mag[0], trial.dt_s)
    return _rate(stream, n_update, repeats), _rate(batch, trial.n, repeats)


def vqf_rate(trial: broad.Trial, mode: broad.Mode, repeats: int) -> float:
    from vqf import VQF

    gyr, acc = np.ascontiguousarray(trial.gyr_rad_s), np.ascontiguousarray(trial.acc_m_s2)
    mag = np.ascontiguousarray(trial.mag_uT) if mode == "9D" else None
    return _rate(lambda: VQF(trial.dt_s).updateBatch(gyr, acc, mag), trial.n, repeats)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.filter_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA, help="BROAD folder (default: ../shared/data/broad)")
    p.add_argument("--trial", default="06_*", help="glob of the trial to use (default: 06_*)")
    p.add_argument("--filter", action="append", dest="filters", help="filter name (repeatable; default: all)")
    p.add_argument("--mode", choices=["6D", "9D"], default="9D")
    p.add_argument("--n-update", type=int, default=3000, help="samples fed one by one to update() (default 3000)")
    p.add_argument("--repeats", type=int, default=3, help="best of this many runs (default 3)")
    a = p.parse_args(argv)
    paths = broad.find_trials(a.data_dir, a.trial + ".mat" if not a.trial.endswith(".mat") else a.trial)
    if not paths:
        p.error(f"no trial matching {a.trial!r} in {a.data_dir}")
    trial = broad.load_trial(paths[0])
    names = a.filters or sorted(FILTERS)
    vqf = vqf_rate(trial, a.mode, a.repeats)
    rows = []
    failed = {}
    for name in tqdm(names, desc="filters", unit="filter"):
        try:
            upd, run = measure(name, trial, a.mode, min(a.n_update, trial.n), a.repeats)
        except Exception as exc:  # a filter that cannot follow this motion (e.g. `hook` off a rope) is reported
            failed[name] = f"{type(exc).__name__}: {exc}"
            continue
        rows.append((name, upd, run))
    print(f"data: {trial.name} ({trial.n} samples, {trial.rate_hz:.1f} Hz), {a.mode}; best of {a.repeats};"
          " compile excluded")
    print(f"{'filter':<14} {'update() samples/s':>19} {'run() samples/s':>16} {'run vs update':>14} {'run vs VQF':>11}")
    for name, upd, run in rows:
        print(f"{name:<14} {upd:>19,.0f} {run:>16,.0f} {run / upd:>13.1f}x {run / vqf:>10.2f}x")
    print(f"{'VQF C++':<14} {'':>19} {vqf:>16,.0f} {'':>14} {1.0:>10.2f}x")
    for name, why in failed.items():
        print(f"{name:<14} failed on this data: {why}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
