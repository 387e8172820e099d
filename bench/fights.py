"""Seeded fights against the simulated rod (devices.rod_physics) for each reel policy; prints landing statistics.

    python -m bench.fights --help
    python -m bench.fights                      # 100 fights x 3 policies, load cell on
    python -m bench.fights --no-load-cell       # the controller sees attitude and line out only

Every fight: a rod at rest for `--rest` seconds (the gateway learns the rest pitch from noisy attitude), then a
fish of random mass (0.5-6 kg) and stamina (0.3-1) is hooked; the policy is enabled `--detect-delay` later (the
bite alarm). The policy sees only what the gateway would: fused pitch with noise and latency, pitch rate from
the gyro with noise, packet loss, and the reel status at 10 Hz (line out, optionally a noisy load-cell tension).
It never sees the fish or the true tension. All rods of a policy run together in one vectorised `RodBank`.

Outcomes: landed, escaped (line broke or the fish came off; `devices.rod_physics` only breaks lines), or still
fighting at `--horizon`. Tension figures are fractions of the line's breaking strength while the fish is on.
The controller was tuned on seed 7; the default seed 0 (and seed 1) are held out.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np
from tqdm import tqdm

from devices.rod_physics import FISH_STATES, Fight, RodBank, RodSettings
from gateway.control.fish_walking import (
    BangBang,
    DragOnly,
    FishWalkingController,
    FishWalkingSettings,
    Observation,
    ReelPolicy,
)

POLICIES = ("drag_only", "bang_bang", "cascade")
LANDED, ESCAPED = FISH_STATES.index("landed"), FISH_STATES.index("escaped")
HOOKED = {FISH_STATES.index(s) for s in ("hooked", "fighting", "tired")}


@dataclass(frozen=True)
class SensorModel:
    """What reaches the controller: fused-attitude noise and latency, packet loss, reel status rate."""

    pitch_noise_rad: float = math.radians(0.3)
    rate_noise_rad_s: float = 0.03
    latency_s: float = 0.04
    dropout_prob: float = 0.02
    status_period_s: float = 0.1
    load_cell: bool = True
    tension_noise_n: float = 0.5


def controller_settings_for(rod: RodSettings, theta2_load_fraction: float = 0.5) -> FishWalkingSettings:
    """θ2, θ3 and the bend→tension calibration for a rod, as an angler would set them up.

    θ3 = pitch drop at the breaking load, θ2 = drop at `theta2_load_fraction` of it (both from rest), and the
    calibration table is the rod's static bend curve sampled at 24 loads (hanging known weights).
    """
    rest = float(rod.bend_rad(rod.baseline_tension_n))
    loads = np.linspace(rod.baseline_tension_n, rod.breaking_strength_n, 24)
    curve = tuple((float(rod.bend_rad(t)) - rest, float(t)) for t in loads)
    return FishWalkingSettings(
        theta2_rad=float(rod.bend_rad(theta2_load_fraction * rod.breaking_strength_n)) - rest,
        theta3_rad=float(rod.bend_rad(rod.breaking_strength_n)) - rest,
        line_breaking_n=rod.breaking_strength_n,
        max_in_m_s=rod.max_reel_speed_m_s,
        max_out_m_s=rod.max_reel_speed_m_s,
        cruise_in_m_s=rod.max_reel_speed_m_s,
        tension_curve=curve,
    )


def make_policy(name: str, settings: FishWalkingSettings) -> ReelPolicy:
    """A fresh policy instance by name."""
    if name == "drag_only":
        return DragOnly()
    if name == "bang_bang":
        return BangBang(settings.theta2_rad, settings.max_in_m_s, settings.max_out_m_s, settings.landed_line_m)
    if name == "cascade":
        return FishWalkingController(settings)
    raise ValueError(f"unknown policy {name!r}; known: {', '.join(POLICIES)}")


@dataclass(frozen=True)
class FightResult:
    """One fight's outcome; times from the hook-up, tension as a fraction of breaking strength."""

    policy: str
    fight: int
    mass_kg: float
    stamina: float
    outcome: str
    time_s: float
    max_tension_frac: float
    mean_tension_frac: float
    before_enable: bool = False
    """The fight ended (line broke) before the policy was enabled: no policy could have acted."""


