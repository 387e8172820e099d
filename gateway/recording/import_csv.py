"""Convert a phone sensor-app CSV log into a replayable recording (one IMU device).

    python -m gateway.recording.import_csv phone.csv -o rec/ --device-id phone-1
    python -m gateway.recording.import_csv log.csv -o rec/ --rate 100 --flip-acc

The header row must name each column with its unit: `time (s)` or `time_ms`, `acc_x (m/s^2)` or `accel x [g]`,
`gyro_x (deg/s)` or `gyr_x_rad/s`, optional `mag_x (uT)`. Units are converted to SI (s, m/s², rad/s, µT), and the
samples are resampled linearly to a uniform grid (median rate, or --rate). `--flip-acc` negates the accelerometer
for apps that report acceleration rather than specific force (iOS reads -1 g on z lying flat; we need +9.81).
Optional one-value columns `temp (C)`, `depth (m)`, `lat (deg)`, `lon (deg)`, `alt (m)`, `speed (m/s)`,
`fix_quality (nmea)` (what `python -m gateway.recording.export` writes) become each packet's `temp_c`, `depth_m`
and `gnss` (from the first sample of the packet that has them), so an exported log reads back as it was recorded.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from gateway.recording.format import SUFFIX, RecordWriter
from gateway.recording.importers import CsvFormatError, csv_meta, csv_records, read_sensor_csv


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.recording.import_csv", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("csv", type=Path, help="sensor log with a header row naming columns and units")
    p.add_argument("-o", "--out", type=Path, required=True, help="output directory")
    p.add_argument("--device-id", default=None,
                   help="device id (default: the id an exported log is named by, `ID-YYYYmmddT...Z.csv`, else phone-1)")
    p.add_argument("--kind", choices=["rod", "hook"], default="rod", help="device kind (default: rod)")
    p.add_argument("--rate", type=float, default=None, help="resample to this rate in Hz (default: median rate)")
    p.add_argument("--samples-per-packet", type=int, default=10, help="samples per ImuPacket (default: 10)")
    p.add_argument("--flip-acc", action="store_true", help="negate the accelerometer (acceleration -> specific force)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


_EXPORT_NAME = re.compile(r"^(?P<id>[A-Za-z0-9_-]{1,64})-\d{8}T\d{6}\.\d{6}Z(_\d{4})?$")


def device_id_from_name(path: Path) -> str | None:
    """The device id of a file named by `gateway.recording.export` (`rod-1-20260101T000000.000000Z.csv`), else None."""
    m = _EXPORT_NAME.match(path.stem)
    return m.group("id") if m else None


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    args.device_id = args.device_id or device_id_from_name(args.csv) or "phone-1"
    try:
        imp = read_sensor_csv(args.csv, args.rate, args.flip_acc)
    except (CsvFormatError, ValueError, OSError) as exc:
        print(f"{args.csv}: {exc}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / f"{args.csv.stem}{SUFFIX}"
    path.unlink(missing_ok=True)
    n = imp.stream.gyr_rad_s.shape[0]
    with RecordWriter(path, csv_meta(args.csv, imp, args.device_id, args.kind, args.samples_per_packet)) as w:
        recs = csv_records(imp, args.device_id, args.kind, args.samples_per_packet)
        for rec in tqdm(recs, total=-(-n // args.samples_per_packet), desc="import", unit="packet", file=sys.stderr,
                        disable=args.no_progress):  # fmt: skip
            w.append(rec)
    print(f"{path}: {n} samples at {imp.stream.rate_hz:.3f} Hz (raw median {imp.raw_rate_hz:.3f} Hz, largest gap "
          f"{imp.max_gap_s * 1e3:.1f} ms), {'9D' if imp.stream.mag_uT is not None else '6D'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
