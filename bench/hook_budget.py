"""Error budget of the hook filter on the crane suite: give it the truth of one thing at a time (an oracle) and see
how much of the swing-angle error goes.

    python -m bench.hook_budget --seeds 1-12 --duration 120 --imu ideal
    python -m bench.hook_budget --seeds 1-12 --oracles base,tip,all --per-seed

Oracles (each on the suite's own samples, `bench.hook_suite.simulate_seed`, so the draws are the suite's):

- `base`: the filter as the suite runs it (`--settings` overrides apply to every oracle);
- `rope`: the true rope length, its rate and acceleration, written into the state after every sample (their
  covariance rows zeroed, so nothing else is corrected through them);
- `tip`: the true boom-tip horizontal acceleration (trolley, slewing), written in the same way;
- `lever`: the IMU's true offset from the rope axis, as the settings' lever arm with a 1 µm prior (x, y and z);
- `init`: the true swing, swing rate, heading and twist rate at the start (tight priors) and the true earth field
  as the magnetometer reference; `swing0`: the swing and its rate only, `heading0`: the heading, twist rate and field;
- `bias`: every sensor-error state pinned at 0 (gyro bias, tension offset, accelerometer x/y bias, cross-axis,
  hard iron): only meaningful with `--imu ideal`;
  `gbias`, `offset`, `accxy`, `cross`, `hard`: one group of them only;
- `all`: all of the above together (what is left is the model, its numerics and the process noise's pull);
- `a+b`: oracles `a` and `b` together.

Pinning runs the filter one sample per call (about 3x slower than the batch run); a jump rollback re-runs up to
0.3 s without the pins. Figures: mean over seeds of the per-seed Θ RMSE (degrees) whole run / free / pull / move,
worst max, direction and torsion RMSE, as `bench.hook_suite` prints them.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.hook_suite import (
    FAMILIES,
    PHASES,
    RATE_HZ,
    WARMUP_S,
    SuiteCase,
    add_suite_version_argument,
    parse_seeds,
    parse_settings,
    rope_errors,
    score_phases,
    simulate_seed,
)
from devices.common import EARTH_FIELD_ENU_UT
from devices.hook_physics import HookTruth
from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

ORACLES = ("base", "rope", "tip", "lever", "init", "bias", "all")
# `bias` split by sensor-error state, to pin one group at a time
BIAS_PARTS = {"gbias": [6, 7, 8], "offset": [9], "accxy": [10, 11], "cross": [12, 13], "hard": [21, 22, 23]}
_SENSOR_STATES = [i for idx in BIAS_PARTS.values() for i in idx]
Pins = list[tuple[list[int], np.ndarray]]


def _pin(f: HookFilter, idx: list[int], values: np.ndarray) -> None:
    f.x[idx] = values
    f.P[idx, :] = 0.0
    f.P[:, idx] = 0.0
    f.P[idx, idx] = 1e-14


def _backdate(a: np.ndarray) -> np.ndarray:
    """A truth series' value one sample before its first (linear extrapolation): the filter predicts into sample 0."""
    return np.asarray(2.0 * a[0] - a[1])


