"""Decode throughput of `gateway.schemas.decode` on realistic IMU packets, packets per CPU-second, in one run:
the pydantic path (`decode(..., fast=False)`, the reference), the msgspec fast path (`decode`, the default) and
the same packets in the binary encoding (protocol v2, float32 samples).

    python -m bench.decode_speed                 # 10-sample 9-axis packets, 20000 decodes per path
    python -m bench.decode_speed --samples 5 --packets 50000

Also prints, for scale, a bare `json.loads` of the same bytes (no validation), and what ingest pays until the fusion
bank has the samples as arrays: batches decoded together (`schemas.decode_many`) and gathered (`gather_all`), where a
binary packet never builds its float tuples. The gateway's target is 1000 devices x 10 packets/s = 10k packets/s.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable

import numpy as np

from devices.common import ImuErrorModel, SensorModel, imu_payload
from gateway import schemas
from gateway.fusion.bank import gather_all
from gateway.ingest.runner import collect_between_batches, tune_gc


def make_packets(n_packets: int, samples: int, with_mag: bool, seed: int = 0) -> list[bytes]:
    """Distinct packets with noisy sensor values like a device at rest sends."""
    rng = np.random.default_rng(seed)
    sensor = SensorModel(ImuErrorModel(), 1, rng)
    out = []
    for k in range(min(n_packets, 1000)):
        gyr, acc, mag = sensor.measure(np.zeros((samples, 3)), np.tile([0.0, 0.0, 9.81], (samples, 1)),
                                       np.tile([0.0, 20.0, -44.0], (samples, 1)) if with_mag else None, 0.01)
        out.append(imu_payload(device_id="rod-1", kind="rod", boot_id=1, seq=k, t0_us=10_000 * k, rate_hz=100.0,
                               gyr_rad_s=gyr, acc_m_s2=acc, mag_uT=mag, wall_t0_us=1_767_225_600_000_000 + k,
                               temp_c=24.5, battery_v=4.1, rssi_dbm=-60.0))
    return out


def rates(fns: dict[str, tuple[Callable[[bytes], object], list[bytes]]], n: int, rounds: int = 20,
          ) -> dict[str, float]:
    """Calls per CPU-second of each fn(payload) over n calls cycling through its packets. CPU time of this process,
    and the functions take turns in `rounds` slices, so load from other processes on a shared machine falls on all
    of them alike and the ratios hold even when the absolute figures move."""
    cpu = dict.fromkeys(fns, 0.0)
    per = max(1, n // rounds)
    for r in range(rounds):
        for name, (f, packets) in fns.items():
            t = time.process_time()
            for i in range(r * per, (r + 1) * per):
                f(packets[i % len(packets)])
            cpu[name] += time.process_time() - t
    return {name: per * rounds / cpu[name] for name in fns}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.decode_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--packets", type=int, default=20_000, help="decodes to time (default: 20000)")
    p.add_argument("--samples", type=int, default=10, help="samples per packet (default: 10)")
    p.add_argument("--no-mag", action="store_true", help="6-axis packets")
    args = p.parse_args(argv)
    packets = make_packets(args.packets, args.samples, not args.no_mag)
    key = schemas.imu_key("rod", "rod-1")
    assert schemas.decode(key, packets[0]).n == args.samples
    assert all(schemas.decode(key, b) == schemas.decode(key, b, fast=False) for b in packets[:100])
    binary = [schemas.imu_to_binary(schemas.decode(key, b)) for b in packets]  # type: ignore[arg-type]
    got = rates({"slow": (lambda b: schemas.decode(key, b, fast=False), packets),
                 "fast": (lambda b: schemas.decode(key, b), packets),
                 "binary": (lambda b: schemas.decode(key, b), binary),
                 "json": (json.loads, packets)}, args.packets)  # fmt: skip
    slow_rate, fast_rate, json_rate = got["slow"], got["fast"], got["json"]
    size = sum(map(len, packets)) / len(packets)
    print(f"packet: {args.samples} samples, {'6' if args.no_mag else '9'}-axis, {size:.0f} bytes")
    print(f"decode, pydantic (before):      {slow_rate:>9,.0f} packets per CPU-second "
          f"= {slow_rate * args.samples:,.0f} samples/s")
    print(f"decode, msgspec fast path (now): {fast_rate:>8,.0f} packets per CPU-second "
          f"= {fast_rate * args.samples:,.0f} samples/s; {fast_rate / slow_rate:.2f}x")
    print(f"binary v2 ({sum(map(len, binary)) / len(binary):.0f} bytes):           {got['binary']:>8,.0f} packets per "
          f"CPU-second; {got['binary'] / slow_rate:.2f}x")
    print(f"json.loads only (no validation): {json_rate:>8,.0f} packets per CPU-second; fast/json.loads = "
          f"{fast_rate / json_rate:.2f}")
    # what ingest pays until the fusion bank has arrays: a batch decoded together, then gathered per device, with
    # the garbage collector run as the ingest loop runs it (between batches)
    tune_gc()
    per = 500
    batches = {name: [[(key, b) for b in src[i:i + per]] for i in range(0, len(src) - per + 1, per)]
               for name, src in (("json", packets), ("binary", binary))}  # fmt: skip
    got = rates({name: (_to_arrays, b) for name, b in batches.items()}, max(1, args.packets // per))
    print(f"to arrays (decode_many of {per}-packet batches + fusion.bank.gather_all, one packet per device), "
          f"packets per CPU-second: JSON {got['json'] * per:,.0f}, binary {got['binary'] * per:,.0f} "
          f"({got['binary'] / got['json']:.2f}x)")
    return 0


def _to_arrays(batch: list[tuple[str, bytes]]) -> object:
    packets = schemas.decode_many(batch)
    arrays = gather_all([[p] for p in packets if isinstance(p, schemas.ImuPacket)])
    del packets, arrays
    collect_between_batches()
    return None


if __name__ == "__main__":
    raise SystemExit(main())
