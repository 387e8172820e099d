"""REST under an ingest backlog, in process: N rods' packets put at once on a MemoryBus app (the real app, routes,
middleware and ingest task; no zenoh), then `GET /api/stats` every 0.2 s until the backlog is processed.

    python -m bench.rest_overload                  # 100 rods x 6 s of packets (12 000 at once)
    python -m bench.rest_overload --rods 300 --seconds 4

Prints the CPU per packet of the whole process (ingest + REST) and the /api/stats latency p50/max while the
gateway works through the backlog: an overloaded gateway always has a batch waiting, so this is the wait REST
sees under overload without the noise of a zenoh fleet (`bench.fleet` has the REST column for that).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from fastapi.testclient import TestClient

from devices.common import FleetSettings
from devices.sim_rod import RodFleet
from gateway.app import create_app
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus


def packets(rods: int, seconds: float) -> list[tuple[str, bytes]]:
    """IMU packets of `rods` simulated rods (5 samples at 100 Hz each), in time order."""
    fleet = RodFleet(FleetSettings(count=rods, seed=1, samples_per_packet=5, progress=False, id_prefix="rod"))
    out = []
    for k in range(int(seconds / 0.05)):
        data, _ = fleet.tick(k)
        out += [(m.key, m.payload) for dev in data for m in dev if m.key.endswith("/imu")]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.rest_overload", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--rods", type=int, default=100)
    p.add_argument("--seconds", type=float, default=6.0, help="seconds of packets per rod, put at once")
    args = p.parse_args(argv)
    msgs = packets(args.rods, args.seconds)
    bus = MemoryBus()
    with tempfile.TemporaryDirectory(prefix="rig-rest-") as tmp:
        settings = Settings(data_dir=Path(tmp) / "data", zenoh_listen=[], ingest_queue_size=len(msgs) + 1)
        with TestClient(create_app(settings, lambda _: bus, warm_up=False)) as client:
            client.get("/api/stats")
            latency_s: list[float] = []
            cpu0, t0 = time.process_time(), time.perf_counter()
            for key, payload in msgs:
                bus.put(key, payload, encoding="application/json")
            while True:
                a = time.perf_counter()
                stats = client.get("/api/stats").json()
                latency_s.append(time.perf_counter() - a)
                if stats["received"] >= len(msgs):
                    break
                time.sleep(0.2)
            cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - t0
    latency_s.sort()
    print(f"{len(msgs)} packets of {args.rods} rods at once: CPU {1e3 * cpu_s / len(msgs):.3f} ms/packet, "
          f"drained in {wall_s:.1f} s in {stats['batches']} batches; /api/stats during it: n={len(latency_s)}, "
          f"p50 {latency_s[len(latency_s) // 2]:.3f} s, max {latency_s[-1]:.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