def oracle_run(oracle: str, case: SuiteCase, truth: HookTruth, gyr: np.ndarray, acc: np.ndarray,
               mag: np.ndarray | None, extra: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The hook filter's quaternions (N, 4) and rope lengths (N,) with `oracle`'s truths given to it."""
    parts = set(ORACLES[1:-1]) if oracle == "all" else set(oracle.split("+")) - {"base"}
    kw: dict[str, object] = dict(extra)
    if "lever" in parts:
        kw.update(lever_arm_m=tuple(float(v) for v in case.physics.lever_arm_m), lever_std_m=1e-6)
    settings = HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True,
                                  **kw)  # type: ignore[arg-type]  # fmt: skip
    f = HookFilter(settings, use_mag=mag is not None)
    n0, dt = int(WARMUP_S * RATE_HZ), 1.0 / RATE_HZ
    f.start(gyr[:n0], acc[:n0], None if mag is None else mag[:n0], dt)
    pins: Pins = []
    if "rope" in parts:
        e = truth.extra
        pins.append(([14, 15, 16], np.stack([np.log(e["rope_length_m"]), e["rope_rate_m_s"],
                                              np.gradient(e["rope_rate_m_s"], dt)], axis=1)))  # fmt: skip
    if "tip" in parts:
        pins.append(([17, 18], truth.suspension_acc_m_s2[:, :2]))
    if "bias" in parts:
        f.acc_z_offset_m_s2 = 0.0
        pins.append((_SENSOR_STATES, np.zeros((truth.t_s.shape[0], len(_SENSOR_STATES)))))
    for name, idx in BIAS_PARTS.items():
        if name in parts and "bias" not in parts:
            if name == "offset":
                f.acc_z_offset_m_s2 = 0.0
            pins.append((idx, np.zeros((truth.t_s.shape[0], len(idx)))))
    if parts & {"init", "swing0"}:
        x0 = np.concatenate([_backdate(truth.rope_dir[:, :2]), _backdate(truth.rope_rate_1_s[:, :2])])
        _pin(f, [0, 1, 2, 3], x0)
        for i in range(4):
            f.P[i, i] = 1e-10
    if parts & {"init", "heading0"}:
        _pin(f, [4, 5], np.array([_backdate(truth.torsion_rad), _backdate(truth.extra["torsion_rate_rad_s"])]))
        for i in (4, 5):
            f.P[i, i] = 1e-10
        if mag is not None:
            f.mag_ref_uT = np.asarray(EARTH_FIELD_ENU_UT, dtype=np.float64)
    for idx, val in pins:
        _pin(f, idx, _backdate(val))
    if not pins:
        q, length = f.run_with_length(gyr, acc, mag, dt)
        return np.asarray(q), np.asarray(length)
    n = gyr.shape[0]
    q, length = np.empty((n, 4)), np.empty(n)
    for i in range(n):
        qi, li = f.run_with_length(gyr[i : i + 1], acc[i : i + 1], None if mag is None else mag[i : i + 1], dt)
        q[i], length[i] = qi[0], li[0]
        for idx, val in pins:
            _pin(f, idx, val[i])
    return q, length


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_budget", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--seeds", default="1-12")
    p.add_argument("--duration", type=float, default=120.0)
    p.add_argument("--imu", default="ideal", help="IMU error preset (default: ideal)")
    p.add_argument("--6d", dest="six_d", action="store_true", help="no magnetometer")
    p.add_argument("--family", default="crane", choices=FAMILIES)
    p.add_argument("--oracles", default=",".join(ORACLES), help=f"comma list of {', '.join(ORACLES)}")
    p.add_argument("--settings", default="",
                   help="settings overrides for every oracle: a=1,b=2 and/or presets tracking, steady")  # fmt: skip
    p.add_argument("--per-seed", action="store_true", help="also print each seed's whole-run Θ RMSE per oracle")
    add_suite_version_argument(p)
    args = p.parse_args(argv)
    seeds, oracles = parse_seeds(args.seeds), [o.strip() for o in args.oracles.split(",")]
    unknown = {p for o in oracles for p in o.split("+")} - set(ORACLES) - set(BIAS_PARTS) - {"swing0", "heading0"}
    if unknown:
        raise SystemExit(f"unknown oracle(s): {', '.join(sorted(unknown))}")
    extra = parse_settings(args.settings)
    print(f"hook error budget (suite v{args.suite_version}, {args.family}), {'6D' if args.six_d else '9D'}, "
          f"IMU {args.imu}, {args.duration:g} s, seeds {args.seeds}, settings {extra or 'default'}; Θ RMSE in degrees, "
          "mean over seeds")
    rows: dict[str, list[dict[str, dict[str, float]]]] = {o: [] for o in oracles}
    t0 = time.perf_counter()
    for seed in seeds:
        case, truth, gyr, acc, mag = simulate_seed(seed, args.duration, args.imu, not args.six_d, args.family,
                                                  suite_version=args.suite_version)
        line = []
        for o in oracles:
            q, length = oracle_run(o, case, truth, gyr, acc, mag, extra)
            r = score_phases(q, truth, case, mag is not None)
            r["all"].update(rope_errors(length, truth))
            rows[o].append(r)
            line.append(f"{o} {r['all']['swing_rmse']:.3f}")
        if args.per_seed:
            print(f"  seed {seed:>3} {case.describe():<48} " + "  ".join(line), flush=True)
    head = "".join(f"{ph:>8}" for ph in ("all", *PHASES))
    print(f"{'oracle':<8}{head}{'max':>7}{'dir':>7}{'tors':>7}{'rope %':>8}")
    for o in oracles:
        means = [float(np.mean([r[ph]["swing_rmse"] for r in rows[o] if r.get(ph)])) for ph in ("all", *PHASES)]
        worst = max(r["all"]["swing_max"] for r in rows[o])
        d = float(np.nanmean([r["all"]["dir_rmse"] for r in rows[o]]))
        tors = float(np.mean([r["all"]["torsion_rmse"] for r in rows[o]]))
        rope = 100.0 * float(np.mean([r["all"]["rope_rel"] for r in rows[o]]))
        print(f"{o:<8}" + "".join(f"{m:8.3f}" for m in means) + f"{worst:7.2f}{d:7.2f}{tors:7.2f}{rope:8.1f}")
    print(f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
