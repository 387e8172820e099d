"""CPU per packet of `Pipeline.process` alone (no zenoh, no decode, no hub), at N simulated rods.

    python -m bench.pipeline_cost                              # this tree, 10 and 100 rods
    python -m bench.pipeline_cost --compare /work/wt/before    # also an older tree, same packets: both and the ratio

Packets come from the rod simulator (`devices.sim_rod.RodFleet`, 5 samples per packet at 100 Hz, reel status at
10 Hz, random bites/fights/wind on), are decoded once before timing, and go to the pipeline in batches as the
runner forms them when it keeps up: one batch per 50 ms packet period, holding every rod's packets of that period.
The first `--skip-s` seconds (warm-up windows, first compiles) are not timed. The figure is process CPU time
(`time.process_time`) per packet over the timed batches: on a shared machine it is inflated less than wall time.

`--compare DIR` runs each configuration in a child process per tree (PYTHONPATH set to the tree, so its own
`gateway` package is imported) with the same seed, `--repeat` times interleaved, and prints the least CPU per
packet of each tree and before/after, and whether both gave the same alarms and attitudes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


def measure(rods: int, seconds: float, skip_s: float, seed: int) -> dict[str, Any]:
    """CPU seconds per packet of `Pipeline.process` at `rods` rods (this interpreter's `gateway`)."""
    from devices.common import DeviceClock, FleetSettings
    from devices.rod_physics import RandomEventRates
    from devices.sim_rod import RodFleet
    from gateway import schemas
    from gateway.pipeline import Pipeline

    fleet = RodFleet(FleetSettings(count=rods, seed=seed, samples_per_packet=5, progress=False, id_prefix="rod"),
                     rates=RandomEventRates.lively())
    # the same wall clock every run (the simulator reads the real one), so runs can be compared output for output
    wall0_s = 1.8e9
    fleet.clocks = [DeviceClock(c.boot_offset_us, int(wall0_s * 1e6) - c.boot_offset_us) for c in fleet.clocks]
    n_ticks = int(round(seconds / fleet.fleet.period_s))
    batches = []
    for k in range(n_ticks):
        data, _ = fleet.tick(k)
        batches.append([schemas.decode(m.key, m.payload) for msgs in data for m in msgs
                        if not m.key.endswith("/truth")])  # fmt: skip
    pipeline = Pipeline()
    pipeline.warm_up()
    t_wall0 = wall0_s + 0.1
    skip = int(round(skip_s / fleet.fleet.period_s))
    cpu, packets = 0.0, 0
    alarms: list[list[Any]] = []
    atts: dict[str, list[float]] = {}
    for k, batch in enumerate(batches):
        now = t_wall0 + k * fleet.fleet.period_s
        t0 = time.process_time()
        out = pipeline.process(batch, now)
        dt = time.process_time() - t0
        if k >= skip:
            cpu += dt
            packets += len(batch)
        alarms += [[a.change.alarm.device_id, a.change.alarm.type, a.change.kind, str(a.change.alarm.severity),
                    round(a.change.alarm.started_at - wall0_s, 6)] for a in out.alarms]  # fmt: skip
        for a in out.attitudes:
            atts.setdefault(f"{a.device_id}/{a.seq}", [*a.quat_wxyz, a.roll_rad, a.pitch_rad, a.yaw_unwrapped_rad])
    return {"rods": rods, "packets": packets, "cpu_s": cpu, "ms_per_packet": 1e3 * cpu / packets,
            "alarms": sorted(alarms), "attitudes": atts}


def same_outputs(a: dict[str, Any], b: dict[str, Any]) -> str:
    """Whether two runs on the same packets gave the same alarms and attitudes (largest difference)."""
    if a["alarms"] != b["alarms"]:
        return f"ALARMS DIFFER ({len(a['alarms'])} vs {len(b['alarms'])})"
    if a["attitudes"].keys() != b["attitudes"].keys():
        return "ATTITUDE SETS DIFFER"
    diff = max((abs(x - y) for k, v in a["attitudes"].items() for x, y in zip(v, b["attitudes"][k], strict=True)),
               default=0.0)  # fmt: skip
    return f"same {len(a['alarms'])} alarm changes, {len(a['attitudes'])} attitudes within {diff:.1e}"


def _child(tree: Path, rods: int, args: argparse.Namespace) -> dict[str, Any]:
    """`measure` in a fresh interpreter running this file with PYTHONPATH=`tree`, so `gateway` is that tree's."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", str(rods), "--seconds", str(args.seconds),
           "--skip-s", str(args.skip_s), "--seed", str(args.seed)]  # fmt: skip
    res = subprocess.run(cmd, env=dict(os.environ, PYTHONPATH=str(tree)), check=True, capture_output=True, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.pipeline_cost", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rods", type=int, nargs="+", default=[10, 100], help="fleet sizes (default: 10 100)")
    p.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per fleet (default: 20)")
    p.add_argument("--skip-s", type=float, default=2.0, help="untimed start, s (default: 2)")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--compare", type=Path, default=None, help="another source tree (e.g. a worktree of main)")
    p.add_argument("--repeat", type=int, default=3, help="with --compare: runs per tree, interleaved; the least CPU "
                   "per packet is shown (the one least disturbed by other load; default: 3)")
    p.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child is not None:
        print(json.dumps(measure(args.child, args.seconds, args.skip_s, args.seed)))
        return 0
    here = Path(__file__).resolve().parents[1]
    print(f"Pipeline.process CPU per packet: rods at 100 Hz, 5 samples/packet, {args.seconds:g} s simulated "
          f"(first {args.skip_s:g} s untimed), seed {args.seed}")
    if args.compare is None:
        for n in args.rods:
            r = measure(n, args.seconds, args.skip_s, args.seed)
            print(f"{n:5d} rods: {r['ms_per_packet']:.4f} ms/packet ({r['packets']} packets, {r['cpu_s']:.2f} CPU s)")
        return 0
    print(f"{'rods':>5}  {'before ms/pkt':>13}  {'after ms/pkt':>12}  {'before/after':>12}   (before: {args.compare})")
    for n in args.rods:
        runs: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
        for _ in range(args.repeat):  # interleaved, so a burst of load on the shared machine hits both
            runs["before"].append(_child(args.compare.resolve(), n, args))
            runs["after"].append(_child(here, n, args))
        before, after = (min(runs[k], key=lambda r: r["ms_per_packet"]) for k in ("before", "after"))
        print(f"{n:5d}  {before['ms_per_packet']:13.4f}  {after['ms_per_packet']:12.4f}  "
              f"{before['ms_per_packet'] / after['ms_per_packet']:12.2f}   "
              f"({after['packets']} packets; {same_outputs(before, after)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
