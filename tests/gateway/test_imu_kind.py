"""The plain `imu` kind: any IMU device gets attitude and height, no rod or hook rules; lost samples are bridged with a
line (a rod's gyro is tapered in gaps)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from bench.link_loss import broad_total_deg, fused_quats, lost_packets, packets
from gateway import schemas
from gateway.ingest.bus import MemoryBus
from tests.gateway.conftest import Running, serve_packets


def test_an_imu_packet_decodes_as_json_and_binary_and_its_outputs_have_keys() -> None:
    pkt = schemas.ImuPacket(v=1, device_id="imu-1", kind="imu", boot_id=3, seq=4, t0_us=0, rate_hz=200.0,
                            gyr_rad_s=[(0.0, 0.0, 0.1)], acc_m_s2=[(0.0, 0.0, 9.81)])  # fmt: skip
    key = schemas.imu_key("imu", "imu-1")
    assert key == "rig/imu/imu-1/imu" and schemas.decode(key, pkt.to_json()) == pkt
    binary = schemas.imu_binary(device_id="imu-1", kind="imu", boot_id=3, seq=4, t0_us=0, rate_hz=200.0,
                                gyr_rad_s=[(0.0, 0.0, 0.1)], acc_m_s2=[(0.0, 0.0, 9.81)])  # fmt: skip
    decoded = schemas.decode(key, binary)
    assert isinstance(decoded, schemas.ImuPacket) and decoded.kind == "imu"
    with pytest.raises(schemas.DecodeError):  # the kind code must equal the key's kind
        schemas.decode(schemas.imu_key("rod", "imu-1"), binary)
    assert schemas.attitude_key("imu", "imu-1") == "gw/imu/imu-1/attitude"


def _through_service(tmp_path: Path, kind: str, trial: object, seconds: float) -> MemoryBus:
    t = trial
    pkts = packets("dev-1", kind, t.gyr_rad_s, t.acc_m_s2, t.mag_uT, t.rate_hz, 10)  # type: ignore[attr-defined]
    return serve_packets(tmp_path / kind, pkts[: int(seconds * t.rate_hz / 10)])[0]  # type: ignore[attr-defined]


def test_a_recording_played_as_imu_gets_the_rods_attitude_and_no_alarms(tmp_path: Path, broad_dir: Path) -> None:
    """BROAD trial 24 (a real IMU, tapped): as a rod it raised bite, drop-back and line alarms; as `imu` none, with the
    same attitude, bit for bit (no loss: nothing differs but the rules)."""
    from gateway.fusion import broad

    path = broad_dir / "24_disturbed_tapping_A.mat"
    if not path.is_file():
        pytest.skip(f"BROAD trial 24 not under {broad_dir}")
    trial = broad.load_trial(path)
    out = {kind: _through_service(tmp_path, kind, trial, 60.0) for kind in ("rod", "imu")}

    def messages(bus: MemoryBus, topic: str) -> list[dict[str, object]]:
        return [json.loads(p) for k, p, _ in bus.sent if k.startswith("gw/") and k.endswith("/" + topic)]

    assert messages(out["rod"], "alarm"), "the rod's rules see bites in a tapped hand-held IMU"
    assert messages(out["imu"], "alarm") == []
    rod, imu = messages(out["rod"], "attitude"), messages(out["imu"], "attitude")
    assert len(imu) > 1500 and [m["quat_wxyz"] for m in imu] == [m["quat_wxyz"] for m in rod]
    assert {k.split("/")[1] for k, _, _ in out["imu"].sent if k.startswith("gw/imu/")} == {"imu"}
    assert messages(out["imu"], "height"), "heights too"


def test_an_imu_crosses_lost_packets_on_a_line_where_a_rod_tapers(broad_dir: Path) -> None:
    """BROAD trial 03 (slow rotations), 2 % of 10-sample packets lost in bursts of 2 (`bench.link_loss`'s link for
    it): the `imu` kind's line keeps the rotation inside each gap that a rod's tapered gyro drops (7.17° -> 2.05°
    total RMSE; 1.94° without loss, where both are the same filter)."""
    from gateway.fusion import broad

    path = broad_dir / "03_undisturbed_slow_rotation_C.mat"
    if not path.is_file():
        pytest.skip(f"BROAD trial 03 not under {broad_dir}")
    trial = broad.load_trial(path)
    total = {}
    for kind in ("rod", "imu"):
        pkts = packets("dev-1", kind, trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT, trial.rate_hz, 10)
        lost = lost_packets(len(pkts), 0.02, 2.0, 9_001)
        kept = [p for p, gone in zip(pkts, lost, strict=True) if not gone]
        q = fused_quats(kept, len(pkts) * 10, kind, 2.0)
        total[kind] = broad_total_deg(trial, q, np.repeat(~lost, 10))
    assert total["imu"] < 0.5 * total["rod"], total


def test_rest_serves_the_imu_kind_defaults_and_refuses_fields_it_has_not(running: Callable[[], Running]) -> None:
    app = running()
    assert app.client.get("/api/thresholds/imu").json() == {}
    r = app.client.put("/api/thresholds/imu", json={"tilt_warn_deg": 5}, headers=app.auth)
    assert r.status_code == 422 and "tilt_warn_deg" in r.text
    assert app.client.put("/api/thresholds/imu", json={}, headers=app.auth).status_code == 200
