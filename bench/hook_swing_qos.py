"""Does a crane app in another process get every `gw/hook/{id}/swing`? Gateway, hooks and a slow subscriber in three
processes on loopback; prints the share of swing messages the subscriber lost.

    python -m bench.hook_swing_qos                       # 4 hooks at 20 packets/s, 20 s, a slow subscriber
    python -m bench.hook_swing_qos --hooks 8 --busy 2    # more hooks, two CPU-burning threads in the subscriber

The subscriber process (`--listen-only`, started by the bench) is loaded on purpose: its callback sleeps
`--work-ms` per message, stalls `--stall-ms` every `--stall-every` messages (a GC pause, a busy UI thread) and it
runs `--busy` threads that burn CPU. Loss is counted per hook from the swing `seq` numbers: every IMU packet from the
first swing received to the last gives one swing (5 samples per packet at 100 Hz = 20 Hz, the documented maximum),
so a gap is a lost message. The gateway publishes swing with CongestionControl.BLOCK (docs/protocol.md section 1).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from bench.bite_latency import REPO, free_port, observer_config, start_gateway, stop_process, wait_http


def listen(port: int, duration_s: float, out_path: Path, work_ms: float, stall_every: int, stall_ms: float,
           busy: int) -> None:  # fmt: skip
    """Subscribe to every hook's swing for `duration_s` with a slow callback; write `{device: [seq, ...]}` JSON."""
    seqs: dict[str, list[int]] = {}
    stop = threading.Event()

    def burn() -> None:
        x = 0
        while not stop.is_set():
            x = (x * 31 + 7) % 1_000_003

    burners = [threading.Thread(target=burn, daemon=True) for _ in range(busy)]
    for b in burners:
        b.start()
    count = 0

    def on_swing(sample: zenoh.Sample) -> None:
        nonlocal count
        d = json.loads(sample.payload.to_bytes())
        seqs.setdefault(d["device_id"], []).append(int(d["seq"]))
        count += 1
        time.sleep(work_ms / 1000.0)
        if stall_every and count % stall_every == 0:
            time.sleep(stall_ms / 1000.0)

    with zenoh.open(observer_config(port)) as session:
        sub = session.declare_subscriber("gw/hook/*/swing", on_swing)
        time.sleep(duration_s)
        sub.undeclare()  # type: ignore[no-untyped-call]
    stop.set()
    out_path.write_text(json.dumps(seqs))


def loss(seqs: dict[str, list[int]]) -> tuple[int, int]:
    """(received, expected) over all hooks: expected = last - first + 1 per hook (one swing per packet)."""
    received = sum(len(set(s)) for s in seqs.values())
    expected = sum(max(s) - min(s) + 1 for s in seqs.values() if s)
    return received, expected


def run(hooks: int, duration_s: float, work: Path, work_ms: float = 4.0, stall_every: int = 50,
        stall_ms: float = 400.0, busy: int = 1) -> dict[str, list[int]]:  # fmt: skip
    """Gateway, `hooks` simulated hooks and the slow subscriber, each its own process; the subscriber's seqs."""
    zport, hport = free_port(), free_port()
    gw = start_gateway(work / "data", zport, hport, work / "gateway.log")
    out = work / "seqs.json"
    try:
        wait_http(hport)
        listener = subprocess.Popen(
            [sys.executable, "-m", "bench.hook_swing_qos", "--listen-only", "--port", str(zport),
             "--duration", str(duration_s + 4.0), "--out", str(out), "--work-ms", str(work_ms),
             "--stall-every", str(stall_every), "--stall-ms", str(stall_ms), "--busy", str(busy)],
            cwd=REPO,
        )  # fmt: skip
        time.sleep(1.5)
        subprocess.run(
            [sys.executable, "-m", "devices.sim_hook", "--count", str(hooks), "--samples-per-packet", "5",
             "--duration", str(duration_s), "--connect", f"tcp/127.0.0.1:{zport}", "--no-progress", "--seed", "3",
             "--no-truth"],
            cwd=REPO, capture_output=True, timeout=duration_s + 120, check=True,
        )  # fmt: skip
        listener.wait(timeout=duration_s + 60)
    finally:
        stop_process(gw)
    result: dict[str, list[int]] = json.loads(out.read_text()) if out.exists() else {}
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_swing_qos", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--hooks", type=int, default=4, help="simulated hooks (default: 4)")
    p.add_argument("--duration", type=float, default=20.0, help="seconds of hook data (default: 20)")
    p.add_argument("--work-ms", type=float, default=4.0, help="subscriber: time spent per message, ms")
    p.add_argument("--stall-every", type=int, default=50, help="subscriber: stall after this many messages (0: never)")
    p.add_argument("--stall-ms", type=float, default=400.0, help="subscriber: stall length, ms")
    p.add_argument("--busy", type=int, default=1, help="subscriber: CPU-burning threads")
    p.add_argument("--listen-only", action="store_true", help="(internal) run the subscriber process")
    p.add_argument("--port", type=int, default=7447, help="(with --listen-only) gateway zenoh port")
    p.add_argument("--out", type=Path, default=None, help="(with --listen-only) where to write the seqs")
    args = p.parse_args(argv)
    if args.listen_only:
        listen(args.port, args.duration, args.out, args.work_ms, args.stall_every, args.stall_ms, args.busy)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        seqs = run(args.hooks, args.duration, Path(tmp), args.work_ms, args.stall_every, args.stall_ms, args.busy)
    received, expected = loss(seqs)
    lost = 100.0 * (1.0 - received / expected) if expected else float("nan")
    print(f"{args.hooks} hooks, {args.duration:g} s, subscriber {args.work_ms:g} ms/message, "
          f"{args.stall_ms:g} ms stall every {args.stall_every}, {args.busy} busy thread(s): "
          f"received {received} of {expected} swing messages ({lost:.2f} % lost) from {len(seqs)} hooks")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
