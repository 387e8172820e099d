"""Lost packets: the gateway's fusion on a lossy link, gaps bridged (`gateway.fusion.gaps`) against back to back.

    python -m bench.link_loss                               # hooks: suite seeds 501-510 (120 s); rods: BROAD's trials
    python -m bench.link_loss --loss 0.05 --burst 3         # 5 % of packets lost, in bursts of 3 on average
    python -m bench.link_loss --kinds hook --seeds 901-910 --duration 180

Each device's samples are cut into packets of `--spp` samples (sample-exact `t0_us`, as a device sends them), a
Gilbert-Elliott link (`devices.common.LinkSim`: long-run loss `--loss`, mean burst `--burst` packets, its own seed
per device) drops some, and the rest go one packet a batch through `FusionBank.fuse` of a real `Pipeline` (the
gateway's fusion stage: warm-up, filter start, calibration, the hook's rope length set as a user sets it). Three
runs per device on the same packets: every packet (`lossless`), the lossy stream fed back to back (`max_bridge_s`
0: the gateway before the bridge), and bridged (each kind's default: the hook's coasting, the rod's tapered gyro,
`RodKind.bridge_gyro_taper_s`). Scored on the samples that arrived, after the 0.5 s warm-up:

- hooks (`bench.hook_suite`'s cranes, calibrated IMU, 9D, rope length told): swing angle Θ RMSE / max, degrees;
- rods (BROAD's real recordings with optical truth, `../shared/data/broad`, 9D, the default filter): total
  attitude error RMSE in the movement phases, degrees (`gateway.fusion.broad.score`).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from bench.hook_suite import add_suite_version_argument, parse_seeds
from gateway import schemas
from gateway.config import DeviceSettings
from gateway.kinds.base import Output
from gateway.pipeline import Pipeline

ROOT = Path(__file__).resolve().parent.parent
BROAD_DIR = ROOT.parent / "shared" / "data" / "broad"
WARMUP_S = 0.5
MODES = ("lossless", "back to back", "bridged")


def packets(device_id: str, kind: str, gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None, rate_hz: float,
            spp: int) -> list[schemas.ImuPacket]:  # fmt: skip
    """The samples as the device's packets of `spp` samples, seq from 0, t0_us on the sample clock."""
    out = []
    for seq, a in enumerate(range(0, gyr.shape[0] - spp + 1, spp)):
        b = a + spp
        out.append(schemas.ImuPacket(
            v=1, device_id=device_id, kind=kind, boot_id=1, seq=seq, t0_us=round(a * 1e6 / rate_hz), rate_hz=rate_hz,
            gyr_rad_s=[tuple(r) for r in gyr[a:b].tolist()], acc_m_s2=[tuple(r) for r in acc[a:b].tolist()],
            mag_uT=None if mag is None else [tuple(r) for r in mag[a:b].tolist()],
        ))  # fmt: skip
    return out


