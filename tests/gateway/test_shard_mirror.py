"""The other shards' attitude and swing outputs cross to a shard only while someone looks at them (a 3-D view client)
and another shard is live: subscribed always, every shard received every other shard's attitude (about one per
packet) and dropped almost all of them. Alarms are mirrored always (the dashboard's alarm frames)."""

from __future__ import annotations

from pathlib import Path

from gateway.config import Settings
from gateway.ingest.bus import MemoryBus, key_matches
from gateway.shard.node import ShardNode
from gateway.shard.ownership import ShardInfo

ATTITUDE_KEY = "gw/rod/rod-9/attitude"
SWING_KEY = "gw/hook/hook-9/swing"
ALARM_KEY = "gw/rod/rod-9/alarm"


def listening(bus: MemoryBus, key: str) -> int:
    return sum(key_matches(sel, key) for sel, _ in bus.subs)


def node(tmp_path: Path) -> tuple[ShardNode, MemoryBus, list[bool]]:
    bus = MemoryBus()
    shard = ShardNode(Settings(data_dir=tmp_path / "data", zenoh_listen=[]), bus, "a")
    demand = [False]
    shard.mirror_demand = lambda: demand[0]
    return shard, bus, demand


def test_attitudes_of_other_shards_are_subscribed_only_while_a_client_looks_and_another_shard_lives(
    tmp_path: Path,
) -> None:
    shard, bus, demand = node(tmp_path)
    assert not shard.update_mirror()  # alone, nobody looking
    demand[0] = True
    assert not shard.update_mirror()  # alone: no other shard's outputs to mirror
    assert listening(bus, ATTITUDE_KEY) == 0
    shard.ownership.update(ShardInfo("b"), alive=True)
    assert shard.update_mirror()
    assert listening(bus, ATTITUDE_KEY) == 1 and listening(bus, SWING_KEY) == 1
    assert shard.update_mirror() and listening(bus, ATTITUDE_KEY) == 1  # idempotent: not a second subscriber
    demand[0] = False
    assert not shard.update_mirror()
    assert listening(bus, ATTITUDE_KEY) == 0 and listening(bus, SWING_KEY) == 0
    demand[0] = True
    shard.ownership.update(ShardInfo("b"), alive=False)
    assert not shard.update_mirror()
    assert listening(bus, ATTITUDE_KEY) == 0


def test_a_memory_bus_subscription_can_be_undeclared_once() -> None:
    bus = MemoryBus()
    got: list[str] = []
    unsubscribe = bus.subscribe("gw/*/*/attitude", lambda k, p: got.append(k))
    bus.put(ATTITUDE_KEY, b"{}", encoding="application/json")
    unsubscribe()
    unsubscribe()
    bus.put(ATTITUDE_KEY, b"{}", encoding="application/json")
    assert got == [ATTITUDE_KEY]
