"""Where the hook filter's swing-centre error comes from (issue 11, seventh round): its states over time against the
truth, on the crane suite's samples (`bench.hook_suite.simulate_seed`, the rope length told at t = 0).

    python -m bench.hook_centre --seeds 1-30 --duration 120             # per seed: RMS of each part
    python -m bench.hook_centre --seeds 15 --duration 120 --timeline    # around the worst Θ error, every second

The pendulum in the filter swings about `(a_tip - R (f - b))/g` (tip acceleration `a_tip`, measured non-tension
force `f`, accelerometer x/y bias `b`), so the error of that centre is the tip estimate's error plus the x/y bias
estimate's error turned to ENU, over g. Printed in degrees:

- Θ: RMS of Θ_est - Θ_true after the warm-up (as bench.hook_suite);
- centre: the error of the rope direction's horizontal part averaged over one pendulum period (the swing's centre);
- tip: (tip estimate - the true boom-tip acceleration) / g;
- acc bias: (x/y bias estimate - the board's effective x/y bias) turned to ENU, / g; the effective bias is the measured
  minus the true specific force averaged over 2 s (the bias and the cross-axis pick-up of the tension);
- rest: centre - tip - acc bias (what the two states do not account for);
- gyro bias (°/s, `--timeline`): the x/y estimate minus the measured minus the true rate averaged over 2 s (on a
  swinging hook this also holds the gyro's scale error times the swing rate: a rough figure).

The filter runs in packets of `--packet` samples (`run_with_length`, the same numbers as one call) to read its state.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from bench.hook_suite import (
    FAMILIES,
    RATE_HZ,
    WARMUP_S,
    add_suite_version_argument,
    parse_seeds,
    parse_settings,
    simulate_seed,
)
from devices.hook_physics import HookTruth
from gateway.fusion import hook
from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

_SMOOTH_S = 2.0  # averaging window of the board's effective biases


def moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving mean of the columns of `x` (N, k) over `n` samples (shorter at the ends: zero-padded), N rows
    even when `n` > N (a run shorter than a pendulum period)."""
    n = max(1, min(n, x.shape[0]))
    k = np.ones(n) / n
    return np.stack([np.convolve(x[:, j], k, mode="same") for j in range(x.shape[1])], axis=1)


