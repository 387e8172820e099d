"""CPU per packet of `Pipeline.process` alone (no zenoh, no decode, no hub), at N simulated rods; or, with
`--stage ingest`, of `GatewayService.handle` all-in without zenoh.

    python -m bench.pipeline_cost                              # this tree, 10 and 100 rods
    python -m bench.pipeline_cost --compare <tree>             # also an older tree, same packets: both and the ratio
    python -m bench.pipeline_cost --stage ingest --rods 300 --seconds 8 --compare <tree>   # all-in, two trees
    python -m bench.pipeline_cost --stage ingest --rods 300 --profile /tmp/ingest.prof        # where it goes
    python -m bench.pipeline_cost --stage ingest --rods 300 --encoding binary --compare <tree>  # protocol v2 packets
    python -m bench.pipeline_cost --stage ingest --rods 1000 --encoding binary --gil-threads 2   # with GIL pressure
    python -m bench.pipeline_cost --stage ingest --rods 1000 --encoding binary --drop 0.5 --compare <tree>  # overload

`--stage ingest`: 80 % rods / 20 % hooks (`--hook-share`), JSON packets as `bench.fleet` sends them (its pooled
simulator streams, `--spp` samples per packet), one batch per packet period holding every device's packet, through
the service `gateway.app.compose` builds (decode, sequence and time checks, pipeline, hub with its blocking-put
thread) with the sinks `create_app` wires (dashboard history, live stream without clients, metrics),
`runner.tune_gc` and `runner.collect_between_batches` as the ingest task calls them. The bus only digests what is
put, so zenoh's own cost is not in it (`bench.fleet` has it). The figure is process CPU (all threads) per packet
over the timed batches; "handle" is the calling thread's. With `--compare` it also says whether both trees published
the same messages, byte for byte (alarm ids made deterministic, the hub's clock set to the batch's time).

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


# -- all-in: GatewayService.handle (decode, checks, pipeline, hub, dashboard sinks), no zenoh ----------------------

class _CountingBus:
    """A bus that only counts and digests what is put (zenoh's own cost is not in the figure); order-free digest so
    two trees' outputs compare even if they publish in another order."""

    def __init__(self) -> None:
        import threading

        self.puts = 0
        self.digest = 0
        self._lock = threading.Lock()  # the blocking-put thread puts too

    def put(self, key: str, payload: bytes, *, encoding: str, block: bool = False, express: bool = False) -> None:
        import hashlib

        h = int.from_bytes(hashlib.blake2b(key.encode() + b"\0" + payload, digest_size=8).digest(), "big")
        with self._lock:
            self.puts += 1
            self.digest ^= h

    def subscribe(self, selector: str, callback: Any) -> Any:
        return lambda: None

    def watch_liveliness(self, selector: str, callback: Any) -> None:
        return None

    def declare_token(self, key: str) -> None:
        return None

    def declare_queryable(self, selector: str, handler: Any, *, encoding: str) -> None:
        return None

    def close(self) -> None:
        return None


def ingest_payloads(n: int, hook_share: float, seconds: float, spp: int, seed: int, wall0_s: float
                    ) -> list[list[tuple[str, bytes]]]:  # fmt: skip
    """Per packet period, every device's encoded IMU packet (JSON, as `bench.fleet` sends them: pooled simulated
    streams of rods and hooks, 16 per kind, header fields patched per device). Cached in the temp directory: the
    simulators take a minute, and two trees compared must get the same bytes."""
    import pickle
    import tempfile

    from bench.fleet import RATE_HZ, build_pool

    cache = Path(tempfile.gettempdir()) / f"pipeline_cost-{n}-{hook_share}-{seconds}-{spp}-{seed}-{wall0_s}.pkl"
    if cache.is_file():
        with cache.open("rb") as f:
            cached: list[list[tuple[str, bytes]]] = pickle.load(f)
        return cached

    hooks = int(round(n * hook_share))
    kinds = ["rod"] * (n - hooks) + ["hook"] * hooks
    period_s = spp / RATE_HZ
    pools = {k: build_pool(k, 16, seconds, spp, seed) for k in sorted(set(kinds))}
    out = []
    for k in range(int(round(seconds / period_s))):
        batch = []
        for j, kind in enumerate(kinds):
            body = pools[kind][j % 16]
            t0_us = k * round(period_s * 1e6)
            wall_t0_us = int((wall0_s + k * period_s) * 1e6)
            dev = f"{kind}{j:04d}"
            batch.append((f"rig/{kind}/{dev}/imu", (
                f'{{"v":1,"device_id":"{dev}","kind":"{kind}","boot_id":{1000 + j},"seq":{k},"t0_us":{t0_us},'
                f'"wall_t0_us":{wall_t0_us},{body[k % len(body)]}}}').encode()))  # fmt: skip
        out.append(batch)
    tmp = cache.with_suffix(f".{os.getpid()}")
    with tmp.open("wb") as f:
        pickle.dump(out, f)
    tmp.replace(cache)
    return out


class _AttitudeReaderBus(_CountingBus):
    """A counting bus whose only subscriber takes the attitude keys."""

    def subscribed(self, key: str, *, encoding: str, block: bool = False, express: bool = False) -> bool:
        return key.endswith("/attitude")


class _BatchReaderBus(_CountingBus):
    """A counting bus whose only subscriber takes the batched attitudes (`gw/attitudes`)."""

    def subscribed(self, key: str, *, encoding: str, block: bool = False, express: bool = False) -> bool:
        return key == "gw/attitudes"


def join_periods(batches: list[list[Any]], k: int) -> list[list[Any]]:
    """Each run of `k` packet periods' batches as one, in order (the last may hold fewer): a gateway that waits `k`
    periods per batch, so each batch holds `k` packets of every device."""
    if k < 1:
        raise ValueError(f"periods per batch must be at least 1, not {k}")
    return [[it for b in batches[i:i + k] for it in b] for i in range(0, len(batches), k)]


def measure_ingest(n: int, seconds: float, skip_s: float, seed: int, spp: int = 10, hook_share: float = 0.2,
                   profile: Path | None = None, encoding: str = "json", gil_threads: int = 0,
                   subscribed: str = "all", batch_size: int = 0, drop: float = 0.0,
                   periods_per_batch: int = 1) -> dict[str, Any]:  # fmt: skip
    """CPU seconds per packet of `GatewayService.handle` at `n` devices, with the sinks `create_app` wires (dashboard
    history, live stream without clients, metrics) and the blocking-put thread; the bus only digests the puts.
    `batch_size`: each packet period's packets handed over in batches of at most this many (0: one batch), as a
    gateway that keeps up takes what arrived since its last batch.
    `periods_per_batch`: each batch holds that many packet periods' packets (`join_periods`), as a gateway that
    waits longer for a batch (`ingest_coalesce_s`) or runs behind.
    `drop`: after the untimed start, each packet is left out with this probability (seeded), as a gateway's full
    inbox drops packets under overload; `ms_per_offered` is then the CPU per packet sent, which a gateway that sheds
    load must lower (each dropped packet's filter work shed with it), not raise.
    `encoding="binary"`: the packets in the binary IMU encoding (protocol v2, as `bench.fleet --encoding binary`).
    `gil_threads`: that many threads each take the GIL 1000 times a second for a moment (ten deque appends), as
    zenoh's receive threads do when they call a subscriber callback per packet: what that costs the ingest thread.
    `subscribed="attitude"`: only attitude keys have a subscriber (as `bench.fleet`'s observer), so a gateway that
    asks its bus (`Bus.subscribed`) neither makes nor puts the heights; "batch": only `gw/attitudes` has one (as
    `bench.fleet --observe batch`); "all": every key has one."""
    import asyncio
    import tempfile

    from bench.fleet import RATE_HZ
    from gateway.api import ws
    from gateway.api.routes import history, metrics
    from gateway.app import compose
    from gateway.config import Settings
    from gateway.ingest import runner
    from gateway.store import Store

    wall0_s = 1.8e9  # a fixed wall clock (as `measure`): two trees' runs compare output for output
    batches = ingest_payloads(n, hook_share, seconds, spp, seed, wall0_s)
    if encoding == "binary":
        from gateway import schemas

        batches = [[(key, schemas.imu_to_binary(schemas.decode(key, payload)))  # type: ignore[arg-type]
                    for key, payload in batch] for batch in batches]  # fmt: skip
    batches = join_periods(batches, periods_per_batch)
    period_s = spp / RATE_HZ * periods_per_batch
    skip = int(round(skip_s / period_s))
    offered = sum(len(b) for b in batches[skip:])
    if drop > 0.0:
        import numpy as np

        rng = np.random.default_rng(seed + 1)
        batches = batches[:skip] + [[it for it, x in zip(b, rng.random(len(b)).tolist(), strict=True) if x >= drop]
                                    for b in batches[skip:]]  # fmt: skip

    import collections
    import threading

    stop = threading.Event()

    def take_the_gil(box: collections.deque[int]) -> None:
        while not stop.wait(0.001):
            for i in range(10):
                box.append(i)

    for _ in range(gil_threads):
        threading.Thread(target=take_the_gil, args=(collections.deque(maxlen=100),), daemon=True).start()

    async def run() -> dict[str, Any]:
        bus = {"all": _CountingBus, "attitude": _AttitudeReaderBus, "batch": _BatchReaderBus}[subscribed]()
        with tempfile.TemporaryDirectory() as tmp:
            store = Store(Path(tmp) / "gw.db")
            service = compose(Settings(data_dir=Path(tmp), zenoh_listen=[]), bus, store)  # type: ignore[arg-type]
            service.pipeline.warm_up()
            tune_gc = getattr(runner, "tune_gc", None)  # as the ingest task does after the warm-up (if the tree has it)
            if tune_gc is not None:
                tune_gc()
            between = getattr(runner, "collect_between_batches", lambda: None)  # as the ingest loop, after each batch
            ids = iter(range(10**9))
            service.pipeline.engine._new_id = lambda: f"a{next(ids)}"  # type: ignore[method-assign]
            app = type("App", (), {"state": type("State", (), {})()})()
            live, hist = ws.start_live(app, service), history.start_history(app, service)
            metrics.start_metrics(app, service)
            cpu0, packets, prof, handle_s = 0.0, 0, None, 0.0
            for k, batch in enumerate(batches):
                now = wall0_s + (k + 1) * period_s
                service.hub.clock = lambda now=now: now  # type: ignore[misc]
                mono = time.monotonic()
                items = [(key, payload, mono) for key, payload in batch]
                if k == skip:
                    cpu0 = time.process_time()
                    if profile is not None:
                        import cProfile

                        prof = cProfile.Profile()
                        prof.enable()
                t0 = time.thread_time()
                step = batch_size if batch_size > 0 else len(items)
                for i in range(0, len(items), step):
                    service.handle(items[i:i + step], now)
                    between()
                if k >= skip:
                    handle_s += time.thread_time() - t0
                    packets += len(batch)
            assert service.hub.publisher is not None
            service.hub.publisher.close()  # its thread's puts are in the process CPU
            cpu = time.process_time() - cpu0
            if prof is not None:
                prof.disable()
                prof.dump_stats(str(profile))
            await live.stop()
            await hist.stop()
            store.close()
        return {"devices": n, "packets": packets, "cpu_s": cpu, "ms_per_packet": 1e3 * cpu / packets,
                "offered": offered, "ms_per_offered": 1e3 * cpu / offered,
                "handle_ms_per_packet": 1e3 * handle_s / packets, "puts": bus.puts,
                "digest": f"{bus.digest:016x}"}  # fmt: skip

    try:
        return asyncio.run(run())
    finally:
        stop.set()


def same_outputs(a: dict[str, Any], b: dict[str, Any]) -> str:
    """Whether two runs on the same packets gave the same alarms and attitudes (largest difference), or (all-in
    stage) the same published messages, byte for byte."""
    if "digest" in a:
        same = a["digest"] == b["digest"] and a["puts"] == b["puts"]
        return f"{'same' if same else 'DIFFERENT'} {a['puts']} / {b['puts']} published messages"
    if a["alarms"] != b["alarms"]:
        return f"ALARMS DIFFER ({len(a['alarms'])} vs {len(b['alarms'])})"
    if a["attitudes"].keys() != b["attitudes"].keys():
        return "ATTITUDE SETS DIFFER"
    diff = max((abs(x - y) for k, v in a["attitudes"].items() for x, y in zip(v, b["attitudes"][k], strict=True)),
               default=0.0)  # fmt: skip
    return f"same {len(a['alarms'])} alarm changes, {len(a['attitudes'])} attitudes within {diff:.1e}"


def _child(tree: Path, rods: int, args: argparse.Namespace) -> dict[str, Any]:
    """`measure` (or `measure_ingest`) in a fresh interpreter running this file with PYTHONPATH=`tree`, so
    `gateway` is that tree's (the bench module is this one)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", str(rods), "--seconds", str(args.seconds),
           "--skip-s", str(args.skip_s), "--seed", str(args.seed), "--stage", args.stage, "--spp", str(args.spp),
           "--encoding", args.encoding, "--gil-threads", str(args.gil_threads), "--subscribed", args.subscribed,
           "--batch-size", str(args.batch_size), "--drop", str(args.drop),
           "--periods-per-batch", str(args.periods_per_batch), "--hook-share", str(args.hook_share)]
    here = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{here}" if args.stage == "ingest" else str(tree))
    res = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    return json.loads(res.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.pipeline_cost", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rods", type=int, nargs="+", default=[10, 100],
                   help="fleet sizes (default: 10 100; with --stage ingest: devices, 20 %% of them hooks)")
    p.add_argument("--seconds", type=float, default=20.0, help="simulated seconds per fleet (default: 20)")
    p.add_argument("--skip-s", type=float, default=2.0, help="untimed start, s (default: 2)")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--stage", choices=("pipeline", "ingest"), default="pipeline",
                   help="pipeline: Pipeline.process alone (default); ingest: GatewayService.handle all-in")
    p.add_argument("--spp", type=int, default=10, help="with --stage ingest: samples per packet (default 10)")
    p.add_argument("--encoding", choices=("json", "binary"), default="json",
                   help="with --stage ingest: the IMU packets' encoding (default json; binary: protocol v2)")
    p.add_argument("--profile", type=Path, default=None, help="with --stage ingest: cProfile of the timed part here")
    p.add_argument("--compare", type=Path, default=None, help="another source tree (e.g. a worktree of main)")
    p.add_argument("--repeat", type=int, default=3, help="with --compare: runs per tree, interleaved; the least CPU "
                   "per packet is shown (the one least disturbed by other load; default: 3)")
    p.add_argument("--gil-threads", type=int, default=0, help="with --stage ingest: threads that each take the GIL "
                   "1000 times a second, as zenoh's receive threads calling a callback per packet (default 0)")
    p.add_argument("--subscribed", choices=("all", "attitude", "batch"), default="all",
                   help="with --stage ingest: which output keys have a subscriber: all (default), only the per-device "
                        "attitudes (bench.fleet's observer), or only gw/attitudes (bench.fleet --observe batch)")
    p.add_argument("--periods-per-batch", type=int, default=1, help="with --stage ingest: each batch holds this many "
                   "packet periods' packets (default 1: one packet per device)")
    p.add_argument("--batch-size", type=int, default=0, help="with --stage ingest: hand each packet period's packets "
                   "over in batches of at most this many (default 0: one batch per period)")
    p.add_argument("--drop", type=float, default=0.0, help="with --stage ingest: leave out this share of the timed "
                   "packets at random, as a full inbox drops them (default 0); the CPU per packet offered is shown")
    p.add_argument("--hook-share", type=float, default=0.2, help="with --stage ingest: share of the devices that are "
                   "hooks (default 0.2; 1: hooks only, e.g. to see whether their lost packets shed work)")
    p.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)

    def run(n: int) -> dict[str, Any]:
        if args.stage == "ingest":
            return measure_ingest(n, args.seconds, args.skip_s, args.seed, args.spp, args.hook_share, args.profile,
                                  encoding=args.encoding, gil_threads=args.gil_threads, subscribed=args.subscribed,
                                  batch_size=args.batch_size, drop=args.drop,
                                  periods_per_batch=args.periods_per_batch)
        return measure(n, args.seconds, args.skip_s, args.seed)

    if args.child is not None:
        print(json.dumps(run(args.child)))
        return 0
    here = Path(__file__).resolve().parents[1]
    if args.stage == "ingest":
        print(f"GatewayService.handle all-in CPU per packet (process CPU incl. the blocking-put thread; handle = the "
              f"ingest thread): {100 - round(100 * args.hook_share)} % rods / {round(100 * args.hook_share)} % hooks "
              f"at 100 Hz, {args.spp} samples/packet, {args.encoding}, one "
              f"batch per packet period, {args.seconds:g} s (first {args.skip_s:g} s untimed), seed {args.seed}"
              + (f", {args.gil_threads} GIL-taking threads" if args.gil_threads else "")
              + (f", {args.drop:.0%} of the timed packets dropped" if args.drop else ""))
    else:
        print(f"Pipeline.process CPU per packet: rods at 100 Hz, 5 samples/packet, {args.seconds:g} s simulated "
              f"(first {args.skip_s:g} s untimed), seed {args.seed}")
    if args.compare is None:
        for n in args.rods:
            r = run(n)
            extra = f", handle {r['handle_ms_per_packet']:.4f} ms, {r['puts']} puts" if "puts" in r else ""
            if args.drop:
                extra += f"; {r['ms_per_offered']:.4f} ms per packet offered ({r['offered']})"
            print(f"{n:5d} devices: {r['ms_per_packet']:.4f} ms/packet ({r['packets']} packets, {r['cpu_s']:.2f} CPU s"
                  f"{extra})")
        return 0
    print(f"{'n':>5}  {'before ms/pkt':>13}  {'after ms/pkt':>12}  {'before/after':>12}   (before: {args.compare})")
    for n in args.rods:
        runs: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
        for _ in range(args.repeat):  # interleaved, so a burst of load on the shared machine hits both
            runs["before"].append(_child(args.compare.resolve(), n, args))
            runs["after"].append(_child(here, n, args))
        before, after = (min(runs[k], key=lambda r: r["ms_per_packet"]) for k in ("before", "after"))
        handle = ""
        if "handle_ms_per_packet" in after:
            hb, ha = (min(r["handle_ms_per_packet"] for r in runs[k]) for k in ("before", "after"))
            handle = f"; handle thread {hb:.4f} -> {ha:.4f} ms ({hb / ha:.2f}x)"
        print(f"{n:5d}  {before['ms_per_packet']:13.4f}  {after['ms_per_packet']:12.4f}  "
              f"{before['ms_per_packet'] / after['ms_per_packet']:12.2f}   "
              f"({after['packets']} packets; {same_outputs(before, after)}{handle}"
              + (f"; per packet offered {before['ms_per_offered']:.4f} -> {after['ms_per_offered']:.4f} ms"
                 if args.drop else "") + ")")
    return 0


if __name__ == "__main__":
    sys.exit(main())
