"""Publish a recording back onto zenoh as the original devices (same keys, encodings and payloads, so the
original device times and sequence numbers), at real time, N× faster, or as fast as possible.

    python -m gateway.recording.replay rec/                 # real time, to the gateway on tcp/127.0.0.1:7447
    python -m gateway.recording.replay rec/x.rigrec --speed 10
    python -m gateway.recording.replay rec/ --fast --key 'rig/rod/*/imu'

Each device seen in the replayed keys (`rig/{kind}/{id}/...`) holds its liveliness token `rig/{kind}/{id}` while the
replay runs, so the gateway shows it online. By default only device-originated keys are replayed (imu, env, reel,
truth, reference), never commands or gateway outputs. Puts use CongestionControl.BLOCK so a fast replay is not
thinned by a full queue (the devices themselves use DROP).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import zenoh
from tqdm import tqdm

from gateway.ingest.bus import key_matches
from gateway.recording._cli import add_zenoh_args, zenoh_config
from gateway.recording.format import ReadStats, Record, read_recording

DEVICE_KEYS: tuple[str, ...] = ("rig/*/*/imu", "rig/*/*/env", "rig/*/*/reel", "rig/*/*/truth", "rig/*/*/reference")
"""Replayed by default: what devices (and simulators) publish; commands and gateway outputs are left out."""


def device_token(key: str) -> str | None:
    """`rig/{kind}/{id}` for a device key `rig/{kind}/{id}/...`, else None."""
    parts = key.split("/")
    return "/".join(parts[:3]) if len(parts) >= 4 and parts[0] == "rig" else None


@dataclass
class ReplayStats:
    published: int = 0
    skipped: int = 0
    bytes: int = 0
    wall_s: float = 0.0
    recorded_s: float = 0.0
    devices: list[str] = field(default_factory=list)

    @property
    def speed(self) -> float:
        """Achieved speed-up over the recording's own time line."""
        return self.recorded_s / self.wall_s if self.wall_s > 0 else float("inf")


def select(records: Iterable[Record], keys: Sequence[str]) -> Iterable[Record]:
    """Records whose key matches one of the selectors."""
    return (r for r in records if any(key_matches(k, r.key) for k in keys))


class Publisher:
    """Puts records on a zenoh session (one declared publisher per key, BLOCK) and holds device tokens."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._tokens: dict[str, zenoh.LivelinessToken] = {}

    def put(self, rec: Record) -> None:
        token = device_token(rec.key)
        if token is not None and token not in self._tokens:
            self._tokens[token] = self.session.liveliness().declare_token(token)
        pub = self._pubs.get(rec.key)
        if pub is None:
            pub = self._pubs[rec.key] = self.session.declare_publisher(
                rec.key, congestion_control=zenoh.CongestionControl.BLOCK)  # fmt: skip
        pub.put(rec.payload, encoding=zenoh.Encoding(rec.encoding) if rec.encoding else None)

    @property
    def devices(self) -> list[str]:
        return list(self._tokens)

    def close(self) -> None:
        for p in self._pubs.values():
            p.undeclare()  # type: ignore[no-untyped-call]
        for t in self._tokens.values():
            t.undeclare()  # type: ignore[no-untyped-call]
        self._pubs.clear()
        self._tokens.clear()


def replay(
    put: Callable[[Record], None], records: Iterable[Record], speed: float | None = 1.0,
    sleep: Callable[[float], None] = time.sleep, clock: Callable[[], float] = time.monotonic,
    progress: tqdm | None = None,
) -> ReplayStats:  # fmt: skip
    """Publish records in order; record i goes out at (t_i − t_0) / speed after the start (speed None: at once)."""
    stats = ReplayStats()
    start = clock()
    t0_us: int | None = None
    t_last = 0
    for rec in records:
        if t0_us is None:
            t0_us = rec.t_us
        if speed is not None:
            delay = start + (rec.t_us - t0_us) * 1e-6 / speed - clock()
            if delay > 0:
                sleep(delay)
        put(rec)
        t_last = rec.t_us
        stats.published += 1
        stats.bytes += len(rec.payload)
        if progress is not None:
            progress.update(1)
    stats.wall_s = clock() - start
    stats.recorded_s = (t_last - t0_us) * 1e-6 if t0_us is not None else 0.0
    return stats


def count_records(path: str | Path, keys: Sequence[str]) -> int:
    """Number of records a replay of `path` with these key selectors would publish (a read pass)."""
    return sum(1 for _ in select(read_recording(path), keys))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.recording.replay", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("recording", type=Path, help="a .rigrec file or a directory of them")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--speed", type=float, default=1.0, help="time scale: 1 = real time (default), 10 = 10× faster")
    g.add_argument("--fast", action="store_true", help="as fast as possible")
    p.add_argument("-k", "--key", dest="keys", action="append", metavar="SELECTOR",
                   help=f"replay only keys matching, repeatable (default: {' '.join(DEVICE_KEYS)})")  # fmt: skip
    p.add_argument("--linger-s", type=float, default=1.0,
                   help="keep the device tokens this long after the last sample (default: 1 s)")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_zenoh_args(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.speed <= 0:
        print("--speed must be > 0", file=sys.stderr)
        return 2
    keys: list[str] = args.keys or list(DEVICE_KEYS)
    total = count_records(args.recording, keys)
    read = ReadStats()
    bar = tqdm(total=total, desc="replay", unit="sample", file=sys.stderr, disable=args.no_progress)
    with zenoh.open(zenoh_config(args)) as session:
        pub = Publisher(session)
        time.sleep(0.5)  # let the link come up before the first put (zenoh drops puts with no route yet)
        try:
            stats = replay(pub.put, select(read_recording(args.recording, read), keys),
                           None if args.fast else args.speed, progress=bar)  # fmt: skip
            time.sleep(args.linger_s)
        finally:
            devices = pub.devices
            pub.close()
    bar.close()
    print(f"replayed {stats.published} samples ({stats.bytes / 1e6:.2f} MB) of {len(devices)} device(s) in "
          f"{stats.wall_s:.2f} s: {stats.published / max(stats.wall_s, 1e-9):,.0f} samples/s, "
          f"{stats.speed:.1f}× the recorded time line", file=sys.stderr)  # fmt: skip
    if read.tail_bytes:
        print(f"note: {read.tail_bytes} bytes of torn tail skipped in {', '.join(read.torn_files)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
