"""A gap in a device's own time (its seq follows on, its t0_us jumps ahead) is bridged and counted: a third party's
late timestamps used to change the attitude with no counter showing why."""

from __future__ import annotations

from pathlib import Path

from gateway import schemas
from tests.gateway.conftest import serve_packets


def _counted(tmp_path: Path, late_ms: dict[int, int], skip: set[int]) -> dict[str, int]:
    """`rejected` counters of one plain IMU (100 Hz, 10-sample packets, 4 s) whose packets `late_ms` carry a t0_us
    that many ms late and whose packets `skip` are lost (never sent)."""
    pkts = [schemas.ImuPacket(
        v=1, device_id="imu-1", kind="imu", boot_id=1, seq=seq, t0_us=seq * 100_000 + 1000 * late_ms.get(seq, 0),
        rate_hz=100.0, gyr_rad_s=[(0.0, 0.0, 0.2)] * 10, acc_m_s2=[(0.0, 0.0, 9.81)] * 10,
    ) for seq in range(40) if seq not in skip]  # fmt: skip
    return serve_packets(tmp_path / f"late{sorted(late_ms.items())}-skip{sorted(skip)}", pkts)[1]


def test_a_late_t0_us_with_seq_following_on_is_bridged_and_counted(tmp_path: Path) -> None:
    assert _counted(tmp_path, {}, set()) == {}
    assert _counted(tmp_path, {20: 20}, set()) == {}, "20 ms late: jitter, nothing bridged"
    assert _counted(tmp_path, {20: 40, 30: 60}, set()) == {"time_gap_bridged": 2}
    assert _counted(tmp_path, {}, {20, 21}) == {}, "lost packets are counted as lost, not as time gaps"
