"""Export IMU data to time-named CSV or text files, the logger of seed 004 (one row per sample, one file per device).

    python -m gateway.recording.export rec/ -o logs/                  # a recording -> logs/rod-1-20260101T000000Z.csv
    python -m gateway.recording.export rec/x.rigrec -o logs/ --format txt
    python -m gateway.recording.export --live -o logs/ --duration 60  # live from zenoh (the devices' imu keys)

Columns (headers name their units, so `python -m gateway.recording.import_csv` reads the files back): device time
`time (s)`, device realtime clock `wall_time (s)` (unix, blank without one), `acc_x..z (m/s^2)`, `gyro_x..z (rad/s)`,
`mag_x..z (uT)`, `temp (C)`, then, when the device sends them, `depth (m)` and the GNSS columns `lat (deg)`,
`lon (deg)`, `alt (m)`, `speed (m/s)`, `fix_quality (nmea)` (filled on the sample a fix belongs to, blank between).
A packet's temperature is written on each of its samples. A device that starts sending a field it did not send before
(a receiver gets its first fix) starts a new file, so a header always covers its rows. Files are named by the UTC
time of their first sample and rotate after `--rotate-s` of device time.
"""

from __future__ import annotations

import argparse
import csv
import logging
import queue
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal

from tqdm import tqdm

from gateway import schemas
from gateway.recording.format import ReadStats, read_recording

log = logging.getLogger("gateway.recording")
Format = Literal["csv", "txt"]

BASE_COLUMNS: tuple[str, ...] = (
    "time (s)", "wall_time (s)", "acc_x (m/s^2)", "acc_y (m/s^2)", "acc_z (m/s^2)",
    "gyro_x (rad/s)", "gyro_y (rad/s)", "gyro_z (rad/s)", "mag_x (uT)", "mag_y (uT)", "mag_z (uT)", "temp (C)",
)  # fmt: skip
DEPTH_COLUMNS: tuple[str, ...] = ("depth (m)",)
GNSS_COLUMNS: tuple[str, ...] = ("lat (deg)", "lon (deg)", "alt (m)", "speed (m/s)", "fix_quality (nmea)")

Cell = float | int | None


def columns_for(has_depth: bool, has_gnss: bool) -> tuple[str, ...]:
    """The header of a file: base columns, then depth and GNSS when the device sends them."""
    return BASE_COLUMNS + (DEPTH_COLUMNS if has_depth else ()) + (GNSS_COLUMNS if has_gnss else ())


def packet_rows(pkt: schemas.ImuPacket, has_depth: bool, has_gnss: bool) -> list[list[Cell]]:
    """One row per sample of `pkt` in the order of `columns_for(has_depth, has_gnss)`; SI units, times in s."""
    rows: list[list[Cell]] = []
    step_s = 1.0 / pkt.rate_hz
    mag = pkt.mag_uT
    for i in range(pkt.n):
        t_s = pkt.t0_us * 1e-6 + i * step_s
        wall_s = pkt.wall_t0_us * 1e-6 + i * step_s if pkt.wall_t0_us is not None else None
        m: Sequence[Cell] = mag[i] if mag is not None else (None, None, None)
        row: list[Cell] = [t_s, wall_s, *pkt.acc_m_s2[i], *pkt.gyr_rad_s[i], *m, pkt.temp_c]
        first = i == 0
        if has_depth:
            row.append(pkt.depth_m if first else None)
        if has_gnss:
            g = pkt.gnss if first else None
            row += [g.lat_deg, g.lon_deg, g.alt_m, g.speed_m_s, g.fix_quality] if g else [None] * 5
        rows.append(row)
    return rows


