"""Hostile input fuzz of a running gateway (issue 13): REST from its OpenAPI schema (schemathesis) and zenoh packets.

REST: schemathesis generates requests for every operation of the gateway's OpenAPI schema (valid and invalid
parameters and bodies, with and without the token) against a real HTTP server (uvicorn on a free port, the app on
an in-memory bus and a real SQLite file). Pass: 0 responses >= 500.

zenoh: a real zenoh session on loopback sends valid rod streams interleaved with hostile packets of many kinds
(garbage bytes, oversized, bad JSON, wrong types, extreme numbers, arbitrary and invalid keys, spoofed boot ids,
extreme timestamps, liveliness tokens with bad ids, puts on the gateway's own keys; binary (protocol v2) packets with
damaged bytes, cut short, header sizes that lie, NaN or infinite samples, a wrong key or kind, extreme times). Every
second valid stream is sent in the binary encoding. Pass: the gateway stays up,
every valid packet is counted, every reject is counted by reason, REST, health and the live stream still answer,
RSS growth stays bounded.

    python -m bench.hostile_fuzz                       # full size: 300 REST cases per operation, 100k packets
    python -m bench.hostile_fuzz --rest-examples 20 --packets 3000     # the CI size (tests/gateway/test_fuzz.py)
"""

from __future__ import annotations

import argparse
import json
import math
import random
import resource
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import uvicorn
import zenoh
from fastapi import FastAPI
from fastapi.testclient import TestClient

from bench.bite_latency import free_port, observer_config
from devices.common import FleetSettings
from devices.sim_rod import RodFleet
from gateway import schemas
from gateway.app import create_app
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus, key_matches

# -- REST ----------------------------------------------------------------------------------------------------------


@dataclass
class RestServer:
    base: str
    token: str
    app: FastAPI


@contextmanager
def rest_server(data_dir: Path) -> Iterator[RestServer]:
    """The gateway app (MemoryBus, real SQLite) served by uvicorn on a free loopback port, in a thread."""
    bus = MemoryBus()
    app = create_app(Settings(data_dir=data_dir, zenoh_listen=[]), lambda _: bus, warm_up=False)
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while not server.started:
            assert thread.is_alive() and time.monotonic() < deadline, "REST server did not start"
            time.sleep(0.05)
        for device_id, kind in (("rod-1", "rod"), ("hook-1", "hook"), ("ball-1", "ball")):  # something to find
            bus.set_alive(schemas.device_token_key(kind, device_id), True)
        yield RestServer(f"http://127.0.0.1:{port}", (data_dir / "api_token").read_text().strip(), app)
    finally:
        server.should_exit = True
        thread.join(timeout=15)


def fuzz_rest(server: RestServer, examples: int, seed: int = 0) -> dict[str, Any]:
    """schemathesis cases for every operation, half with the token; returns counts by operation and status."""
    import schemathesis
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    schema = schemathesis.openapi.from_dict(server.app.openapi())
    statuses: Counter[int] = Counter()
    errors: list[str] = []
    ops = 0
    for result in schema.get_all_operations():
        op = result.ok()
        ops += 1

        @given(case=op.as_strategy(), with_token=st.booleans())
        @settings(max_examples=examples, deadline=None, database=None, derandomize=True,
                  suppress_health_check=list(HealthCheck))  # fmt: skip
        def run(case: Any, with_token: bool) -> None:
            headers = {"Authorization": f"Bearer {server.token}"} if with_token else {}
            r = case.call(base_url=server.base, headers=headers, timeout=30)
            statuses[r.status_code] += 1
            if r.status_code >= 500:
                errors.append(f"{case.method} {case.formatted_path} -> {r.status_code}: {r.text[:200]}")

        run()
    return {"operations": ops, "requests": sum(statuses.values()), "statuses": dict(sorted(statuses.items())),
            "server_errors": errors}  # fmt: skip


