"""bench.fleet end to end at a tiny size: the load generator, the real gateway and the observer agree on counts."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench import fleet

pytestmark = pytest.mark.slow


def test_pool_bodies_decode_as_imu_packets() -> None:
    """A pooled body plus the patched header is a valid ImuPacket (the generator never builds invalid JSON)."""
    from gateway import schemas

    pools = fleet.build_pool("hook", 2, 0.2, 5, seed=3)
    assert len(pools) == 2 and len(pools[0]) == 4
    payload = ('{"v":1,"device_id":"fleet-hook-0001","kind":"hook","boot_id":7,"seq":3,"t0_us":150000,'
               f'"wall_t0_us":1767225610420000,{pools[1][3]}}}')
    p = schemas.decode("rig/hook/fleet-hook-0001/imu", payload.encode())
    assert isinstance(p, schemas.ImuPacket) and p.n == 5 and p.seq == 3


@pytest.mark.parametrize("shards", [1, 2])
def test_small_fleet_through_the_gateway(tmp_path: Path, shards: int) -> None:
    """4 devices for 3 s: every device reaches the gateway (with 2 shards: the counts of both are summed), nearly
    every packet is processed, attitudes arrive."""
    pools = {k: fleet.build_pool(k, 2, 2.0, 5, seed=1) for k in ("rod", "hook")}
    pool_path = tmp_path / "pool.pickle"
    import pickle

    pool_path.write_bytes(pickle.dumps(pools))
    row = fleet.run_one(4, 0.25, pools, pool_path, 5, 1, duration_s=3.0, warmup_s=2.0, work=tmp_path,
                       shards=shards)  # fmt: skip
    assert row.shards == shards
    assert row.sent == 4 * 5.0 * 20  # 4 devices x (2 + 3) s x 20 packets/s
    assert row.devices_seen == 4
    assert row.processed >= 0.98 * row.sent, row
    assert row.attitudes > 0 and row.attitude_p99_ms == row.attitude_p99_ms  # measured, not NaN
    assert row.cpu_ms_per_packet > 0


def test_binary_pool_packets_decode_with_the_patched_header() -> None:
    """--encoding binary: the generator's patched v2 header + id + pooled rows is the pooled packet, re-addressed."""
    import struct

    from gateway import schemas

    json_pool = fleet.build_pool("rod", 1, 0.1, 5, seed=3)
    head, rows = fleet.build_pool("rod", 1, 0.1, 5, seed=3, encoding="binary")[0][1]  # type: ignore[misc]
    h = bytearray(head)
    ident = b"fleet-rod-0007"
    fleet.BIN_IDS.pack_into(h, 2, fleet.KIND_CODES["rod"], len(ident))
    fleet.BIN_SEQ.pack_into(h, 8, 1006, 42, 210_000)
    fleet.BIN_WALL.pack_into(h, 32, 1_767_225_610_420_000)
    p = schemas.decode("rig/rod/fleet-rod-0007/imu", bytes(h) + ident + rows)
    assert isinstance(p, schemas.ImuPacket)
    assert (p.boot_id, p.seq, p.t0_us, p.wall_t0_us, p.n) == (1006, 42, 210_000, 1_767_225_610_420_000, 5)
    twin = schemas.decode("rig/rod/fleet-rod-0007/imu", (
        '{"v":1,"device_id":"fleet-rod-0007","kind":"rod","boot_id":1006,"seq":42,"t0_us":210000,'
        f'"wall_t0_us":1767225610420000,{json_pool[0][1]}}}').encode())
    assert isinstance(twin, schemas.ImuPacket)
    for a, b in zip(twin.arrays(), p.arrays(), strict=True):
        assert a is not None and b is not None and (a.astype("float32") == b).all()
    assert struct.unpack_from("<B", h)[0] == schemas.IMU_BINARY_MAGIC
