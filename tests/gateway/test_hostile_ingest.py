"""Hostile and extreme device input (issue 13, items 2 and 3): a spoofed boot_id must not silence a device, and one
device's extreme but schema-valid timestamps cost only that device's output, counted by reason, logged rarely.

Runs `GatewayService.handle` directly on batches (as the ingest task does) with a MemoryBus and a real SQLite file,
so what is co-batched is exact."""

from __future__ import annotations

import contextlib
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from devices.common import FleetSettings
from devices.sim_rod import RodFleet
from gateway import protocol_doc, schemas
from gateway.app import compose
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus
from gateway.ingest.runner import GatewayService
from gateway.store import Store
from gateway.views import device_view

Msg = tuple[str, bytes]


def fleet_imu(seconds: float, count: int = 1, seed: int = 1) -> list[Msg]:
    """IMU packets (5 samples at 100 Hz, 20 a second per device) of `count` simulated rods, interleaved in time."""
    fleet = RodFleet(FleetSettings(count=count, seed=seed, samples_per_packet=5, progress=False, id_prefix="rod"))
    out = []
    for k in range(int(round(seconds / 0.05))):
        data, _ = fleet.tick(k)
        out += [(m.key, m.payload) for dev in data for m in dev if m.key.endswith("/imu")]
    return out


def edit(msg: Msg, **fields: object) -> Msg:
    p = json.loads(msg[1])
    p.update(fields)
    return msg[0], json.dumps(p).encode()


@contextlib.contextmanager
def service(tmp_path: Path) -> Iterator[tuple[GatewayService, MemoryBus, Store]]:
    """A service on a MemoryBus and a real SQLite file; its store writer is flushed and closed at the end."""
    bus, store = MemoryBus(), Store(tmp_path / "gw.db")
    svc = compose(Settings(data_dir=tmp_path, zenoh_listen=[]), bus, store, blocking_thread=False)
    try:
        yield svc, bus, store
    finally:
        svc.writer.close()
        store.close()


def run(svc: GatewayService, msgs: list[Msg], batch: int = 1) -> None:
    """Feed in batches at the simulated pace (2 devices x 20 packets/s: 0.025 s a packet); one packet a batch by
    default, as ingest takes them when it keeps up (attitudes are coalesced to one per device per batch)."""
    t0 = time.time()
    for i in range(0, len(msgs), batch):
        svc.handle([(k, p, i * 0.025) for k, p in msgs[i : i + batch]], now_wall_s=t0 + i * 0.025)


def attitudes(bus: MemoryBus, device_id: str) -> list[dict[str, object]]:
    return bus.sent_json(schemas.attitude_key("rod", device_id))


def alarms(bus: MemoryBus, device_id: str, alarm: str) -> list[dict[str, object]]:
    return [a for a in bus.sent_json(schemas.alarm_key("rod", device_id)) if a["alarm"] == alarm]


def test_a_spoofed_boot_id_does_not_silence_the_device(tmp_path: Path) -> None:
    """Old code: 3 packets with a new boot_id made the real boot stale, every later real packet was dropped as a
    duplicate (0 attitudes). Now the real boot wins the stream back, the spoofer's packets are dropped and counted,
    and a device_conflict alarm is raised (and clears once the spoofer is quiet)."""
    real = fleet_imu(4.0)
    spoof = [edit(m, boot_id=12345, seq=7 + i) for i, m in enumerate(real[40:43])]
    with service(tmp_path) as (svc, bus, store):
        run(svc, real[:40])
        before = len(attitudes(bus, "rod-1"))
        run(svc, spoof + real[40:60] + [edit(real[60], boot_id=12345, seq=99)] + real[61:])
        after = len(attitudes(bus, "rod-1")) - before
        assert after >= 35, f"real stream silenced: {after} attitudes from 40 real packets after the spoof"
        stats = svc.counters.snapshot(0)
        assert stats.rejected["device_conflict"] >= 2  # the packet that showed it, then the rival's
        assert stats.devices[0].reboots == 0  # the spoof was not a reboot
        raised = alarms(bus, "rod-1", "device_conflict")
        assert [a["state"] for a in raised] == ["raised"] and raised[0]["severity"] == "critical"
        assert [a.type for a in svc.pipeline.engine.active("rod-1")] == ["device_conflict"]
        svc._clear_conflicts(0.0, mono=1e9)  # long after the last rival packet
        assert [a["state"] for a in alarms(bus, "rod-1", "device_conflict")] == ["raised", "cleared"]
        assert svc.writer.flush()
        assert store.counts("rod-1")["active"] == 0