def body_xy_to_enu(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Body x/y vectors `v` (N, 2) turned to ENU x/y by the attitudes `q` (N, 4, wxyz)."""
    qw, qx, qy, qz = q.T
    ex = (1.0 - 2.0 * (qy * qy + qz * qz)) * v[:, 0] + 2.0 * (qx * qy - qw * qz) * v[:, 1]
    ey = 2.0 * (qx * qy + qw * qz) * v[:, 0] + (1.0 - 2.0 * (qx * qx + qz * qz)) * v[:, 1]
    return np.stack([ex, ey], axis=1)


def trace(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None, settings: HookFilterSettings, packet: int
          ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Quaternions (N, 4) and the state after each sample's packet (N, 24), the filter started as the suite starts
    it."""
    f = HookFilter(settings, use_mag=mag is not None)
    dt = 1.0 / RATE_HZ
    n0 = int(WARMUP_S * RATE_HZ)
    f.start(gyr[:n0], acc[:n0], None if mag is None else mag[:n0], dt)
    n = gyr.shape[0]
    q, x = np.zeros((n, 4)), np.zeros((n, f.x.shape[0]))
    for i in range(0, n, packet):
        j = min(n, i + packet)
        q[i:j] = f.run_with_length(gyr[i:j], acc[i:j], None if mag is None else mag[i:j], dt)[0]
        x[i:j] = f.x
    return q, x


def centre_parts(q: np.ndarray, x: np.ndarray, truth: HookTruth, gyr: np.ndarray, acc: np.ndarray, rope_m: float,
                 g: float) -> dict[str, np.ndarray]:  # fmt: skip
    """Per-sample errors in degrees: `theta` (N,), `centre`, `tip`, `acc_bias`, `rest` (N, 2, ENU) and `gyro_bias`
    (N, 2, body, °/s), see the module docstring."""
    period = int(2.0 * math.pi * math.sqrt(rope_m / g) * RATE_HZ)
    smooth = int(_SMOOTH_S * RATE_HZ)
    centre = np.degrees(moving_mean(x[:, 0:2] - truth.rope_dir[:, :2], period))
    tip = np.degrees((x[:, 17:19] - truth.suspension_acc_m_s2[:, :2]) / g)
    acc_bias = np.degrees(body_xy_to_enu(q, x[:, 10:12] - moving_mean(acc[:, :2] - truth.acc_m_s2[:, :2], smooth)) / g)
    return {"theta": np.degrees(hook.swing_angle(q) - truth.swing_rad), "centre": centre, "tip": tip,
            "acc_bias": acc_bias, "rest": centre - tip - acc_bias,
            "gyro_bias": np.degrees(x[:, 6:8] - moving_mean(gyr[:, :2] - truth.gyr_rad_s[:, :2], smooth))}  # fmt: skip


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(a.reshape(a.shape[0], -1) ** 2, axis=1))))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_centre", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--seeds", default="1-12", help="suite seeds, e.g. 1-30 (tuning)")
    p.add_argument("--duration", type=float, default=120.0, help="simulated seconds per seed (default: 120)")
    p.add_argument("--family", default="crane", choices=FAMILIES, help="as bench.hook_suite")
    p.add_argument("--settings", default="", help="HookFilterSettings overrides and presets, as bench.hook_suite")
    p.add_argument("--packet", type=int, default=5, help="samples per filter call (default: 5)")
    p.add_argument("--timeline", action="store_true", help="print every second from 8 s before the worst Θ error")
    add_suite_version_argument(p)
    args = p.parse_args(argv)
    overrides = parse_settings(args.settings)
    print(f"{'seed':>4} {'Θ':>6} {'centre':>7} {'tip':>6} {'acc bias':>9} {'rest':>6}   (RMS, degrees)")
    parts = ("theta", "centre", "tip", "acc_bias", "rest")
    rows: list[list[float]] = []
    for seed in parse_seeds(args.seeds):
        case, truth, gyr, acc, mag = simulate_seed(seed, args.duration, "calibrated", True, args.family,
                                                  suite_version=args.suite_version)
        s = HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True, **overrides)
        q, x = trace(gyr, acc, mag, s, args.packet)
        e = centre_parts(q, x, truth, gyr, acc, case.physics.rope_length_m, s.gravity_m_s2)
        keep = truth.t_s >= WARMUP_S
        rows.append([_rms(e[k][keep]) for k in parts])
        print(f"{seed:>4} " + " ".join(f"{v:{w}.3f}" for v, w in zip(rows[-1], (6, 7, 6, 9, 6), strict=True)))
        if args.timeline:
            worst = int(np.argmax(np.abs(e["theta"]) * keep))
            print(f"     {case.describe()}; events {[(k, round(a, 1), round(b, 1)) for k, a, b in case.events]}")
            print(f"{'t s':>7} {'Θ err':>6} {'centre x, y':>13} {'tip x, y':>13} {'acc bias x, y':>14} "
                  f"{'tip est m/s²':>14} {'tip true':>14} {'gyro bias °/s':>14}")
            for k in range(max(0, worst - 8 * int(RATE_HZ)), min(len(q), worst + 25 * int(RATE_HZ)), int(RATE_HZ)):
                a = truth.suspension_acc_m_s2[k]
                c, t, b, gb = e["centre"][k], e["tip"][k], e["acc_bias"][k], e["gyro_bias"][k]
                print(f"{truth.t_s[k]:7.1f} {e['theta'][k]:6.2f} {c[0]:6.2f}{c[1]:7.2f} {t[0]:6.2f}{t[1]:7.2f} "
                      f"{b[0]:6.2f}{b[1]:8.2f} {x[k, 17]:7.3f}{x[k, 18]:7.3f} {a[0]:7.3f}{a[1]:7.3f} "
                      f"{gb[0]:7.3f}{gb[1]:7.3f}")
    print("mean " + " ".join(f"{v:{w}.3f}" for v, w in zip(np.mean(rows, axis=0), (6, 7, 6, 9, 6), strict=True)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