def file_name(device_id: str, wall_s: float, fmt: Format) -> str:
    """`{device_id}-YYYYmmddTHHMMSS.ffffffZ.{csv|txt}` (UTC, so name order is time order)."""
    stamp = datetime.fromtimestamp(wall_s, UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    return f"{device_id}-{stamp}.{fmt}"


@dataclass
class _DeviceFile:
    path: Path
    handle: IO[str]
    writer: Any  # csv.writer's type is private to typeshed
    has_depth: bool
    has_gnss: bool
    t_first_s: float
    rows: int = 0


class CsvExporter:
    """Writes IMU packets to one time-named file per device (new file on rotation or when new fields appear).

    Not thread-safe: call `add()` from one thread. Time comes from the packets (wall clock of the sample when the
    device sends one, else `arrival_wall_us`)."""

    def __init__(self, directory: Path, fmt: Format = "csv", rotate_s: float = 0.0) -> None:
        self.directory = directory
        self.fmt = fmt
        self.rotate_s = rotate_s
        self.files: list[Path] = []
        self.rows = 0
        self._open: dict[tuple[str, str], _DeviceFile] = {}
        directory.mkdir(parents=True, exist_ok=True)

    def add(self, pkt: schemas.ImuPacket, arrival_wall_us: int) -> None:
        """Append the packet's samples to its device's file."""
        dev = (pkt.kind, pkt.device_id)
        f = self._open.get(dev)
        need_depth, need_gnss = pkt.depth_m is not None, pkt.gnss is not None
        t_s = pkt.t0_us * 1e-6
        if f is None or (need_depth and not f.has_depth) or (need_gnss and not f.has_gnss) or (
                self.rotate_s > 0 and t_s - f.t_first_s >= self.rotate_s):  # fmt: skip
            has_depth = need_depth or (f is not None and f.has_depth)
            has_gnss = need_gnss or (f is not None and f.has_gnss)
            if f is not None:
                f.handle.close()
            wall_us = pkt.wall_t0_us if pkt.wall_t0_us is not None else arrival_wall_us
            f = self._new_file(pkt.device_id, wall_us * 1e-6, has_depth, has_gnss, t_s)
            self._open[dev] = f
        rows = packet_rows(pkt, f.has_depth, f.has_gnss)
        f.writer.writerows(rows)
        f.rows += len(rows)
        self.rows += len(rows)

    def _new_file(self, device_id: str, wall_s: float, has_depth: bool, has_gnss: bool, t_s: float) -> _DeviceFile:
        name = file_name(device_id, wall_s, self.fmt)
        path, k = self.directory / name, 0
        while path.exists() or path in self.files:  # same microsecond twice: `_0001` sorts after it
            k += 1
            path = self.directory / f"{name.removesuffix('.' + self.fmt)}_{k:04d}.{self.fmt}"
        handle = open(path, "w", newline="")  # noqa: SIM115 (closed in close())
        writer = csv.writer(handle, delimiter="," if self.fmt == "csv" else "\t", lineterminator="\n")
        writer.writerow(columns_for(has_depth, has_gnss))
        self.files.append(path)
        return _DeviceFile(path, handle, writer, has_depth, has_gnss, t_s)

    def flush(self) -> None:
        for f in self._open.values():
            f.handle.flush()

    def close(self) -> None:
        for f in self._open.values():
            f.handle.close()
        self._open.clear()

    def __enter__(self) -> CsvExporter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def export_records(records: Iterable[tuple[str, bytes, int]], exporter: CsvExporter) -> int:
    """Decode (key, payload, arrival unix µs) of IMU keys and export them; returns packets rejected by the decoder."""
    rejected = 0
    for key, payload, t_us in records:
        if not key.endswith("/imu"):
            continue
        try:
            pkt = schemas.decode(key, payload)
        except schemas.DecodeError as exc:
            log.warning("skipped %s: %s", key, exc)
            rejected += 1
            continue
        assert isinstance(pkt, schemas.ImuPacket)
        exporter.add(pkt, t_us)
    return rejected


def export_recording(path: Path, exporter: CsvExporter, progress: bool = False) -> tuple[int, ReadStats]:
    """Export every IMU packet of a `.rigrec` file or directory; returns (packets rejected, read stats)."""
    stats = ReadStats()
    recs = tqdm(read_recording(path, stats), desc="export", unit="record", file=sys.stderr, disable=not progress)
    rejected = export_records(((r.key, r.payload, r.t_us) for r in recs), exporter)
    return rejected, stats


def export_live(args: argparse.Namespace, exporter: CsvExporter) -> int:
    """Subscribe to the IMU keys and export until Ctrl-C/SIGTERM, `--duration` or `--count` packets."""
    import zenoh

    from gateway.recording._cli import stop_on_signals, zenoh_config

    inbox: queue.SimpleQueue[tuple[str, bytes, int]] = queue.SimpleQueue()

    def on_sample(s: zenoh.Sample) -> None:  # zenoh thread: copy and hand off only
        inbox.put((str(s.key_expr), s.payload.to_bytes(), time.time_ns() // 1000))

    stop = stop_on_signals()
    t_end = time.monotonic() + args.duration if args.duration > 0 else float("inf")
    packets, last_flush = 0, time.monotonic()
    with zenoh.open(zenoh_config(args)) as session:
        subs = [session.declare_subscriber(k, on_sample) for k in args.keys or [schemas.SEL_IMU]]
        while not stop.is_set() and time.monotonic() < t_end and not (args.count and packets >= args.count):
            try:
                item = inbox.get(timeout=0.1)
            except queue.Empty:
                continue
            export_records([item], exporter)
            packets += 1
            if time.monotonic() - last_flush > 1.0:
                exporter.flush()
                last_flush = time.monotonic()
        for s in subs:
            s.undeclare()  # type: ignore[no-untyped-call]
    return packets


def build_parser() -> argparse.ArgumentParser:
    from gateway.recording._cli import add_zenoh_args

    p = argparse.ArgumentParser(prog="python -m gateway.recording.export", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("recording", type=Path, nargs="?", help="a .rigrec file or directory (omit with --live)")
    p.add_argument("-o", "--out", type=Path, required=True, help="directory for the time-named files")
    p.add_argument("--format", choices=["csv", "txt"], default="csv", help="csv (comma) or txt (tab) (default: csv)")
    p.add_argument("--rotate-s", type=float, default=3600.0,
                   help="start a new file per device after this much device time, s (0 = never; default: 3600)")
    p.add_argument("--live", action="store_true", help="export live from zenoh instead of a recording")
    p.add_argument("-k", "--key", dest="keys", action="append", metavar="SELECTOR",
                   help=f"live: IMU key expression, repeatable (default: {schemas.SEL_IMU})")
    p.add_argument("--duration", type=float, default=0.0, help="live: stop after this many seconds (default: ^C)")
    p.add_argument("--count", type=int, default=0, help="live: stop after this many packets (default: no limit)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_zenoh_args(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.live == (args.recording is not None):
        parser.error("give a recording or --live (not both)")
    rejected = 0
    with CsvExporter(args.out, args.format, args.rotate_s) as exporter:
        if args.live:
            packets = export_live(args, exporter)
            source = f"{packets} live packets"
        else:
            rejected, stats = export_recording(args.recording, exporter, progress=not args.no_progress)
            source = f"{stats.records} records of {args.recording}" + (
                f" ({stats.tail_bytes} bytes of torn tail skipped)" if stats.tail_bytes else "")
    for f in exporter.files:
        print(f, file=sys.stderr)
    print(f"{exporter.rows} samples from {source} in {len(exporter.files)} file(s) under {args.out}; "
          f"{rejected} packet(s) rejected", file=sys.stderr)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