def test_a_spoofed_seq_jump_in_the_same_boot_does_not_silence_the_device(tmp_path: Path) -> None:
    """Anyone who can subscribe sees a device's boot_id; 3 packets with it and seq far ahead made every real packet
    a duplicate ('too old'). Now the real sequence wins back and the spoofer's is the rival."""
    real = fleet_imu(4.0)
    boot = json.loads(real[0][1])["boot_id"]
    spoof = [edit(m, seq=10**6 + i) for i, m in enumerate(real[40:43])]
    with service(tmp_path) as (svc, bus, _):
        run(svc, real[:40])
        before = len(attitudes(bus, "rod-1"))
        run(svc, spoof + real[40:60] + [edit(real[60], boot_id=boot, seq=10**6 + 9)] + real[61:])
        assert len(attitudes(bus, "rod-1")) - before >= 35
        stats = svc.counters.snapshot(0)
        assert stats.rejected["device_conflict"] >= 2 and stats.devices[0].lost < 10  # not the 10**6 jump
        assert [a["state"] for a in alarms(bus, "rod-1", "device_conflict")] == ["raised"]


def test_a_new_boot_id_on_every_spoofed_packet_is_reported(tmp_path: Path) -> None:
    """Several spoofed boots between two real packets never let the boot left behind deliver 2 packets in a row;
    boots flapping are reported as device_conflict all the same."""
    real = fleet_imu(3.0)
    mixed = list(real[:20])
    for i, m in enumerate(real[20:40]):
        mixed += [edit(real[0], boot_id=1000 + 2 * i, seq=5), edit(real[0], boot_id=1001 + 2 * i, seq=9), m]
    with service(tmp_path) as (svc, bus, _):
        run(svc, mixed + real[40:])
        assert svc.counters.snapshot(0).rejected["device_conflict"] >= 20
        assert [a["state"] for a in alarms(bus, "rod-1", "device_conflict")] == ["raised"]


def test_a_real_reboot_is_not_a_conflict(tmp_path: Path) -> None:
    msgs = fleet_imu(2.0)
    rebooted = [edit(m, boot_id=777, seq=i) for i, m in enumerate(msgs[20:])]
    with service(tmp_path) as (svc, bus, store):
        run(svc, msgs[:20] + rebooted + [msgs[19]])  # plus one late straggler of the old boot
        stats = svc.counters.snapshot(0)
        assert "device_conflict" not in stats.rejected and stats.devices[0].reboots == 1
        assert not alarms(bus, "rod-1", "device_conflict")


EXTREME = [
    ("wall_t0_us max", lambda m, i: edit(m, wall_t0_us=2**63 - 1), "wall_time_ignored", True),
    ("wall_t0_us zero", lambda m, i: edit(m, wall_t0_us=0), "wall_time_ignored", True),
    ("t0_us jump to 2**62", lambda m, i: edit(m, t0_us=2**62 + i), "time_range", False),
    ("t0_us jumps", lambda m, i: edit(m, t0_us=json.loads(m[1])["t0_us"] + 10**10 + 10**9 * (i % 2)),
     "time_jump", False),  # 10000 s ahead, then 11000 s: never an agreeing new timeline
    ("t0_us runs backwards", lambda m, i: edit(m, t0_us=json.loads(m[1])["t0_us"] - 5 * 10**8 - 5 * 10**7 * (i % 2)),
     "time_backwards", False),  # 500 s back, then 550 s
]  # fmt: skip


@pytest.mark.parametrize(("name", "poison", "reason", "keeps_output"), EXTREME, ids=[e[0] for e in EXTREME])
def test_extreme_timestamps_cost_only_that_device(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, name: str, poison, reason: str, keeps_output: bool
) -> None:  # type: ignore[no-untyped-def]
    """rod-2's packets 30..69 carry the extreme value; co-batched rod-1 must lose nothing (old code: the batch
    raised, rod-1 lost the attitudes of every batch rod-2 was in, and each failure logged a traceback)."""
    msgs = [edit(m, t0_us=json.loads(m[1])["t0_us"] + 10**9) if "/rod-2/" in m[0] else m  # rod-2 started 1000 s ago
            for m in fleet_imu(4.0, count=2)]  # fmt: skip
    with service(tmp_path / "clean") as (clean_svc, clean_bus, _):
        run(clean_svc, msgs)
    n2 = 0
    poisoned = []
    for k, p in msgs:
        if "/rod-2/" in k:
            n2 += 1
            if 30 <= n2 < 70:
                k, p = poison((k, p), n2)
        poisoned.append((k, p))
    caplog.set_level(logging.WARNING)
    with service(tmp_path / "poisoned") as (svc, bus, _):
        run(svc, poisoned)
    assert len(attitudes(bus, "rod-1")) == len(attitudes(clean_bus, "rod-1")) > 50
    stats = svc.counters.snapshot(0)
    assert stats.rejected[reason] == 40
    assert {d.device_id: d.rejected for d in stats.devices}["rod-2"][reason] == 40
    if keeps_output:  # the data is good, only its wall time was ignored
        assert len(attitudes(bus, "rod-2")) == len(attitudes(clean_bus, "rod-2"))
    else:
        assert len(attitudes(bus, "rod-2")) >= len(attitudes(clean_bus, "rod-2")) - 41
    assert len(caplog.records) <= 3, [r.getMessage() for r in caplog.records]
    assert not any(r.exc_info for r in caplog.records)