def run_fights(
    policy: str,
    n: int,
    seed: int,
    *,
    horizon_s: float = 300.0,
    dt_s: float = 0.02,
    rest_s: float = 2.0,
    detect_delay_s: float = 0.3,
    sensors: SensorModel = SensorModel(),
    rod: RodSettings | None = None,
    controller: FishWalkingSettings | None = None,
    fish: list[tuple[float, float]] | None = None,
    drag_n: float | None = None,
    drag_control: bool = True,
    progress: bool = True,
) -> list[FightResult]:
    """Run `n` seeded fights in parallel with one policy instance per rod; `fish` = [(mass kg, stamina)] overrides
    the random draw (then n = len(fish))."""
    rod = rod or RodSettings()
    fish_rng = np.random.default_rng(seed)
    mass = fish_rng.uniform(0.5, 6.0, n)
    stamina = fish_rng.uniform(0.3, 1.0, n)
    if fish is not None:
        n = len(fish)
        mass, stamina = np.array([f[0] for f in fish]), np.array([f[1] for f in fish])
    bank = RodBank(rod, n, seed=seed + 1)
    if drag_n is not None:
        bank.set_drag(drag_n)
    for i in range(n):
        bank.inject(Fight(t_s=rest_s, mass_kg=float(mass[i]), stamina=float(stamina[i])), i)
    settings = controller or controller_settings_for(rod)
    policies = [make_policy(policy, settings) for _ in range(n)]
    noise = np.random.default_rng(seed + 2)
    lag = max(0, round(sensors.latency_s / dt_s))
    history: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=lag + 1)
    baseline_sum, baseline_n = np.zeros(n), 0
    status_every = max(1, round(sensors.status_period_s / dt_s))
    status_line, status_tension = bank.line_out.copy(), bank.tension.copy()
    cmd = np.zeros(n)
    done_t = np.full(n, np.nan)
    t_max = np.zeros(n)
    t_sum, t_cnt = np.zeros(n), np.zeros(n)
    steps = int(round((rest_s + horizon_s) / dt_s))
    enable_t = rest_s + detect_delay_s
    for k in tqdm(range(steps), desc=policy, disable=not progress, leave=False):
        t = bank.t_s
        e, de, _ = bank.euler()
        pitch = e[:, 1] + noise.normal(0.0, sensors.pitch_noise_rad, n)
        rate = de[:, 1] + noise.normal(0.0, sensors.rate_noise_rad_s, n)
        history.append((t, pitch, rate))
        t_seen, pitch_seen, rate_seen = history[0]
        if t < rest_s:  # the gateway's rest baseline, learnt before the bite
            baseline_sum += pitch_seen
            baseline_n += 1
        if k % status_every == 0:
            status_line = bank.line_out.copy()
            status_tension = bank.tension + noise.normal(0.0, sensors.tension_noise_n, n)
        if t >= enable_t:
            baseline = baseline_sum / max(baseline_n, 1)
            lost = noise.random(n) < sensors.dropout_prob
            for i in range(n):
                obs = None
                if not lost[i]:
                    obs = Observation(
                        attitude_t_s=t_seen,
                        pitch_deviation_rad=float(pitch_seen[i] - baseline[i]),
                        pitch_rate_rad_s=float(rate_seen[i]),
                        tension_n=float(max(status_tension[i], 0.0)) if sensors.load_cell else None,
                        line_out_m=float(status_line[i]),
                    )
                decision = policies[i].step(t, obs)
                cmd[i] = decision.speed_m_s
                if drag_control and decision.drag_n is not None and decision.drag_n != bank.drag[i]:
                    bank.set_drag(decision.drag_n, i)
        bank.step(dt_s, cmd)
        hooked = np.isin(bank.fish, list(HOOKED))
        frac = bank.line_tension / bank.breaking
        t_max = np.where(hooked, np.maximum(t_max, frac), t_max)
        t_sum += np.where(hooked, frac, 0.0)
        t_cnt += hooked
        ended = np.isnan(done_t) & np.isin(bank.fish, [LANDED, ESCAPED])
        done_t[ended] = bank.t_s - rest_s
        if not np.isnan(done_t).any():
            break
    broke_frac = np.where(bank.fish == ESCAPED, np.maximum(t_max, 1.0), t_max)  # the breaking step is zeroed
    return [
        FightResult(
            policy,
            i,
            float(mass[i]),
            float(stamina[i]),
            "landed" if bank.fish[i] == LANDED else "escaped" if bank.fish[i] == ESCAPED else "fighting",
            float(done_t[i]),
            float(broke_frac[i]),
            float(t_sum[i] / max(t_cnt[i], 1)),
            bool(done_t[i] < detect_delay_s),
        )
        for i in range(n)
    ]


