"""Record zenoh samples to time-named `.rigrec` files (format: gateway/recording/format.py, docs/recording.md).

    python -m gateway.recording.record -o recordings/                      # everything under rig/**
    python -m gateway.recording.record -o rec/ -k 'rig/*/*/imu' -k 'gw/**' --duration 60

Every sample is stored raw (key, encoding, payload bytes, arrival time). Blocks are fsynced at least every
--block-s; files rotate by size or age; below --min-free-mb of free disk the recorder pauses (or stops).
Ctrl-C (or SIGTERM) flushes and closes cleanly; a SIGKILL loses at most the unsynced block.
"""

from __future__ import annotations

import argparse
import logging
import queue
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import zenoh
from tqdm import tqdm

from gateway.recording._cli import add_zenoh_args, stop_on_signals, zenoh_config
from gateway.recording.recorder import LowDiskSpace, Recorder, RecorderSettings

log = logging.getLogger("gateway.recording")
Item = tuple[str, str, bytes, int]  # key, encoding, payload, arrival unix µs


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.recording.record", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("-o", "--out", type=Path, required=True, help="directory for the .rigrec files")
    p.add_argument("-k", "--key", dest="keys", action="append", metavar="SELECTOR",
                   help="key expression to record, repeatable (default: rig/**)")  # fmt: skip
    p.add_argument("--prefix", default="rig", help="file name prefix (default: rig)")
    p.add_argument("--rotate-mb", type=float, default=256.0, help="start a new file beyond this size (default: 256)")
    p.add_argument("--rotate-s", type=float, default=3600.0, help="... or after this many seconds (0 = never)")
    p.add_argument("--block-s", type=float, default=1.0, help="fsync at least this often (default: 1 s)")
    p.add_argument("--min-free-mb", type=float, default=512.0, help="free-space floor (default: 512 MB)")
    p.add_argument("--resume-free-mb", type=float, default=None, help="resume above this (default: floor × 1.5)")
    p.add_argument("--on-low-disk", choices=["pause", "stop"], default="pause", help="below the floor (default: pause)")
    p.add_argument("--no-compress", action="store_true", help="store payloads uncompressed")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (default: run until ^C)")
    p.add_argument("--count", type=int, default=0, help="stop after this many samples (default: no limit)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_zenoh_args(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    keys: list[str] = args.keys or ["rig/**"]
    floor = int(args.min_free_mb * 1e6)
    settings = RecorderSettings(
        directory=args.out, prefix=args.prefix, rotate_bytes=int(args.rotate_mb * 1e6), rotate_s=args.rotate_s,
        block_s=args.block_s, min_free_bytes=floor,
        resume_free_bytes=int(args.resume_free_mb * 1e6) if args.resume_free_mb is not None else int(floor * 1.5),
        on_low_disk=args.on_low_disk, compress=not args.no_compress, meta={"keys": keys, "source": "record"},
    )  # fmt: skip
    inbox: queue.SimpleQueue[Item] = queue.SimpleQueue()

    def on_sample(s: zenoh.Sample) -> None:  # zenoh thread: copy and hand off only
        inbox.put((str(s.key_expr), str(s.encoding), s.payload.to_bytes(), time.time_ns() // 1000))

    stop = stop_on_signals()
    t_end = time.monotonic() + args.duration if args.duration > 0 else float("inf")
    bar = tqdm(desc="record", unit="sample", file=sys.stderr, disable=args.no_progress)
    rc = 0
    with zenoh.open(zenoh_config(args)) as session, Recorder(settings) as rec:
        subs = [session.declare_subscriber(k, on_sample) for k in keys]
        log.info("recording %s into %s", ", ".join(keys), args.out)
        try:
            limit = args.count or float("inf")
            while not stop.is_set() and time.monotonic() < t_end and rec.stats.records < limit:
                try:
                    key, enc, payload, t_us = inbox.get(timeout=0.1)
                except queue.Empty:
                    rec.tick()
                    continue
                rec.append(key, payload, t_us, enc)
                bar.update(1)
                if bar.n % 200 == 0:
                    bar.set_postfix_str(f"{rec.stats.bytes / 1e6:.1f} MB, {len(rec.stats.files)} file(s)")
        except LowDiskSpace as exc:
            log.error("%s", exc)
            rc = 3
        for s in subs:
            s.undeclare()  # type: ignore[no-untyped-call]
        while rc == 0 and not args.count:  # what arrived before the subscribers went away
            try:
                key, enc, payload, t_us = inbox.get_nowait()
            except queue.Empty:
                break
            rec.append(key, payload, t_us, enc)
    bar.close()
    st = rec.stats
    print(f"{st.records} samples, {st.bytes / 1e6:.2f} MB in {len(st.files)} file(s) under {args.out}; "
          f"{st.dropped_low_disk} dropped for lack of disk space", file=sys.stderr)  # fmt: skip
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