def test_a_device_clock_that_really_jumped_resyncs(tmp_path: Path) -> None:
    """A clock that jumps for good (same boot) is not silenced: after 3 agreeing packets the new timeline is taken
    and the device's fusion restarts."""
    msgs = fleet_imu(4.0)
    jumped = msgs[:30] + [edit(m, t0_us=json.loads(m[1])["t0_us"] + 7200 * 10**6) for m in msgs[30:]]
    with service(tmp_path) as (svc, bus, store):
        run(svc, jumped)
    stats = svc.counters.snapshot(0)
    assert stats.rejected["time_jump"] == 2 and stats.rejected["time_resync"] == 1
    late = [a for a in attitudes(bus, "rod-1") if int(a["t_us"]) > 7200 * 10**6]  # type: ignore[call-overload]
    assert len(late) >= 30


def test_a_resumed_alarm_without_its_cause_clears(tmp_path: Path) -> None:
    """An alarm left active in the store (its clear lost with a full disk or a kill) used to stay active for good:
    the rules restart from scratch and never clear what they did not raise. Now it clears after 10 s of the
    device's data without its condition."""
    from gateway.alarm.engine import Alarm, AlarmStatus, Severity

    stale = Alarm(id="stale1", device_id="rod-1", type="bite", severity=Severity.MAJOR, status=AlarmStatus.ACTIVE,
                  started_at=1.0, updated_at=1.0, value=20.0, threshold=15.0, message="bite")  # fmt: skip
    with Store(tmp_path / "gw.db") as store:
        store.upsert_alarm(stale)
    with service(tmp_path) as (svc, bus, store):
        assert [a.id for a in svc.pipeline.engine.active("rod-1")] == ["stale1"]
        run(svc, fleet_imu(30.0))  # a quiet rod, 15 s of gateway time at this pace
        events = alarms(bus, "rod-1", "bite")
        assert [(e["alarm_id"], e["state"]) for e in events] == [("stale1", "cleared")]
        assert svc.writer.flush()
        assert store.counts("rod-1")["active"] == 0


def test_an_extreme_env_wall_time_does_not_pin_a_spot(tmp_path: Path) -> None:
    """A ball's reading with wall_t_us 2**63 - 1 stayed the spot's newest reading for good (the ranking keeps the
    reading with the latest wall time); now its wall time is ignored and counted."""
    key, env = protocol_doc.examples()["env"]
    now_us = int(time.time() * 1e6)
    first = env.model_copy(update={"wall_t_us": 2**63 - 1, "water_temp_c": 30.0, "seq": 1})
    second = env.model_copy(update={"wall_t_us": now_us, "water_temp_c": 12.0, "seq": 2})
    with service(tmp_path) as (svc, _, _):
        run(svc, [(key, first.to_json()), (key, second.to_json())], batch=1)
        spot = svc.pipeline.rank_spots(time.time()).spots[0]
        assert spot.last_seen_wall_us == now_us
        assert svc.counters.snapshot(0).rejected["wall_time_ignored"] == 1


def test_a_crane_feed_is_counted_and_checked_like_any_device_data(tmp_path: Path) -> None:
    """CraneMotion on a hook's key (docs/protocol.md, crane motion): a good one reaches the hook's feed; one whose
    wall time is far from the gateway's clock is dropped as `crane_wall_time` (it is aligned by it); one with a tip
    acceleration beyond 2 g is rejected `out_of_range`; one naming another hook than its key `key_mismatch`. None of
    them costs the other hook's feed anything."""
    key, crane = protocol_doc.examples()["crane"]
    now_us = int(time.time() * 1e6)
    good = crane.model_copy(update={"wall_t0_us": now_us, "seq": 1})
    far = crane.model_copy(update={"wall_t0_us": 2**63 - 1, "seq": 2})
    wild = json.loads(crane.model_copy(update={"wall_t0_us": now_us, "seq": 3}).to_json())
    wild["tip_acc_m_s2"][0][0] = 30.0
    other = json.loads(good.to_json())
    other["device_id"] = "hook-2"
    with service(tmp_path) as (svc, _, _):
        run(svc, [(key, good.to_json()), (key, far.to_json()), (key, json.dumps(wild).encode()),
                  (key, json.dumps(other).encode())], batch=4)
        rejected = svc.counters.snapshot(0).rejected
        assert (rejected["crane_wall_time"], rejected["out_of_range"], rejected["key_mismatch"]) == (1, 1, 1)
        hook = svc.pipeline.handlers["hook"]
        feed = hook.feeds["hook-1"]  # type: ignore[attr-defined]
        assert feed.packets == 1 and feed.t_s[0] == pytest.approx(now_us * 1e-6)
        assert set(hook.feeds) == {"hook-1"}  # type: ignore[attr-defined]
        view = device_view(svc, "hook-1", detail=False)["crane_feed"]  # what REST and the dashboard's card show
        assert view["packets"] == 1 and -1.0 < view["newest_age_s"] < 60.0  # its last sample is 0.1 s after now
        assert view["in_use"] is True
