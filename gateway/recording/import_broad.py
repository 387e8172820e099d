"""Convert BROAD trials (.mat) into replayable recordings: IMU packets of a `rod` device plus reference packets.

    python -m gateway.recording.import_broad ../shared/data/broad/15_undisturbed_fast_translation_A.mat -o rec/
    python -m gateway.recording.import_broad DATA_DIR --trials '*translation*' -o rec/

One file per trial, `<out>/<trial>.rigrec`. The device publishes at the trial's rate (285.714 Hz) in blocks of
--samples-per-packet. To reproduce the offline BROAD figures through zenoh, run the gateway with
`--attitude-blocks --no-warmup-bias-seed` (every sample's attitude; docs/recording.md); any block size works.
Data: BROAD, Laidig et al., Data 6(7):72, 2021, CC BY 4.0.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from gateway.fusion import broad
from gateway.recording.format import SUFFIX, RecordWriter
from gateway.recording.importers import broad_meta, broad_records


def import_trial(trial: broad.Trial, out: Path, device_id: str = "broad-1", kind: str = "imu",
                 samples_per_packet: int = 10, use_mag: bool = True, progress: bool = False) -> Path:  # fmt: skip
    """Write one trial as `<out>/<trial>.rigrec` (replacing it); returns the path."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{trial.name}{SUFFIX}"
    path.unlink(missing_ok=True)
    n_packets = -(-trial.n // samples_per_packet)
    with RecordWriter(path, broad_meta(trial, device_id, kind, samples_per_packet, use_mag), compress=True) as w:
        recs = broad_records(trial, device_id, kind, samples_per_packet, use_mag)
        for i, rec in enumerate(tqdm(recs, total=2 * n_packets, desc=trial.name[:28], unit="packet",
                                     file=sys.stderr, disable=not progress, leave=False)):  # fmt: skip
            w.append(rec)
            if i % 2000 == 1999:
                w.flush()
    return path


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.recording.import_broad", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("source", type=Path, help="a BROAD .mat file or a folder of them")
    p.add_argument("-o", "--out", type=Path, required=True, help="output directory")
    p.add_argument("--trials", default="*.mat", metavar="GLOB", help="glob inside a folder (default: *.mat)")
    p.add_argument("--device-id", default="broad-1", help="device id (default: broad-1)")
    p.add_argument("--kind", choices=["imu", "rod", "hook"], default="imu",
                   help="device kind (default: imu, a plain IMU; a rod's rules would judge the motion as bites)")
    p.add_argument("--samples-per-packet", type=int, default=10, help="samples per ImuPacket, 1..1000 (default 10)")
    p.add_argument("--no-mag", action="store_true", help="leave the magnetometer out (6D device)")
    p.add_argument("--seconds", type=float, default=0.0, help="keep only the first N seconds (default: all)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not 1 <= args.samples_per_packet <= 1000:
        print("--samples-per-packet must be within 1..1000", file=sys.stderr)
        return 2
    paths = broad.find_trials(args.source, args.trials) if args.source.is_dir() else [args.source]
    if not paths:
        print(f"no .mat files matching {args.trials!r} in {args.source}", file=sys.stderr)
        return 2
    for p in tqdm(paths, desc="import", unit="trial", file=sys.stderr, disable=args.no_progress):
        trial = broad.load_trial(p)
        if args.seconds > 0:
            trial = trial.slice(0, int(round(args.seconds * trial.rate_hz)))
        out = import_trial(trial, args.out, args.device_id, args.kind, args.samples_per_packet, not args.no_mag,
                           progress=not args.no_progress)  # fmt: skip
        print(f"{out}: {trial.n} samples, {out.stat().st_size / 1e6:.2f} MB", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
