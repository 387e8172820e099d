"""What zenoh costs a shard's session by how it subscribes: one wildcard subscriber or one per device.

    python -m bench.zenoh_subscribers                          # 1000 devices, 10,000 samples/s, 8 s per case
    python -m bench.zenoh_subscribers --devices 300 --rate 3000

A router session (as `python -m gateway` is), a client publishing 1 KB samples on `rig/rod/{a|b}{i}/imu` for the
devices round-robin, and a client subscriber (as a local shard is), each its own process. Cases:

- `catch-all`: one `rig/*/*/imu` subscriber, receives every sample (what a shard held before per-device
  subscriptions: it then drops the other shards' samples in its inbox);
- `catch-all-direct`: the same with its callbacks on zenoh's receive thread (`Callback(indirect=False)`);
- `catch-all-fifo`: the same as a `FifoChannel` that a Python thread empties every 2 ms (`try_recv` until empty): no
  callback per sample (tried as the gateway's intake and dropped: docs/gateway.md "How far one machine goes");
- `half-wildcard`: one `rig/*/a$*/imu`, receives half (the ideal: half the traffic, one subscriber);
- `half-per-device`: one exact-key subscriber per device of the `a` half, callbacks on zenoh's receive thread
  (`Callback(indirect=False)`: what a shard beside another now holds);
- `half-per-device-threads`: the same with zenoh-python's default callbacks, a Python thread per subscriber.

- `catch-all+tokens`: the catch-all while the subscriber also watches the devices' liveliness tokens (the
  publisher declares one a device, `rig/rod/{id}`), as every gateway does for presence;
- `catch-all+tokens+keys`: the same with the received keys declared (`Session.declare_keyexpr`), as
  `gateway.ingest.bus.RouteKeys` does: zenoh then caches each key's route instead of matching the key against every
  token on every sample.

The other catch-all and wildcard cases use the default callbacks, as the gateway's catch-all subscriptions do.

Prints the subscriber's and the router's CPU (share of one core) and the subscriber's CPU per received sample.
The callbacks only count (the gateway's do a little more: `Inbox.offer`). gateway/shard/subscriptions.py uses the
figures for its subscriber cap.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import threading
import time
from multiprocessing.synchronize import Event
from typing import Any

import zenoh

from bench.bite_latency import free_port
from devices.common import zenoh_config

CASES = ("catch-all", "catch-all-direct", "catch-all-fifo", "half-wildcard", "half-per-device",
         "half-per-device-threads", "catch-all+tokens", "catch-all+tokens+keys", "half-per-device+tokens",
         "half-per-device+tokens+keys", "half-buckets+tokens+keys", "half-buckets-threads+tokens+keys")


def _cpu_s() -> float:
    t = os.times()
    return t.user + t.system


def _key(i: int) -> str:
    return f"rig/rod/{'a' if i % 2 == 0 else 'b'}{i}/imu"


def router(ep: str, seconds: float, out: Any, start: Event, stop: Event) -> None:
    with zenoh.open(zenoh_config("router", connect=(), listen=(ep,))):
        out.put("up")
        start.wait()
        time.sleep(1.0)
        c0 = _cpu_s()
        time.sleep(seconds)
        out.put(("router", _cpu_s() - c0))
        stop.wait()


def publisher(ep: str, devices: int, rate: int, start: Event, stop: Event) -> None:
    with zenoh.open(zenoh_config("client", connect=(ep,))) as s:
        pubs = [s.declare_publisher(_key(i)) for i in range(devices)]
        tokens = [s.liveliness().declare_token(_key(i).rsplit("/", 1)[0]) for i in range(devices)]  # noqa: F841
        payload = b"x" * 1000
        start.wait()
        t0, k = time.perf_counter(), 0
        while not stop.is_set():
            due = int((time.perf_counter() - t0) * rate)
            while k < due:
                pubs[k % devices].put(payload)
                k += 1
            time.sleep(0.001)


def _drain(sub: Any, on_sample: Any, stop: Event) -> None:
    """Take what the FIFO holds every 2 ms (no callback, no wake-up per sample)."""
    while not stop.is_set():
        while (sample := sub.try_recv()) is not None:
            on_sample(sample)
        time.sleep(0.002)


def subscriber(ep: str, case: str, devices: int, seconds: float, out: Any, start: Event, stop: Event) -> None:
    with zenoh.open(zenoh_config("client", connect=(ep,))) as s:
        got = [0]

        def on_sample(sample: zenoh.Sample) -> None:
            str(sample.key_expr)
            sample.payload.to_bytes()
            got[0] += 1

        if case == "catch-all-direct":
            subs = [s.declare_subscriber("rig/*/*/imu", zenoh.handlers.Callback(on_sample, indirect=False))]
        elif case == "catch-all-fifo":
            subs = [s.declare_subscriber("rig/*/*/imu", zenoh.handlers.FifoChannel(10_000))]
            threading.Thread(target=_drain, args=(subs[0], on_sample, stop), daemon=True).start()
        elif case.startswith("catch-all"):
            subs = [s.declare_subscriber("rig/*/*/imu", on_sample)]
            if "+tokens" in case:
                subs.append(s.liveliness().declare_subscriber("rig/*/*", lambda sample: None, history=True))
            keys = [s.declare_keyexpr(_key(i)) for i in range(devices)] if "+keys" in case else []  # noqa: F841
        elif case == "half-wildcard":
            subs = [s.declare_subscriber("rig/*/a$*/imu", on_sample)]
        elif case.startswith("half-per-device") and case != "half-per-device-threads":
            subs = [s.declare_subscriber(_key(i), zenoh.handlers.Callback(on_sample, indirect=False))
                    for i in range(0, devices, 2)]  # fmt: skip
        elif case.startswith("half-buckets"):  # ids ending in an even digit: the even i, the `a` half
            subs = [s.declare_subscriber(f"rig/*/$*{d}/imu", on_sample if "-threads" in case else
                                         zenoh.handlers.Callback(on_sample, indirect=False)) for d in range(0, 10, 2)]
        else:
            subs = [s.declare_subscriber(_key(i), on_sample) for i in range(0, devices, 2)]
        if case.startswith("half") and "+tokens" in case:
            subs.append(s.liveliness().declare_subscriber("rig/*/*", lambda sample: None, history=True))
        if case.startswith("half") and "+keys" in case:
            keys = [s.declare_keyexpr(_key(i)) for i in range(0, devices, 2)]  # noqa: F841
        time.sleep(1.0)
        start.set()
        time.sleep(1.0)
        c0, n0 = _cpu_s(), got[0]
        time.sleep(seconds)
        out.put(("subscriber", len(subs), got[0] - n0, _cpu_s() - c0))
        stop.set()
        for sub in subs:
            sub.undeclare()  # type: ignore[no-untyped-call]


def run_case(case: str, devices: int, rate: int, seconds: float) -> dict[str, float]:
    ctx = mp.get_context("spawn")
    ep = f"tcp/127.0.0.1:{free_port()}"
    out, start, stop = ctx.Queue(), ctx.Event(), ctx.Event()
    procs = [ctx.Process(target=router, args=(ep, seconds, out, start, stop))]
    procs[0].start()
    assert out.get(timeout=30) == "up"
    procs += [ctx.Process(target=publisher, args=(ep, devices, rate, start, stop)),
              ctx.Process(target=subscriber, args=(ep, case, devices, seconds, out, start, stop))]  # fmt: skip
    for p in procs[1:]:
        p.start()
    got = {m[0]: m[1:] for m in (out.get(timeout=120), out.get(timeout=120))}
    for p in reversed(procs):
        p.join(10)
    subs, received, sub_cpu = got["subscriber"]
    return {"subscribers": subs, "received_per_s": received / seconds, "sub_cpu": sub_cpu / seconds,
            "sub_ms_per_sample": sub_cpu / max(received, 1) * 1e3,
            "router_cpu": got["router"][0] / seconds}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.zenoh_subscribers", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--devices", type=int, default=1000)
    p.add_argument("--rate", type=int, default=10000, help="samples per second, all devices (default 10000)")
    p.add_argument("--seconds", type=float, default=8.0, help="measured seconds per case (default 8)")
    p.add_argument("--rounds", type=int, default=2, help="cases alternate this many times (default 2)")
    p.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES), help="which cases (default: all)")
    args = p.parse_args(argv)
    print(f"{args.devices} devices, {args.rate} samples/s of 1 KB, {args.seconds:g} s per case")
    print("case                     subscribers  received/s  subscriber CPU  ms/sample  router CPU")
    for _ in range(args.rounds):
        for case in args.cases:
            r = run_case(case, args.devices, args.rate, args.seconds)
            print(f"{case:24s} {r['subscribers']:11.0f} {r['received_per_s']:11.0f} {r['sub_cpu']:14.1%} "
                  f"{r['sub_ms_per_sample']:10.4f} {r['router_cpu']:11.1%}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
