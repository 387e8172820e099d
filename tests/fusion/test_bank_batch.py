"""The fusion bank's batch path (`FusionBank.fuse` on shared arrays, `gather_batch`) against its per-device path:
the same fused blocks, packet ends, device state, failures and time gaps, bit for bit, on random batches."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from gateway import schemas
from gateway.fusion import bank as bank_mod
from gateway.fusion.bank import FusionBank, gather
from gateway.kinds.base import Fused
from gateway.pipeline import Output, Pipeline

KINDS = ("rod",) * 6 + ("hook",) * 2 + ("imu",)
CALIBRATION = {"acc_offset_m_s2": [0.1, -0.05, 0.2], "acc_scale": [1.01, 0.99, 1.0], "mag_offset_uT": [3.0, -2.0, 1.0],
               "mag_soft_iron": [[1.02, 0.0, 0.0], [0.0, 0.98, 0.0], [0.0, 0.0, 1.0]], "n_poses": 6,
               "acc_fit_rms_m_s2": 0.01, "mag_fit_rms_uT": 0.2}  # fmt: skip


class Device:
    """One simulated device: its kind, sensors, packet size and rate, and where its packets are in time."""

    def __init__(self, rng: np.random.Generator, j: int) -> None:
        self.kind = KINDS[j % len(KINDS)]
        self.device_id = f"{self.kind}-{j}"
        self.mag = bool(rng.random() < 0.6)
        self.spp = int(rng.choice([4, 5, 10]))
        self.rate_hz = 100.0
        self.seq, self.t0_us = 0, int(rng.integers(0, 10**6))
        self.wall = bool(rng.random() < 0.7)
        self.tilt = rng.normal(0.0, 0.3, 3)


def packet(rng: np.random.Generator, d: Device, diverge: bool) -> schemas.ImuPacket:
    """The device's next packet (a packet or a few lost before it now and then, a late t0_us, a 6-wide packet from
    a 9D device, a rate change), in the JSON or the binary form (float32 rows); `diverge`: one absurd rate."""
    if rng.random() < 0.08:  # packets lost
        lost = int(rng.integers(1, 4))
        d.seq += lost
        d.t0_us += lost * round(d.spp * 1e6 / d.rate_hz)
    if rng.random() < 0.03:
        d.rate_hz = 50.0 if d.rate_hz == 100.0 else 100.0
    jitter = int(rng.choice([0, 0, 0, 8000, 40000])) if rng.random() < 0.1 else 0  # late stamp, or a time gap
    n = d.spp
    gyr = rng.normal(0.0, 0.05, (n, 3))
    if diverge:
        gyr[n // 2] = 1e300
    acc = np.array([0.0, 0.0, 9.81]) + d.tilt + rng.normal(0.0, 0.1, (n, 3))
    mag = np.array([20.0, 5.0, -40.0]) + rng.normal(0.0, 0.5, (n, 3)) if d.mag and rng.random() > 0.05 else None
    gyr_s, acc_s = [tuple(r) for r in gyr.tolist()], [tuple(r) for r in acc.tolist()]
    fields: dict[str, Any] = {
        "v": 1, "device_id": d.device_id, "kind": d.kind, "boot_id": 7, "seq": d.seq, "t0_us": d.t0_us + jitter,
        "rate_hz": d.rate_hz, "gyr_rad_s": gyr_s, "acc_m_s2": acc_s,
        "mag_uT": None if mag is None else [tuple(r) for r in mag.tolist()],
        "wall_t0_us": 1_800_000_000_000_000 + d.t0_us if d.wall else None,
    }  # fmt: skip
    d.seq += 1
    d.t0_us += round(n * 1e6 / d.rate_hz)
    if diverge:  # past validation: a sample that makes the filter diverge (a non-finite quaternion: a failure)
        return schemas.ImuPacket.model_construct(**fields)
    p = schemas.ImuPacket(**fields)
    if rng.random() < 0.5:
        decoded = schemas.decode_many([(schemas.imu_key(d.kind, d.device_id), schemas.imu_to_binary(p))])[0]
        assert isinstance(decoded, schemas.ImuPacket)
        return decoded
    return p


def batches(seed: int, n_batches: int) -> list[dict[str, list[schemas.ImuPacket]]]:
    """Random batches of a random number of devices: some send nothing in a batch, some two packets."""
    rng = np.random.default_rng(seed)
    devices = [Device(rng, j) for j in range(int(rng.integers(3, 25)))]
    out = []
    for k in range(n_batches):
        imu: dict[str, list[schemas.ImuPacket]] = {}
        for d in devices:
            if rng.random() < 0.15:
                continue
            count = 2 if rng.random() < 0.2 else 1
            diverge = k > 12 and rng.random() < 0.02
            imu[d.device_id] = [packet(rng, d, diverge and i == 0) for i in range(count)]
        order = list(imu)
        rng.shuffle(order)  # arrival order
        out.append({dev_id: imu[dev_id] for dev_id in order})
    return out


def fused_state(fused: list[Fused], bank: FusionBank, out: Output) -> list[Any]:
    """Everything a batch gave, as comparable values (arrays as bytes: bit for bit)."""
    rows: list[Any] = [repr(out.filter_failures), repr(out.time_gaps)]
    for f in fused:
        d = f.dev
        rows.append((d.device_id, f.q.tobytes(), f.gyr.tobytes(), f.acc.tobytes(), f.t_s.tobytes(), f.ends,
                     d.t_us, d.seq, d.wall_offset_us, d.wall_from_device, d.follows, d.dt_s, d.last_t_s))  # fmt: skip
    if bank.batch is not None:
        rows.append((tuple(bank.batch.device_ids), bank.batch.states.tobytes()))
    return rows


def _no_shared_arrays(groups: list[list[schemas.ImuPacket]]) -> bank_mod.Gathered:
    raise ValueError("per-device path")


@pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning")  # the diverging samples
@pytest.mark.parametrize("seed", range(6))
def test_the_batch_path_is_the_per_device_path(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Rods, hooks and IMUs (6D and 9D, some calibrated), packets of 4, 5 and 10 samples in the JSON and binary
    forms, devices that skip a batch or send two packets, lost packets, late and gapped t0_us, rate changes and a
    diverging filter now and then: `fuse` on the shared arrays gives what it gives with every device gathered alone
    (`gather`, which `_blocks` falls back to, and so the per-device copies, gap checks and packet ends)."""
    fast, ref = Pipeline(), Pipeline()
    data = batches(seed, 40)
    for d in sorted({d for imu in data for d in imu})[::3]:
        for p in (fast, ref):
            p.bank.set_calibration(d, CALIBRATION)
    for k, imu in enumerate(data):
        now = 1.8e9 + 0.05 * k
        out_fast, out_ref = Output(), Output()
        got = fused_state(fast.bank.fuse(imu, now, out_fast), fast.bank, out_fast)
        with monkeypatch.context() as m:
            m.setattr(bank_mod, "gather_batch", _no_shared_arrays)
            m.setattr(bank_mod, "gather_all", lambda groups: [gather(g) for g in groups])
            want = fused_state(ref.bank.fuse(imu, now, out_ref), ref.bank, out_ref)
        assert got == want, f"batch {k}"
    assert fast.bank.devices.keys() == ref.bank.devices.keys()