# -- zenoh -----------------------------------------------------------------------------------------------------------


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@dataclass
class HostileSource:
    """Hostile packets by kind; `template` is a valid rod IMU payload to mutate."""

    template: dict[str, Any]
    rng: random.Random
    kinds: Counter[str] = field(default_factory=Counter)

    def _imu(self, **changes: Any) -> bytes:
        return json.dumps(self.template | changes).encode()

    def _bin(self, **changes: Any) -> bytes:
        """The template (or it changed) in the binary encoding (protocol v2, docs/protocol.md 3.6)."""
        fields = {k: v for k, v in (self.template | changes).items() if k not in ("v", "gnss")}
        return schemas.imu_binary(**fields)

    def _bin_damaged(self, dev: str) -> bytes:
        """A binary packet with 1-3 random bytes replaced (header, id or samples), or cut short, or its header's
        sample count or id length lying about the size."""
        r, b = self.rng, bytearray(self._bin(device_id=dev))
        how = r.randrange(3)
        if how == 0:
            for _ in range(r.randrange(1, 4)):
                b[r.randrange(len(b))] = r.randrange(256)
        elif how == 1:
            del b[r.randrange(1, len(b)):]
        else:  # n (uint16 at byte 4) or the id length (byte 3) rewritten
            if r.random() < 0.5:
                b[4:6] = r.choice([0, 1, 2, 65535]).to_bytes(2, "little")
            else:
                b[3] = r.choice([0, 1, 255])
        return bytes(b)

    def next(self) -> tuple[str, str, bytes]:
        """(kind, key, payload)."""
        r = self.rng
        dev = f"x{r.randrange(10**6)}"
        key = f"rig/rod/{dev}/imu"
        choices: list[tuple[str, str, bytes]] = [
            ("garbage", key, r.randbytes(r.randrange(1, 2000))),
            ("huge", key, b"[" * (schemas.MAX_PAYLOAD_BYTES + 1)),
            ("bad_json", key, b'{"v": 1, "device_id": '),
            ("wrong_types", f"rig/rod/{dev}/imu", self._imu(device_id=dev, seq="one", rate_hz=[1])),
            ("extreme_numbers", f"rig/rod/{dev}/imu", self._imu(device_id=dev, gyr_rad_s=[[1e308, -1e308, 0.0]])),
            ("nan_text", key, self._imu(device_id=dev).replace(b"0.0", b"NaN", 1)),
            ("unknown_key", f"rig/rod/{dev}/nope", self._imu(device_id=dev)),
            ("invalid_id_key", f"rig/rod/{dev}.evil/imu", self._imu(device_id=dev)),
            ("key_mismatch", "rig/rod/rod-1/imu", self._imu(device_id="rod-2")),
            ("spoofed_boot", "rig/rod/rod-1/imu", self._imu(boot_id=r.randrange(2**32), seq=r.randrange(2**32))),
            ("wall_time_extreme", f"rig/rod/{dev}/imu", self._imu(device_id=dev, wall_t0_us=r.choice([0, 2**63 - 1]))),
            ("t0_extreme", f"rig/rod/{dev}/imu", self._imu(device_id=dev, t0_us=r.choice([0, 2**62, 2**63 - 1]))),
            ("env_on_rod", f"rig/rod/{dev}/env", b"{}"),
            ("gateway_key", "gw/rod/rod-1/alarm", b'{"alarm": "bite"}'),
            ("reel_cmd", "rig/rod/rod-1/reel/cmd", b'{"v":1,"cmd_id":1,"action":"out","speed_m_s":1.5}'),
            ("bin_damaged", key, self._bin_damaged(dev)),
            ("bin_not_finite", key, self._bin(device_id=dev, gyr_rad_s=self._rows(r.choice([math.nan, math.inf])))),
            ("bin_key_mismatch", "rig/rod/rod-1/imu", self._bin(device_id="rod-2")),
            ("bin_kind_mismatch", f"rig/hook/{dev}/imu", self._bin(device_id=dev)),
            ("bin_t0_extreme", key, self._bin(device_id=dev, t0_us=r.choice([0, 2**62, 2**63 - 1]))),
        ]  # fmt: skip
        kind, k, p = r.choice(choices)
        self.kinds[kind] += 1
        return kind, k, p

    def _rows(self, bad: float) -> list[list[float]]:
        """The template's gyro rows with one value replaced by `bad`."""
        rows = [list(row) for row in self.template["gyr_rad_s"]]
        rows[self.rng.randrange(len(rows))][self.rng.randrange(3)] = bad
        return rows


