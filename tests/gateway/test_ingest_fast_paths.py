"""`GatewayService.handle`'s batched binary decode (`schemas.decode_many`: headers and rows checked for the whole
batch, the rest decoded alone) against the per-packet reference (`schemas.decode` of each), on random streams of
binary IMU packets with hostile edits: the same packets reach the pipeline and every counter (received, rejects
by reason, per-device sequence figures, time and wall-time drops) is the same."""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway import schemas
from gateway.app import compose
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus
from gateway.pipeline import Output
from gateway.store import Store

DEVICES = ("rod-1", "rod-2", "hook-1")
EDITS = ("none", "none", "none", "none", "seq_jump", "seq_back", "repeat", "reboot", "t0_back", "t0_jump",
         "wall_far", "rate", "flip_head", "flip_body", "cut", "other_key", "other_kind", "nan", "beyond",
         "json")  # fmt: skip


def _packet(device: str, k: int, edit: str, rng: np.random.Generator) -> tuple[str, bytes]:
    """Packet `k` of a device (10 samples at 100 Hz; optional fields there or not), with one hostile or unusual
    edit."""
    kind = "hook" if device.startswith("hook") else "rod"

    def maybe(value: Any) -> Any:
        return value if rng.random() < 0.7 else None

    fields: dict[str, Any] = {
        "device_id": device, "kind": kind, "boot_id": 7, "seq": k, "t0_us": 100_000 * k, "rate_hz": 100.0,
        "gyr_rad_s": rng.normal(0, 0.1, (10, 3)), "acc_m_s2": rng.normal(0, 1, (10, 3)) + [0, 0, 9.8],
        "mag_uT": maybe(rng.normal(0, 20, (10, 3))), "wall_t0_us": maybe(1_800_000_000_000_000 + k),
        "temp_c": maybe(21.5), "battery_v": maybe(3.9), "rssi_dbm": maybe(-60.25), "depth_m": maybe(1.5),
    }  # fmt: skip
    key = schemas.imu_key(kind, device)
    match edit:
        case "seq_jump":
            fields["seq"] = k + 5
        case "seq_back":
            fields["seq"] = max(0, k - 3)
        case "reboot":
            fields["boot_id"] = 8
        case "t0_back":
            fields["t0_us"] = max(0, 100_000 * k - 5_000_000)
        case "t0_jump":
            fields["t0_us"] = 100_000 * k + 4_000_000_000
        case "wall_far":
            fields["wall_t0_us"] = 0
        case "rate":
            fields["rate_hz"] = 2001.0
        case "other_key":
            key = schemas.imu_key("rod", "rod-9")
        case "other_kind":
            key = schemas.imu_key("rod" if kind == "hook" else "hook", device)
        case "nan":
            fields["gyr_rad_s"][3, 1] = np.nan
        case "beyond":
            fields["acc_m_s2"][0, 0] = 400.5
    payload = bytearray(schemas.imu_binary(**fields))
    if edit == "json":
        payload = bytearray(schemas.decode(key, bytes(payload)).to_json())  # a JSON packet among binary ones
    elif edit == "flip_head":
        payload[1 + int(rng.integers(0, schemas.IMU_BINARY_HEADER.size - 1))] ^= 1 << int(rng.integers(0, 8))
    elif edit == "flip_body":
        payload[int(rng.integers(schemas.IMU_BINARY_HEADER.size, len(payload)))] ^= 0xFF
    elif edit == "cut":
        del payload[int(rng.integers(1, len(payload))):]
    return key, bytes(payload)


def _per_packet(items: Sequence[tuple[str, bytes]]) -> list[schemas.Packet | schemas.DecodeError]:
    """The reference: `decode` of each packet alone."""
    out: list[schemas.Packet | schemas.DecodeError] = []
    for key, payload in items:
        try:
            out.append(schemas.decode(key, payload))
        except schemas.DecodeError as err:
            out.append(err)
    return out


class _Lines(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def _run(batches: list[list[tuple[str, bytes]]], tmp: Path) -> tuple[list[Any], str, list[str]]:
    """What reaches the pipeline (one row per packet), the counters' snapshot after the batches, the log lines."""
    store = Store(tmp / "gw.db")
    svc = compose(Settings(data_dir=tmp, zenoh_listen=[]), MemoryBus(), store, blocking_thread=False)
    seen: list[Any] = []

    def process(packets: list[schemas.Packet], now: float) -> Output:
        for p in packets:
            assert isinstance(p, schemas.ImuPacket)
            seen.append((p.device_id, p.kind, p.boot_id, p.seq, p.t0_us, p.rate_hz, p.wall_t0_us, p.temp_c,
                         p.has_mag, p.model_fields_set, p.to_json()))  # fmt: skip
        return Output()

    svc.pipeline.process = process  # type: ignore[method-assign]
    log, lines = logging.getLogger("gateway.ingest"), _Lines()
    log.addHandler(lines)
    try:
        for i, batch in enumerate(batches):
            svc.handle([(key, payload, 10.0 + i) for key, payload in batch], now_wall_s=1.8e9 + i)
        return seen, svc.counters.snapshot(0).model_dump_json(), lines.lines
    finally:
        log.removeHandler(lines)
        svc.writer.close()
        store.close()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(DEVICES), st.sampled_from(EDITS)), min_size=1, max_size=80),
       st.lists(st.integers(1, 40), min_size=1, max_size=8), st.integers(0, 2**32 - 1))  # fmt: skip
def test_batched_decode_ingests_like_decode_of_each(stream: list[tuple[str, str]], cuts: list[int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    sent: dict[str, int] = {}
    packets = []
    for device, edit in stream:
        k = sent[device] = sent.get(device, -1) + 1
        packets.append(_packet(device, k, edit, rng))
    batches, i = [], 0
    for size in [*cuts, len(packets)]:
        if i < len(packets):
            batches.append(packets[i : i + size])
            i += size
    with tempfile.TemporaryDirectory() as a, tempfile.TemporaryDirectory() as b:
        got = _run(batches, Path(a))
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(schemas, "decode_many", _per_packet)
            want = _run(batches, Path(b))
    assert got == want
