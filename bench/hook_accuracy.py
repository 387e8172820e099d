"""Hook swing accuracy: the pendulum-aware hook filter vs VQF and the project's generic filters, on seeded sims.

    python -m bench.hook_accuracy --help
    python -m bench.hook_accuracy                       # 4 scenarios x 3 seeds, 6D, plot in bench-output/
    python -m bench.hook_accuracy --mag --seeds 1       # 9D (magnetometer with hard/soft iron errors)

Every run: devices.hook_physics (l = 10 m by default) through devices.common.SensorModel (MPU-6050/HMC5883L
errors: ~1 °/s gyro bias, 1 % scale, 20 mg accelerometer bias...), hook hanging still for the first 2 s (the
filters initialise from the first 0.5 s, the hook filter through `HookFilter.start` as gateway.pipeline does),
then the scenario. Every estimate goes through the same
gateway.fusion.hook functions. Figures, over the scored window (from `--settle` s after the excitation ends):

- swing RMSE / max: |Θ_est - Θ_true| in degrees;
- dir RMSE: displacement-bearing error in degrees where Θ_true > 1° (6D: relative to the start heading);
- torsion RMSE: twist about the rope vs the truth, degrees (6D: relative to the start heading).

Scenarios: free (a 2 s trolley jerk sets an ~8° swing, then free), trolley (a 6 m start-cruise-stop move),
wind (gusts 0.3 m/s² std + 0.2 m/s² steady on a 5° swing), twist (60° initial twist, strong torque gusts).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from devices.common import EARTH_FIELD_ENU_UT, G_M_S2, ImuErrorModel, SensorModel
from devices.hook_physics import HookPhysicsSettings, HookScenario, HookTruth, TrolleyMove, simulate, trolley_traverse
from gateway.fusion import hook
from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

REST_S = 2.0
RATE_HZ = 100.0


@dataclass(frozen=True)
class Case:
    name: str
    scenario: HookScenario
    excitation_end_s: float


def scenarios(duration_s: float, seed: int) -> list[Case]:
    """The four scenarios for one seed (the seed also drives wind and sensor errors)."""
    a = 1.6
    kick = (TrolleyMove(REST_S, 1.0, (a * math.cos(0.7), a * math.sin(0.7))),
            TrolleyMove(REST_S + 1.0, 1.0, (-a * math.cos(0.7), -a * math.sin(0.7))))
    traverse = trolley_traverse(REST_S, 6.0, 1.2)
    base = HookScenario(duration_s=duration_s, output_rate_hz=RATE_HZ, wind_torque_std_n_m=2.0, seed=seed)
    return [
        Case("free", HookScenario(**{**base.__dict__, "trolley_moves": kick}), REST_S + 2.0),
        Case("trolley", HookScenario(**{**base.__dict__, "trolley_moves": traverse}),
             traverse[-1].start_s + traverse[-1].duration_s),
        Case("wind", HookScenario(**{**base.__dict__, "trolley_moves": kick[:1] + (
            TrolleyMove(REST_S + 1.0, 0.6, kick[1].acc_m_s2),), "wind_std_m_s2": 0.3, "wind_mean_m_s2": (0.2, 0.0)}),
             REST_S + 2.0),
        Case("twist", HookScenario(**{**base.__dict__, "trolley_moves": kick, "initial_torsion_rad": math.radians(60),
                                      "wind_torque_std_n_m": 15.0}), REST_S + 2.0),
    ]  # fmt: skip


def estimate(name: str, gyr, acc, mag, rope_length_m: float) -> np.ndarray | None:
    """Quaternions (N, 4) of one filter, or None when it is not available."""
    rest = slice(0, int(0.5 * RATE_HZ))
    if name == "vqf":
        from vqf import offlineVQF

        out = offlineVQF(np.ascontiguousarray(gyr), np.ascontiguousarray(acc),
                         None if mag is None else np.ascontiguousarray(mag), 1.0 / RATE_HZ)
        return np.asarray(out["quat6D" if mag is None else "quat9D"])
    if name == "hook":  # started as gateway.pipeline starts it (HookFilter.start on the warm-up window)
        f = HookFilter(HookFilterSettings(rope_length_m=rope_length_m, rope_length_known=True), use_mag=mag is not None)
        f.start(gyr[rest], acc[rest], None if mag is None else mag[rest], 1.0 / RATE_HZ)
        return np.asarray(f.run(gyr, acc, mag, 1.0 / RATE_HZ))
    else:
        from gateway.fusion.registry import make_filter

        try:
            f = make_filter(name, use_mag=mag is not None)  # type: ignore[assignment]
        except (KeyError, ImportError):
            return None
    f.initialise(acc[rest].mean(axis=0), None if mag is None else mag[rest].mean(axis=0))
    return np.asarray(f.run(gyr, acc, mag, 1.0 / RATE_HZ))


def wrap_deg(a: np.ndarray) -> np.ndarray:
    return np.degrees(np.remainder(a + np.pi, 2 * np.pi) - np.pi)


def score(q: np.ndarray, truth: HookTruth, scored: np.ndarray) -> dict[str, float]:
    err = np.degrees(hook.swing_angle(q) - truth.swing_rad)[scored]
    swinging = scored & (truth.swing_rad > math.radians(1.0))
    dir_err = wrap_deg(hook.displacement_bearing(q) - truth.swing_bearing_rad)[swinging]
    tor_err = wrap_deg(hook.torsion(q, 0.0) - truth.torsion_rad)[scored]
    return {
        "swing_rmse": float(np.sqrt(np.mean(err**2))), "swing_max": float(np.max(np.abs(err))),
        "dir_rmse": float(np.sqrt(np.mean(dir_err**2))) if dir_err.size else float("nan"),
        "torsion_rmse": float(np.sqrt(np.mean(tor_err**2))),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_accuracy", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, default=3, help="seeds per scenario (default: 3)")
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds per run (default: 60)")
    p.add_argument("--settle", type=float, default=12.0, help="score from this long after the excitation, s")
    p.add_argument("--rope-length", type=float, default=10.0, help="rope length, m (default: 10)")
    p.add_argument("--mag", action="store_true", help="9D: use the magnetometer")
    p.add_argument("--filters", default="hook,vqf,default,ekf", help="comma list (default: hook,vqf,default,ekf)")
    p.add_argument("--scenarios", default="free,trolley,wind,twist", help="comma list of scenarios")
    p.add_argument("--plot", default="bench-output/hook_accuracy.png", help="PNG of Θ truth vs estimates ('' = none)")
    args = p.parse_args(argv)

    physics = HookPhysicsSettings(rope_length_m=args.rope_length, gravity_m_s2=G_M_S2,
                                  earth_field_uT=EARTH_FIELD_ENU_UT, swing_damping_1_s=0.002)
    filters = args.filters.split(",")
    wanted = args.scenarios.split(",")
    results: dict[tuple[str, str], list[dict[str, float]]] = {}
    plots: dict[str, tuple[HookTruth, dict[str, np.ndarray]]] = {}
    runtime_s: dict[str, float] = {}
    jobs = [(seed, case) for seed in range(1, args.seeds + 1)
            for case in scenarios(args.duration, seed) if case.name in wanted]
    timed_samples = 0.0
    for job, (seed, case) in enumerate(tqdm(jobs, desc="hook runs", unit="run")):
        truth = simulate(physics, case.scenario)
        sensor = SensorModel(ImuErrorModel(), 1, np.random.default_rng(1000 + seed))
        gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, 1.0 / RATE_HZ)
        scored = truth.t_s >= case.excitation_end_s + args.settle
        estimates = {}
        for name in filters:
            t0 = time.perf_counter()
            q = estimate(name, gyr, acc, mag if args.mag else None, args.rope_length)
            if job > 0:  # the first run includes numba compilation
                runtime_s[name] = runtime_s.get(name, 0.0) + time.perf_counter() - t0
            if q is None:
                continue
            estimates[name] = q
            results.setdefault((case.name, name), []).append(score(q, truth, scored))
        if seed == 1:
            plots[case.name] = (truth, estimates)
        if job > 0:
            timed_samples += len(truth.t_s)

    mode = "9D" if args.mag else "6D"
    print(f"hook accuracy, {mode}, l = {args.rope_length:g} m, {args.seeds} seed(s), {args.duration:g} s runs, "
          f"scored from {args.settle:g} s after the excitation; mean over seeds (worst seed for max)")
    print(f"{'scenario':<9}{'filter':<9}{'swing RMSE°':>12}{'swing max°':>11}{'dir RMSE°':>10}{'torsion RMSE°':>14}")
    for (case_name, name), rows in results.items():
        mean = {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]}
        worst = max(r["swing_max"] for r in rows)
        print(f"{case_name:<9}{name:<9}{mean['swing_rmse']:>12.3f}{worst:>11.3f}{mean['dir_rmse']:>10.2f}"
              f"{mean['torsion_rmse']:>14.2f}")
    for name, t in runtime_s.items():
        if name in {k[1] for k in results}:
            print(f"throughput {name}: {timed_samples / t:,.0f} samples/s (one device, after the first run)")
    if args.plot and plots:
        _plot(plots, Path(args.plot), mode)
        print(f"plot: {args.plot}")
    return 0


def _plot(plots: dict[str, tuple[HookTruth, dict[str, np.ndarray]]], path: Path, mode: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(plots), 1, figsize=(11, 2.6 * len(plots)), sharex=True, squeeze=False)
    for ax, (case_name, (truth, estimates)) in zip(axes[:, 0], plots.items(), strict=True):
        ax.plot(truth.t_s, np.degrees(truth.swing_rad), "k", lw=2.0, label="truth")
        for name, q in estimates.items():
            ax.plot(truth.t_s, np.degrees(hook.swing_angle(q)), lw=0.9, label=name)
        ax.set_ylabel("Θ, deg")
        ax.set_title(f"{case_name} ({mode}, seed 1)", fontsize=9)
        ax.legend(loc="upper right", fontsize=7, ncol=5)
    axes[-1, 0].set_xlabel("t, s")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
