"""Do a batch's bursts of DROP puts reach a subscriber in another process? The gateway's real `ZenohBus` (router
mode, loopback) puts `--devices` attitude-sized messages on as many keys every `--period` s (what one ingest batch
emits: one attitude per device), express or batched; a client subscriber in a child process counts what arrives.

    python -m bench.zenoh_burst                          # 300 and 1000 keys, express vs batched, 5 s each
    python -m bench.zenoh_burst --devices 1000 --seconds 10

zenoh queues a few batches per priority on each link; an express put is a batch of its own, so a burst of express
DROP puts overflows that queue and the rest are dropped. Batched, the same burst packs ~250 messages per batch.
The gateway's DROP streams (attitude, height, spots, diagnostics) are therefore not express (schemas.TOPICS);
BLOCK topics (alarms, swing, commands) stay express: a full queue makes them wait, never drop.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

import zenoh

from bench.bite_latency import REPO, free_port
from devices.common import zenoh_config
from gateway import schemas
from gateway.ingest.bus import ZenohBus

PAYLOAD = (b'{"device_id":"rod-0001","kind":"rod","seq":123,"t_us":123456789,"wall_t_us":1764662400000000,'
           b'"quat_wxyz":[0.99,0.01,0.02,0.03],"roll_rad":0.01,"pitch_rad":0.02,"yaw_rad":0.03,'
           b'"yaw_unwrapped_rad":0.03,"filter":"default"}')


def count_child(port: int, seconds: float) -> None:
    """Child process: subscribe to gw/** as a client for `seconds` and print how many samples arrived."""
    received = 0

    def on_sample(_: zenoh.Sample) -> None:
        nonlocal received
        received += 1

    with zenoh.open(zenoh_config("client", connect=(f"tcp/127.0.0.1:{port}",))) as session:
        session.declare_subscriber("gw/**", on_sample)
        time.sleep(seconds)
    print(received, flush=True)


def burst(devices: int, seconds: float, period_s: float, express: bool) -> tuple[int, int]:
    """(sent, received) for bursts of `devices` DROP puts every `period_s` over `seconds`."""
    port = free_port()
    with zenoh.open(zenoh_config("router", connect=(), listen=(f"tcp/127.0.0.1:{port}",))) as session:
        bus = ZenohBus(session)
        child = subprocess.Popen([sys.executable, "-m", "bench.zenoh_burst", "--child", str(port),
                                  "--seconds", str(seconds + 3.0)], cwd=REPO, stdout=subprocess.PIPE, text=True)
        keys = [schemas.T_ATTITUDE.key("rod", f"rod-{i:04d}") for i in range(devices)]
        time.sleep(1.5)  # the child's subscription reaches the router
        for key in keys:  # declare every publisher before the measured bursts
            bus.put(key, PAYLOAD, encoding=schemas.ENCODING_GW, express=express)
        time.sleep(0.5)
        sent, end = 0, time.monotonic() + seconds
        while time.monotonic() < end:
            t0 = time.monotonic()
            for key in keys:
                bus.put(key, PAYLOAD, encoding=schemas.ENCODING_GW, express=express)
            sent += devices
            time.sleep(max(0.0, period_s - (time.monotonic() - t0)))
        out, _ = child.communicate(timeout=seconds + 30)
        bus.close()
    return sent + devices, int(out.strip() or 0)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", type=int, nargs="+", default=[300, 1000], help="keys per burst")
    ap.add_argument("--seconds", type=float, default=5.0, help="measured seconds per case")
    ap.add_argument("--period", type=float, default=0.1, help="seconds between bursts (one ingest batch)")
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child is not None:
        count_child(a.child, a.seconds)
        return
    print(f"{'keys':>6} {'express':>8} {'sent':>8} {'received':>9} {'lost %':>7}")
    for n in a.devices:
        for express in (True, False):
            sent, received = burst(n, a.seconds, a.period, express)
            print(f"{n:>6} {str(express):>8} {sent:>8} {received:>9} {100.0 * (sent - received) / sent:>7.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