def summarise(results: list[FightResult]) -> dict[str, float]:
    """Counts and tension/time statistics of one policy's fights."""
    landed = [r for r in results if r.outcome == "landed"]
    times = np.array([r.time_s for r in landed])
    return {
        "fights": len(results),
        "landed": len(landed),
        "escaped": sum(r.outcome == "escaped" for r in results),
        "escaped_before_enable": sum(r.outcome == "escaped" and r.before_enable for r in results),
        "fighting": sum(r.outcome == "fighting" for r in results),
        "mean_tension_frac": float(np.mean([r.mean_tension_frac for r in results])),
        "max_tension_frac": float(np.max([r.max_tension_frac for r in results])),
        "p95_max_tension_frac": float(np.percentile([r.max_tension_frac for r in results], 95)),
        "land_time_mean_s": float(times.mean()) if times.size else math.nan,
        "land_time_median_s": float(np.median(times)) if times.size else math.nan,
    }


def main(argv: list[str] | None = None) -> int:
    """CLI entry."""
    ap = argparse.ArgumentParser(prog="python -m bench.fights", description=__doc__.split("\n")[0])
    ap.add_argument("--fights", type=int, default=100, help="fights per policy (default 100)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--policies", nargs="+", default=list(POLICIES), choices=POLICIES)
    ap.add_argument("--horizon", type=float, default=300.0, help="max fight time in s (default 300)")
    ap.add_argument("--dt", type=float, default=0.02, help="control/simulation step in s (default 0.02 = 50 Hz)")
    ap.add_argument("--rest", type=float, default=2.0, help="rest time before the hook-up in s")
    ap.add_argument("--detect-delay", type=float, default=0.3, help="hook-up to controller enable in s")
    ap.add_argument("--no-load-cell", action="store_true", help="no measured tension in the reel status")
    ap.add_argument("--latency", type=float, default=0.04, help="attitude latency in s (default 0.04)")
    ap.add_argument(
        "--drag", type=float, default=None, help="reel drag in N for every policy (default: the rod's, 25 N; a drag "
        "at or above the breaking load, e.g. 60, is a locked spool: only then can the line break)"
    )
    ap.add_argument("--no-drag-control", action="store_true", help="the controller may not change the drag")
    ap.add_argument("--json", action="store_true", help="print per-policy summaries as JSON")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    sensors = SensorModel(load_cell=not args.no_load_cell, latency_s=args.latency)
    summaries: dict[str, dict[str, float]] = {}
    for policy in args.policies:
        t0 = time.perf_counter()
        results = run_fights(
            policy,
            args.fights,
            args.seed,
            horizon_s=args.horizon,
            dt_s=args.dt,
            rest_s=args.rest,
            detect_delay_s=args.detect_delay,
            sensors=sensors,
            drag_n=args.drag,
            drag_control=not args.no_drag_control,
            progress=not args.quiet,
        )
        wall = time.perf_counter() - t0
        summaries[policy] = summarise(results) | {"wall_s": wall}
    if args.json:
        print(json.dumps({"sensors": asdict(sensors), "seed": args.seed, "policies": summaries}, indent=1))
        return 0
    print(
        f"{args.fights} seeded fights per policy, seed {args.seed}, load cell {'on' if sensors.load_cell else 'off'}, "
        f"drag {args.drag if args.drag is not None else RodSettings().drag_n} N, "
        f"drag control {'off' if args.no_drag_control else 'on'}, horizon {args.horizon:g} s"
    )
    print("| policy | landed | escaped (line broke or came off) | of which before enable | still fighting "
          "| mean T/Tbreak | p95 max | max T/Tbreak | land time mean (s) | median (s) | wall (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for policy, s in summaries.items():
        print(
            f"| {policy} | {s['landed']} | {s['escaped']} | {s['escaped_before_enable']} | {s['fighting']} "
            f"| {s['mean_tension_frac']:.2f} "
            f"| {s['p95_max_tension_frac']:.2f} | {s['max_tension_frac']:.2f} | {s['land_time_mean_s']:.1f} "
            f"| {s['land_time_median_s']:.1f} | {s['wall_s']:.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