def fuzz_zenoh(data_dir: Path, packets: int, seed: int = 0, valid_streams: int = 4) -> dict[str, Any]:
    """`packets` hostile packets interleaved with `valid_streams` simulated rods (20 packets/s each, as fast as the
    link takes them) into an in-process gateway on a real zenoh session; returns the figures."""
    rng = random.Random(seed)
    port = free_port()
    settings = Settings(data_dir=data_dir, zenoh_listen=[f"tcp/127.0.0.1:{port}"], ingest_queue_size=200_000)
    fleet = RodFleet(FleetSettings(count=valid_streams, seed=seed, samples_per_packet=5, progress=False,
                                   id_prefix="rod"))  # fmt: skip
    with TestClient(create_app(settings, warm_up=False)) as client, zenoh.open(observer_config(port)) as session:
        probe = session.declare_publisher(schemas.imu_key("rod", "rod-1"))
        deadline = time.monotonic() + 30
        while not probe.matching_status.matching:
            assert time.monotonic() < deadline, "gateway subscription not seen"
            time.sleep(0.05)
        probe.undeclare()
        template: dict[str, Any] | None = None
        src: HostileSource | None = None
        tokens = [session.liveliness().declare_token(f"rig/rod/evil{i}.tok") for i in range(20)]
        rss0 = _rss_mb()
        valid = hostile = subscribed = 0
        t0 = time.monotonic()
        tick = 0
        block = zenoh.CongestionControl.BLOCK
        while hostile < packets:
            data, _ = fleet.tick(tick)
            tick += 1
            for i, dev_msgs in enumerate(data):
                for m in dev_msgs:
                    if not m.key.endswith("/imu"):
                        continue
                    if template is None:
                        template = json.loads(m.payload)
                        src = HostileSource(template, rng)
                    if i % 2:  # every second valid stream in the binary encoding, as a v2 device sends it
                        payload = schemas.imu_to_binary(schemas.ImuPacket.model_validate_json(m.payload))
                        session.put(m.key, payload, encoding=schemas.ENCODING_IMU_BINARY, congestion_control=block)
                    else:
                        session.put(m.key, m.payload, congestion_control=block)
                    valid += 1
            assert src is not None
            for _ in range(max(1, packets // 500)):  # ~500 ticks: 25 s of data per valid stream
                _, key, payload = src.next()
                try:
                    session.put(key, payload, congestion_control=block)
                    subscribed += any(key_matches(sel, key) for sel in schemas.SEL_DEVICE_DATA)
                except zenoh.ZError:  # keys zenoh itself refuses never leave this process
                    src.kinds["refused_by_zenoh"] += 1
                hostile += 1
        sent_s = time.monotonic() - t0
        expected = valid + subscribed  # hostile packets on keys the gateway subscribes to
        deadline = time.monotonic() + 300
        while (got := client.get("/api/stats").json()["received"]) < expected:
            assert time.monotonic() < deadline, f"gateway counted {got} of {expected} packets"
            time.sleep(0.2)
        stats = client.get("/api/stats").json()
        devices = {d["device_id"]: d for d in client.get("/api/devices").json()}
        health = client.get("/api/health").json()
        live = client.app.state.live  # type: ignore[attr-defined]
        frame = live.tick_frame(time.time())
        rss1 = _rss_mb()
        for t in tokens:
            t.undeclare()
    return {
        "valid_sent": valid, "hostile_sent": hostile, "hostile_kinds": dict(src.kinds), "send_s": round(sent_s, 1),
        "received": stats["received"], "expected": expected, "queue_drops": stats["queue_drops"],
        "rejected": stats["rejected"], "filter_restarts": stats["filter_restarts"],
        "valid_ok": sum(devices[f"rod-{i + 1}"]["loss_fraction"] == 0.0 for i in range(valid_streams)),
        "valid_streams": valid_streams, "devices_known": len(devices), "health": health["status"],
        "invalid_tokens": stats["invalid_tokens"], "tick_devices": len(frame["devices"]),
        "raw_buffers": len(live._imu) + len(live._env), "rss_mb": (round(rss0, 1), round(rss1, 1)),
    }  # fmt: skip


def main(rest_examples: int, packets: int, seed: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        with rest_server(Path(tmp) / "rest") as server:
            t0 = time.monotonic()
            rest = fuzz_rest(server, rest_examples, seed)
        print(f"REST: {rest['requests']} requests over {rest['operations']} operations in "
              f"{time.monotonic() - t0:.1f} s; statuses {rest['statuses']}; "
              f"server errors: {len(rest['server_errors'])}")
        for e in rest["server_errors"][:10]:
            print("  ", e)
        z = fuzz_zenoh(Path(tmp) / "zenoh", packets, seed)
    print(f"zenoh: {z['hostile_sent']} hostile packets ({len(z['hostile_kinds'])} kinds) among {z['valid_sent']} "
          f"valid ones in {z['send_s']} s; gateway counted {z['received']} of {z['expected']} expected, "
          f"queue drops {z['queue_drops']}")
    print(f"  rejected by reason: {z['rejected']}")
    print(f"  valid streams without loss: {z['valid_ok']}/{z['valid_streams']}; devices known {z['devices_known']}; "
          f"health {z['health']}; invalid tokens {z['invalid_tokens']}; tick frame devices {z['tick_devices']}; "
          f"raw buffers {z['raw_buffers']}; RSS {z['rss_mb'][0]} -> {z['rss_mb'][1]} MB")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rest-examples", type=int, default=300, help="schemathesis cases per operation")
    ap.add_argument("--packets", type=int, default=100_000, help="hostile zenoh packets")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    main(a.rest_examples, a.packets, a.seed)
