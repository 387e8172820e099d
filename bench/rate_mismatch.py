"""A device whose declared `rate_hz` is off its real sample rate, on BROAD's real recordings: the default filter's
total attitude error with the declared rate taken as is, and with the ingest's measured rate
(`gateway.ingest.samplerate.SampleRateMeter`, as `GatewayService` applies it), next to VQF given the declared rate.

    python -m bench.rate_mismatch                                  # rate_hz off by 0, ±0.2 %, ±0.5 %, ±1 %, ±2 %
    python -m bench.rate_mismatch --off 0.01 --jitter-ms 9 --loss 0.02   # t0_us jittered ±9 ms, 2 % of packets lost

Each trial is cut into `--spp`-sample packets whose `t0_us` follow the recording's own clock (plus jitter) and whose
`rate_hz` is the recording's rate × (1 + off); they go through a `Pipeline`'s fusion bank one packet per batch, lost
ones left out (bridged as in the gateway). Score: BROAD's total RMSE (9D, movement phases, heading offset removed)
over the samples that arrived, mean and worst of the trials; "identical" counts trials whose quaternions are bit for
bit those of the declared rate (expected where nothing is off).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bench.link_loss import broad_total_deg, lost_packets, packets
from gateway import schemas
from gateway.fusion import broad
from gateway.ingest.samplerate import SampleRateMeter
from gateway.kinds.base import Output
from gateway.pipeline import Pipeline


def fused(pkts: list[schemas.ImuPacket], lost: np.ndarray, n_samples: int, measure: bool) -> np.ndarray:
    """(n_samples, 4) quaternions by packet order (NaN where none came); `measure`: the rate the meter says."""
    pipe, spp = Pipeline(), pkts[0].n
    meter = SampleRateMeter()
    q = np.full((n_samples, 4), np.nan)
    for k, p in enumerate(pkts):
        if lost[k]:
            continue
        if measure:
            rate = meter.update(p.boot_id, p.seq, p.t0_us, p.n, p.rate_hz)
            if rate != p.rate_hz:
                p = p.model_copy(update={"rate_hz": rate})
        for f in pipe.bank.fuse({p.device_id: [p]}, 1e9, Output()):
            q[(k + 1) * spp - f.q.shape[0] : (k + 1) * spp] = f.q
    return q


def vqf_total_deg(trial: broad.Trial, rate_hz: float) -> float:
    from vqf import VQF

    q = VQF(1.0 / rate_hz).updateBatch(trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT)["quat9D"]
    return float(broad.score(np.asarray(q, dtype=np.float64), trial, "9D").total_deg)


def row(trials: Sequence[broad.Trial], off: float, spp: int, jitter_ms: int, loss: float) -> dict[str, float]:
    declared, measured, vqf, same = [], [], [], 0
    for i, tr in enumerate(trials):
        rng = np.random.default_rng(i)
        base = packets("broad", "rod", tr.gyr_rad_s, tr.acc_m_s2, tr.mag_uT, tr.rate_hz, spp)
        pk = [p.model_copy(update={"rate_hz": tr.rate_hz * (1.0 + off), "t0_us": max(
            0, p.t0_us + int(rng.integers(-jitter_ms * 1000, jitter_ms * 1000 + 1)))}) for p in base]  # fmt: skip
        lost = lost_packets(len(pk), loss, 2.0, i) if loss > 0 else np.zeros(len(pk), dtype=bool)
        n = len(pk) * spp
        arrived = np.repeat(~lost, spp)
        q_decl, q_meas = fused(pk, lost, n, False), fused(pk, lost, n, True)
        same += bool(np.array_equal(q_decl, q_meas, equal_nan=True))
        declared.append(broad_total_deg(tr, q_decl, arrived))
        measured.append(broad_total_deg(tr, q_meas, arrived))
        vqf.append(vqf_total_deg(tr, tr.rate_hz * (1.0 + off)))
        print(f"  {tr.name[:30]:30s} off {off:+.3f}: declared {declared[-1]:6.2f}  measured {measured[-1]:6.2f}  "
              f"VQF {vqf[-1]:6.2f}", file=sys.stderr, flush=True)  # fmt: skip
    return {"off": off, "declared": float(np.mean(declared)), "declared_worst": float(np.max(declared)),
            "measured": float(np.mean(measured)), "measured_worst": float(np.max(measured)),
            "vqf": float(np.mean(vqf)), "identical": same, "trials": len(trials)}  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m bench.rate_mismatch", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--data", type=Path, default=Path("../shared/data/broad"), help="BROAD .mat directory")
    offs = [0.0, 0.002, -0.002, 0.005, -0.005, 0.01, -0.01, 0.02, -0.02]
    p.add_argument("--off", type=float, nargs="+", default=offs, help="relative errors of the declared rate_hz")
    p.add_argument("--spp", type=int, default=10, help="samples per packet (default 10)")
    p.add_argument("--jitter-ms", type=int, default=0, help="t0_us moved by up to ± this (uniform), default 0")
    p.add_argument("--loss", type=float, default=0.0, help="share of packets lost, bursts of 2 (default 0)")
    p.add_argument("--trials", default="*.mat", help="glob of the trials (default all)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    paths = broad.find_trials(args.data, args.trials) if args.data.is_dir() else []
    if not paths:
        print(f"no BROAD trials under {args.data}", file=sys.stderr)
        return 2
    trials = [broad.load_trial(p) for p in paths]
    print(f"BROAD {len(trials)} trials, 9D total RMSE (deg), {args.spp}-sample packets, t0_us ±{args.jitter_ms} ms, "
          f"{args.loss:.0%} lost; mean (worst)")  # fmt: skip
    print("| rate_hz off | declared rate | measured rate (default) | VQF, declared rate | identical |")
    print("|---|---|---|---|---|")
    for off in args.off:
        r = row(trials, off, args.spp, args.jitter_ms, args.loss)
        print(f"| {off:+.1%} | {r['declared']:.2f} ({r['declared_worst']:.2f}) | {r['measured']:.2f} "
              f"({r['measured_worst']:.2f}) | {r['vqf']:.2f} | {r['identical']}/{r['trials']} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
