"""Recording and replay throughput: write (with fsync per block), read, and replay over zenoh on loopback.

    python -m bench.replay_speed                              # BROAD trial 15, 10 samples per packet
    python -m bench.replay_speed --trial 24_disturbed_tapping_A --samples-per-packet 1 --seconds 60

Prints records/s and MB/s (wall and CPU time, because the CI machine is shared) for: encoding + writing a
recording with `Recorder` (fsync every 1000 records), reading it back, and a `--fast` replay to a subscriber in a
second zenoh session on loopback (counting what arrived, so any loss shows), plus the replay's speed-up over the
recording's own time line (a device at 285.7 Hz in blocks of 10 sends 28.6 packets/s).
Data: BROAD, Laidig et al., Data 6(7):72, 2021, CC BY 4.0.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh
from tqdm import tqdm

from bench.bite_latency import free_port
from gateway.fusion import broad
from gateway.recording.format import Record, read_recording
from gateway.recording.importers import broad_records
from gateway.recording.recorder import Recorder, RecorderSettings
from gateway.recording.replay import Publisher, replay

BROAD_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "broad"


def timed(fn: Callable[[], object]) -> tuple[float, float]:
    """(wall s, CPU s of this process) of one call."""
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def line(what: str, n: int, nbytes: int, wall: float, cpu: float) -> str:
    return (f"{what:34s} {n:8d} records  {n / wall:10,.0f} rec/s wall  {n / max(cpu, 1e-9):10,.0f} rec/s CPU  "
            f"{nbytes / 1e6 / wall:7.1f} MB/s")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.replay_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--data", type=Path, default=BROAD_DIR, help=f"BROAD folder (default: {BROAD_DIR})")
    p.add_argument("--trial", default="15_undisturbed_fast_translation_A", help="trial name")
    p.add_argument("--seconds", type=float, default=0.0, help="only the first N seconds (default: all)")
    p.add_argument("--samples-per-packet", type=int, default=10, help="IMU samples per packet (default: 10)")
    args = p.parse_args(argv)
    trial = broad.load_trial(args.data / f"{args.trial}.mat")
    if args.seconds > 0:
        trial = trial.slice(0, int(args.seconds * trial.rate_hz))
    records = list(tqdm(broad_records(trial, samples_per_packet=args.samples_per_packet), desc="encode",
                        unit="rec", file=sys.stderr))  # fmt: skip
    nbytes = sum(len(r.payload) for r in records)
    print(f"{trial.name}: {trial.n} samples, {len(records)} records (IMU + reference), {nbytes / 1e6:.1f} MB of "
          f"payload, {(records[-1].t_us - records[0].t_us) / 1e6:.1f} s recorded")  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "rec"
        settings = RecorderSettings(out, block_records=1000, block_s=1e9, min_free_bytes=0, resume_free_bytes=0)

        def write() -> None:
            with Recorder(settings) as rec:
                for r in tqdm(records, desc="write", unit="rec", file=sys.stderr, leave=False):
                    rec.append(r.key, r.payload, r.t_us, r.encoding)

        w, c = timed(write)
        size = sum(f.stat().st_size for f in out.iterdir())
        print(line("write (compressed, fsync/1000)", len(records), nbytes, w, c) + f"  file {size / 1e6:.1f} MB "
              f"({size / nbytes:.2f} of payload)")  # fmt: skip
        got: list[Record] = []
        w, c = timed(lambda: got.extend(read_recording(out)))
        assert [r.payload for r in got] == [r.payload for r in records]
        print(line("read (CRC check + inflate)", len(got), nbytes, w, c))

        port = free_port()
        listen, connect = zenoh.Config(), zenoh.Config()
        listen.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        connect.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        for conf in (listen, connect):
            conf.insert_json5("scouting/multicast/enabled", "false")
        received = 0
        lock = threading.Lock()

        def on_sample(_: zenoh.Sample) -> None:
            nonlocal received
            with lock:
                received += 1

        with zenoh.open(listen) as sink, zenoh.open(connect) as source:
            sub = sink.declare_subscriber("rig/**", on_sample)
            time.sleep(1.0)
            pub = Publisher(source)
            stats_box = []
            with tqdm(total=len(got), desc="replay", unit="rec", file=sys.stderr, leave=False) as bar:
                w, c = timed(lambda: stats_box.append(replay(pub.put, got, None, progress=bar)))
            deadline = time.monotonic() + 10
            while received < len(got) and time.monotonic() < deadline:
                time.sleep(0.05)
            pub.close()
            sub.undeclare()  # type: ignore[no-untyped-call]
        st = stats_box[0]
        print(line("replay --fast over zenoh loopback", st.published, nbytes, w, c) +
              f"  {st.speed:,.0f}× real time; received {received}/{st.published}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
