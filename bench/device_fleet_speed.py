"""How many simulated rods one process can run in real time (physics + sensor model + JSON, no zenoh).

    python -m bench.device_fleet_speed                       # 1, 10, 100, 1000 rods, 5 samples/packet, with truth
    python -m bench.device_fleet_speed --counts 1000 --samples-per-packet 10 --no-truth

For each fleet size, prints the real-time factor (simulated seconds per CPU-second; >= 1 means the fleet keeps
up at that rate on one core) and the packets per CPU-second it builds. Also times RodSim.step, the closed-loop
API a reel controller uses, in steps per CPU-second.
"""

from __future__ import annotations

import argparse
import time

from tqdm import tqdm

from devices.common import FleetSettings
from devices.rod_physics import RodBank, RodSettings, RodSim
from devices.sim_rod import RodFleet


def fleet_rate(count: int, spp: int, truth: bool, ticks: int) -> tuple[float, float]:
    """(real-time factor, packets per CPU-second) of a RodFleet of `count` rods at 100 Hz."""
    f = RodFleet(FleetSettings(count=count, seed=1, samples_per_packet=spp, truth=truth, id_prefix="rod"))
    f.tick(0)
    packets = 0
    t = time.process_time()
    for k in tqdm(range(1, ticks + 1), desc=f"{count} rods", leave=False, mininterval=0.5):
        data, extra = f.tick(k)
        packets += sum(len(m) for m in data) + len(extra)
    cpu = time.process_time() - t
    return ticks * f.fleet.period_s / cpu, packets / cpu


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.device_fleet_speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--counts", type=int, nargs="+", default=[1, 10, 100, 1000], help="fleet sizes")
    p.add_argument("--samples-per-packet", type=int, default=5, help="samples per packet (default: 5)")
    p.add_argument("--no-truth", action="store_true", help="do not build truth packets")
    p.add_argument("--sim-seconds", type=float, default=2.0, help="simulated seconds per fleet size (default: 2)")
    args = p.parse_args(argv)
    spp = args.samples_per_packet
    ticks = max(1, round(args.sim_seconds * 100.0 / spp))
    print(f"rod fleet at 100 Hz, {spp} samples/packet, truth {'off' if args.no_truth else 'on'}")
    for count in args.counts:
        rtf, pps = fleet_rate(count, spp, not args.no_truth, ticks)
        print(f"  {count:5d} rods: real-time factor {rtf:7.2f}  ({pps:,.0f} packets per CPU-second)")
    sim = RodSim(RodSettings(), seed=1)
    t = time.process_time()
    for _ in range(1000):
        sim.step(0.01, 0.3)
    print(f"RodSim.step (1 rod, dt 10 ms): {1000 / (time.process_time() - t):,.0f} steps per CPU-second")
    bank = RodBank(RodSettings(), 1000, seed=1)
    t = time.process_time()
    for _ in range(100):
        bank.step(0.01, 0.3)
    print(f"RodBank.step (1000 rods, dt 10 ms): {100 * 1000 / (time.process_time() - t):,.0f} rod-steps per "
          "CPU-second")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