def lost_packets(n: int, loss: float, burst: float, seed: int) -> np.ndarray:
    """(n,) bool: which of n packets the link drops (never the first second's, so every run starts alike)."""
    from devices.common import LinkModel, LinkSim

    link = LinkSim(LinkModel(loss, burst), 1, np.random.default_rng(seed))
    lost = np.array([bool(link.lost()[0]) for _ in range(n)])
    lost[: max(1, n // 100)] = False
    return lost


def fused_quats(pkts: list[schemas.ImuPacket], n_samples: int, kind: str, max_bridge_s: float,
                thresholds: dict[str, float] | None = None) -> np.ndarray:  # fmt: skip
    """(n_samples, 4) quaternions of the gateway's fusion fed `pkts` one per batch; NaN where no packet came."""
    pipe = Pipeline()
    dev_id = pkts[0].device_id
    if thresholds:
        pipe.set_device_settings(dev_id, kind, DeviceSettings(thresholds=thresholds))
    pipe.bank.max_bridge_s = max_bridge_s
    if max_bridge_s > 0.0:  # what the bridge does for this kind, whether its row bridges by default or not
        pipe.bank.bridge_kinds.add(kind)
    q = np.full((n_samples, 4), np.nan)
    for p in pkts:
        for f in pipe.bank.fuse({dev_id: [p]}, 1e9, Output()):
            t_idx = np.rint(f.t_s * p.rate_hz).astype(np.int64)
            q[t_idx] = f.q
    return q


def runs(pkts: list[schemas.ImuPacket], lost: np.ndarray, n: int, kind: str,
         thresholds: dict[str, float] | None = None) -> Iterator[tuple[str, np.ndarray]]:  # fmt: skip
    """(mode, quaternions) for the three `MODES`."""
    kept = [p for p, gone in zip(pkts, lost, strict=True) if not gone]
    yield MODES[0], fused_quats(pkts, n, kind, 0.0, thresholds)
    yield MODES[1], fused_quats(kept, n, kind, 0.0, thresholds)
    yield MODES[2], fused_quats(kept, n, kind, Pipeline().bank.max_bridge_s, thresholds)


def broad_total_deg(trial: Any, q: np.ndarray, arrived: np.ndarray) -> float:
    """BROAD's total attitude error RMSE (9D, movement phases), degrees, of quaternions `q` (n, 4) of the first n
    samples of `trial` (a `gateway.fusion.broad.Trial`), over the samples that `arrived` and were fused."""
    from gateway.fusion import broad

    n = q.shape[0]
    ref = trial.quat_ref[:n].copy()
    bad = ~(arrived & np.isfinite(q[:, 0]))
    ref[bad] = np.nan
    q = np.where(bad[:, None], np.array([1.0, 0.0, 0.0, 0.0]), q)
    sub = broad.Trial(trial.name, trial.rate_hz, trial.gyr_rad_s[:n], trial.acc_m_s2[:n], trial.mag_uT[:n], ref,
                      trial.pos_m[:n], trial.movement[:n], trial.groups)  # fmt: skip
    return float(broad.score(q, sub, "9D").total_deg)


def theta_rmse_deg(q: np.ndarray, swing_rad: np.ndarray, scored: np.ndarray) -> tuple[float, float]:
    """(RMSE, max) of the hook's swing angle Θ from `q` (n, 4) against `swing_rad` over the `scored` samples that were
    fused, degrees."""
    from gateway.fusion import hook

    ok = scored & np.isfinite(q[:, 0])
    err = np.degrees(hook.swing_angle(q[ok]) - swing_rad[: q.shape[0]][ok])
    return float(np.sqrt(np.mean(err**2))), float(np.abs(err).max())


def hook_rows(seeds: list[int], duration_s: float, spp: int, loss: float, burst: float, suite_version: int
              ) -> list[dict[str, float]]:  # fmt: skip
    from bench.hook_suite import RATE_HZ, simulate_seed

    rows = []
    for seed in seeds:
        case, truth, gyr, acc, mag = simulate_seed(seed, duration_s, "calibrated", True,
                                                  suite_version=suite_version)
        pkts = packets(f"hook-{seed}", "hook", gyr, acc, mag, RATE_HZ, spp)
        lost = lost_packets(len(pkts), loss, burst, 7_000 + seed)
        arrived = np.repeat(~lost, spp)
        n = arrived.shape[0]
        scored = arrived & (truth.t_s[:n] >= WARMUP_S)
        row: dict[str, float] = {"seed": seed, "lost": float(lost.mean())}
        for mode, q in runs(pkts, lost, n, "hook", {"rope_length_m": case.physics.rope_length_m}):
            row[mode], row[mode + " max"] = theta_rmse_deg(q, truth.swing_rad, scored)
        rows.append(row)
        print(f"  hook seed {seed}: lost {row['lost']:.1%}, Θ RMSE " + ", ".join(
            f"{m} {row[m]:.3f}° (max {row[m + ' max']:.2f}°)" for m in MODES), flush=True)  # fmt: skip
    return rows


def broad_rows(spp: int, loss: float, burst: float, pattern: str, kind: str = "rod") -> list[dict[str, float]]:
    """BROAD's trials as `kind` devices (a rod: its tapered gyro in gaps; a plain `imu`: a line), same losses."""
    from gateway.fusion import broad

    paths = broad.find_trials(BROAD_DIR, pattern) if BROAD_DIR.is_dir() else []
    if not paths:
        print(f"  {kind}: no BROAD trials under {BROAD_DIR}: skipped")
        return []
    rows = []
    for k, path in enumerate(paths):
        trial = broad.load_trial(path)
        pkts = packets(f"{kind}-{k}", kind, trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT, trial.rate_hz, spp)
        lost = lost_packets(len(pkts), loss, burst, 9_000 + k)
        arrived = np.repeat(~lost, spp)
        n = arrived.shape[0]
        row: dict[str, float] = {"trial": k, "lost": float(lost.mean())}
        for mode, q in runs(pkts, lost, n, kind):
            row[mode] = broad_total_deg(trial, q, arrived)
        rows.append(row)
        print(f"  {kind} {path.stem}: lost {row['lost']:.1%}, total RMSE " + ", ".join(
            f"{m} {row[m]:.2f}°" for m in MODES), flush=True)  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--kinds", nargs="+", choices=("hook", "rod", "imu"), default=["hook", "rod"],
                   help="hook: the crane suite; rod, imu: BROAD's real trials as that kind (default hook rod)")
    p.add_argument("--seeds", type=parse_seeds, default=parse_seeds("501-510"),
                   help="hook suite seeds (default 501-510: held out of every hook tuning round)")
    p.add_argument("--duration", type=float, default=120.0, help="seconds per hook seed (default 120)")
    p.add_argument("--trials", default="*.mat", help="BROAD trial file pattern (default: all)")
    p.add_argument("--spp", type=int, default=10, help="samples per packet (default 10)")
    p.add_argument("--loss", type=float, default=0.02, help="long-run packet loss (default 0.02)")
    p.add_argument("--burst", type=float, default=2.0, help="mean burst length, packets (default 2)")
    add_suite_version_argument(p)
    args = p.parse_args(argv)
    t0 = time.monotonic()
    print(f"link: {args.loss:.1%} of packets lost in bursts of {args.burst:g} on average, {args.spp} samples a packet; "
          f"hook suite v{args.suite_version}")
    table = []
    if "hook" in args.kinds:
        rows = hook_rows(args.seeds, args.duration, args.spp, args.loss, args.burst, args.suite_version)
        table.append(("hooks, Θ RMSE / worst max (°)", rows, True))
    for kind in ("rod", "imu"):
        if kind in args.kinds:
            rows = broad_rows(args.spp, args.loss, args.burst, args.trials, kind)
            table.append((f"{kind}s (BROAD), total RMSE (°)", rows, False))
    print(f"\n| devices | lost | {' | '.join(MODES)} |\n|---|---|---|---|---|")
    for title, rows, with_max in table:
        if not rows:
            continue
        cells = []
        for m in MODES:
            mean = float(np.mean([r[m] for r in rows]))
            cells.append(f"{mean:.3f} / {max(r[m + ' max'] for r in rows):.2f}" if with_max else f"{mean:.2f}")
        lost = float(np.mean([r["lost"] for r in rows]))
        print(f"| {title}, {len(rows)} | {lost:.1%} | {' | '.join(cells)} |")
    print(f"({time.monotonic() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
