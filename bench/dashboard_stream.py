"""Cost of the dashboard live stream: tick-frame build + encode per device count, fan-out per client, hub listener.

    python -m bench.dashboard_stream --devices 10 100 1000 --clients 50
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from tqdm import tqdm

from devices.common import FleetSettings
from devices.sim_rod import RodFleet
from gateway.api.ws import ClientQueue, LiveStream
from gateway.app import compose
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus
from gateway.store import Store


def measure(n: int, clients: int, reps: int) -> dict[str, float]:
    tmp = Path(tempfile.mkdtemp())
    settings = Settings(data_dir=tmp, zenoh_listen=[])
    bus, store = MemoryBus(), Store(tmp / "db.sqlite3")
    svc = compose(settings, bus, store, blocking_thread=False)
    live = LiveStream(svc)
    svc.hub.listeners.append(live.on_hub)  # as HubSink.start_sink wires it (without the tick task)
    svc.hub.plot_listeners.append(live.on_plot)
    svc.hub.packet_listeners.append(live.on_packet)
    live.clients.add(ClientQueue(256))  # the stream buffers only while someone reads it
    fleet = RodFleet(FleetSettings(count=n, seed=1, samples_per_packet=5, progress=False, id_prefix="rod"))
    now = time.time()
    for k in tqdm(range(20), desc=f"{n} rods: 1 s of packets", leave=False):
        data, _ = fleet.tick(k)
        items = []
        for dev in data:
            for m in dev:
                items.append((m.key, m.payload, time.monotonic()))
        svc.handle(items, now + k * 0.05)
    # one tick's worth of pending data is what a 10 Hz tick sees; refill the raw deques before each rep
    snapshot = {k: list(v) for k, v in live._imu.items()}
    series = {k: (list(s.t_s), {kk: list(vv) for kk, vv in s.values.items()}) for k, s in live._series.items()}
    t_build = 0.0
    t_full = 0.0
    size = 0
    for _ in tqdm(range(reps), desc=f"{n} rods: tick frames", leave=False):
        for k, v in snapshot.items():
            live._imu[k].extend(v[-2:])
        for k, (ts, vals) in series.items():
            s = live._series[k]
            s.t_s.extend(ts[-5:])
            for kk, vv in vals.items():
                s.values[kk].extend(vv[-5:])
        t0 = time.perf_counter()
        text = json.dumps(live.tick_frame(time.time(), full=False), separators=(",", ":"), default=str)
        t_build += time.perf_counter() - t0
        t0 = time.perf_counter()
        full = json.dumps(live.tick_frame(time.time(), full=True), separators=(",", ":"), default=str)
        t_full += time.perf_counter() - t0
        size = len(text) * 4 + len(full)  # per 5 ticks (cards_every)
    qs = [ClientQueue(256) for _ in range(clients)]
    t0 = time.perf_counter()
    for _ in range(1000):
        for q in qs:
            q.put(text)
    t_fan = (time.perf_counter() - t0) / (1000 * clients)
    store.close()
    return {"tick_ms": 1e3 * t_build / reps, "full_ms": 1e3 * t_full / reps, "kib_s": size / 1024 * 2,
            "put_us": 1e6 * t_fan}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--devices", type=int, nargs="+", default=[10, 100, 1000])
    p.add_argument("--clients", type=int, default=50)
    p.add_argument("--reps", type=int, default=20)
    a = p.parse_args()
    print(f"{'rods':>6} {'samples tick ms':>16} {'full tick ms':>13} {'CPU share (8+2 per s)':>22}"
          f" {'KiB/s per client':>17} {'put/client us':>14}")
    for n in a.devices:
        r = measure(n, a.clients, a.reps)
        share = (8 * r["tick_ms"] + 2 * r["full_ms"]) / 1000
        print(f"{n:>6} {r['tick_ms']:>16.2f} {r['full_ms']:>13.2f} {share:>22.1%}"
              f" {r['kib_s']:>17.0f} {r['put_us']:>14.3f}")


if __name__ == "__main__":
    main()
