"""What a hook packet costs when packets before it were lost: `HookFilter.run` against `run_bridged`, per call.

    python -m bench.hook_bridge_cost                         # suite seeds 3 8 12, 120 s, 30 % lost after 60 s
    python -m bench.hook_bridge_cost --seeds 1-10 --drop 0.5

A gateway that falls behind drops packets from its full inbox, and each device's next packet then comes with a gap
that `FusionBank` bridges (`gateway.fusion.gaps`): the hook filter coasts across it on its model (`run_bridged`).
Load is shed only if such a call costs less than the packets it replaces. This replays one suite crane at a time
(`bench.hook_suite`, rope told, calibrated board, 9D) in 10-sample packets through one `HookFilter`, drops each
packet after `--after-s` with probability `--drop` (seeded), bridges as the bank does, and times every call after an
untimed replay has loaded the code (numba's first call of each array layout loads it): the whole call, and the
kernel (`ekf_run`) inside it; the rest is Python. It prints per seed and pooled: calls, µs a call (kernel + Python),
and the CPU per packet *offered*, which a call that sheds its lost packets' work makes lower than lossless.
"""

from __future__ import annotations

import argparse
import copy
import time
from typing import Any

import numpy as np

from bench.hook_suite import parse_seeds, simulate_seed
from gateway.fusion import hook_filter
from gateway.fusion.gaps import GAP_FACTOR, bridge_block, coast_mask
from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

DT_S = 0.01
SPP = 10


class _KernelClock:
    """Wraps the hook filter's kernels (`hook_filter.ekf_run` and `ekf_run_led`) to sum the time spent in them."""

    NAMES = ("ekf_run", "ekf_run_led")

    def __init__(self) -> None:
        self.s = 0.0
        self._orig = {name: getattr(hook_filter, name) for name in self.NAMES if hasattr(hook_filter, name)}

    def __enter__(self) -> _KernelClock:
        for name, orig in self._orig.items():
            setattr(hook_filter, name, self._timed(orig))
        return self

    def _timed(self, orig: Any) -> Any:
        def timed(*args: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return orig(*args)
            finally:
                self.s += time.perf_counter() - t0

        return timed

    def __exit__(self, *exc: object) -> None:
        for name, orig in self._orig.items():
            setattr(hook_filter, name, orig)


def replay(seed: int, duration_s: float, drop: float, after_s: float) -> dict[str, list[float]]:
    """Per call kind ("run", "bridged"): [calls, whole s, kernel s] after `after_s`, and "offered":
    [packets offered after `after_s`, their whole s]."""
    case, _, gyr, acc, mag = simulate_seed(seed, duration_s, "calibrated", True)
    assert mag is not None
    t = np.arange(gyr.shape[0]) * DT_S
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True), use_mag=True)
    warm = int(0.5 / DT_S)
    f.start(gyr[:warm], acc[:warm], mag[:warm], DT_S)
    rng = np.random.default_rng(seed)
    prev = (gyr[warm - SPP:warm], acc[warm - SPP:warm], mag[warm - SPP:warm], t[warm - SPP:warm])
    tol = np.full(SPP, (GAP_FACTOR - 1.0) * DT_S)
    out: dict[str, list[float]] = {"run": [0, 0.0, 0.0], "bridged": [0, 0.0, 0.0], "offered": [0, 0.0]}
    first = int(after_s / DT_S)
    # compiled before the clock wraps the kernels: `ekf_run` compiled with `ekf_run_led` wrapped sees a Python
    # function there and fails to type (a cold numba cache, e.g. a fresh worktree without `--prepare`)
    copy.deepcopy(f).run_with_length(gyr[warm:warm + SPP], acc[warm:warm + SPP], mag[warm:warm + SPP], DT_S)
    with _KernelClock() as kernel:
        for a in range(warm, gyr.shape[0] - SPP + 1, SPP):
            b = a + SPP
            timed = a >= first
            if timed:
                out["offered"][0] += 1
            if timed and rng.random() < drop:
                continue
            block = (gyr[a:b], acc[a:b], mag[a:b], t[a:b])
            k0, t0 = kernel.s, time.perf_counter()
            bridged = bridge_block(*block, DT_S, prev, tol_s=tol)
            if bridged is None:
                f.run(block[0], block[1], block[2], DT_S)
                kind = "run"
            else:
                g2, a2, m2, keep = bridged
                f.run_bridged(g2, a2, m2, DT_S, coast_mask(g2.shape[0], keep, 1))
                kind = "bridged"
            whole = time.perf_counter() - t0
            prev = block
            if timed:
                out["offered"][1] += whole
                row = out[kind]
                row[0] += 1
                row[1] += whole
                row[2] += kernel.s - k0
    return out


def _line(name: str, r: dict[str, list[float]]) -> str:
    parts = [f"{name:>8}"]
    for kind in ("run", "bridged"):
        n, whole, kern = r[kind]
        parts.append(f"{kind} {int(n):5d} calls {1e6 * whole / max(n, 1):7.1f} µs ({1e6 * kern / max(n, 1):6.1f} "
                     f"kernel + {1e6 * (whole - kern) / max(n, 1):6.1f} Python)")  # fmt: skip
    offered, spent = r["offered"]
    parts.append(f"{1e6 * spent / max(offered, 1):7.1f} µs per packet offered")
    return "  ".join(parts)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_bridge_cost", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--seeds", default="3,8,12", help="suite seeds, e.g. 1-10 or 3,8,12 (default 3,8,12)")
    p.add_argument("--duration", type=float, default=120.0, help="seconds per crane (default 120)")
    p.add_argument("--drop", type=float, default=0.3, help="share of packets lost after --after-s (default 0.3)")
    p.add_argument("--after-s", type=float, default=60.0, help="packets are lost (and timed) from here (default 60: "
                   "after the compass twin's first minute)")  # fmt: skip
    args = p.parse_args(argv)
    pooled: dict[str, list[float]] = {"run": [0, 0.0, 0.0], "bridged": [0, 0.0, 0.0], "offered": [0, 0.0]}
    print(f"hook filter calls, 10-sample packets at 100 Hz, {args.drop:.0%} lost at random after {args.after_s:g} s "
          f"(lossless beside it), {args.duration:g} s per crane")  # fmt: skip
    seeds = parse_seeds(args.seeds)
    replay(seeds[0], 120.0, 0.5, 5.0)  # untimed: numba loads the code of every path and array layout the calls meet
    # (the compass twin's, which runs for the first minute or so of swinging, and the steady state's after it)
    for seed in seeds:
        for drop in (0.0, args.drop):
            r = replay(seed, args.duration, drop, args.after_s)
            print(_line(f"{seed} {drop:.0%}", r), flush=True)
            if drop > 0.0:
                for k, row in r.items():
                    pooled[k] = [x + y for x, y in zip(pooled[k], row, strict=True)]
    print(_line("pooled", pooled))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
