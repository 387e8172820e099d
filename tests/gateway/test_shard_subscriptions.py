"""A shard's device-data subscriptions (gateway/shard/subscriptions.py): alone the catch-all selectors, beside other
shards the exact keys of its own devices (token holders, and tokenless ones a probe found), so the router never sends
it the others' packets. MemoryBus: a put reaches exactly the subscribers whose selector matches its key."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway import schemas
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus
from gateway.shard import subscriptions
from gateway.shard.node import ShardNode
from gateway.shard.ownership import Ownership, ShardInfo, owner_of
from gateway.shard.subscriptions import DataSubscriptions, device_keys, may_overlap

A, B = ShardInfo("A"), ShardInfo("B")
DEVICES = {**{f"rod-{i}": "rod" for i in range(12)}, **{f"hook-{i}": "hook" for i in range(6)}, "ball-1": "ball"}
MINE = {d for d in DEVICES if owner_of(d, (A, B)) == "A"}


@pytest.fixture(autouse=True)
def short_probes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(subscriptions, "PROBE_WINDOW_S", 0.02)  # over within one `settle()`


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


class Rig:
    """Shard A's subscriptions on a MemoryBus, with what reached its inbox."""

    def __init__(self) -> None:
        self.bus, self.clock, self.own = MemoryBus(), Clock(), Ownership(A)
        self.offered: list[str] = []
        self.last: dict[str, float] = {}
        self.subs = DataSubscriptions(self.bus, schemas.SEL_DEVICE_DATA, self.own.owns, 100,
                                      self.last.get, self.clock)  # fmt: skip

    def selectors(self) -> set[str]:
        return {sel for sel, _ in self.bus.subs}

    def send_all(self, devices: dict[str, str]) -> None:
        """One packet on every data key of every device."""
        for d, kind in devices.items():
            for key in device_keys(kind, d):
                self.bus.put(key, b"{}", encoding=schemas.ENCODING_IMU)

    def reached(self) -> set[str]:
        return {k.split("/")[2] for k in self.offered}


def run(body: Callable[[Rig], Awaitable[Any]]) -> Rig:
    rig = Rig()

    async def main() -> None:
        rig.subs.start(lambda key, payload: rig.offered.append(key))
        await settle()
        try:
            await body(rig)
        finally:
            await rig.subs.stop()

    asyncio.run(main())
    assert rig.bus.subs == [], "stop() left subscribers behind"
    return rig


async def settle() -> None:
    for _ in range(20):
        await asyncio.sleep(0.005)


def beside_b(rig: Rig) -> None:
    rig.own.update(B, True)
    rig.subs.set_mode(alone=False)


def test_device_keys_are_the_data_keys_only() -> None:
    assert device_keys("rod", "r1") == ("rig/rod/r1/imu", "rig/rod/r1/reel")
    assert device_keys("hook", "h1") == ("rig/hook/h1/imu", "rig/hook/h1/crane")  # the crane's feed beside it
    assert device_keys("ball", "b1") == ("rig/ball/b1/env",)


def test_alone_the_catch_all_beside_another_shard_only_its_own_devices() -> None:
    async def body(rig: Rig) -> None:
        for d, kind in DEVICES.items():
            rig.subs.token(f"rig/{kind}/{d}", True)
        await settle()
        assert rig.selectors() == set(schemas.SEL_DEVICE_DATA)
        rig.send_all(DEVICES)
        assert rig.reached() == set(DEVICES)  # alone: every device

        rig.offered.clear()
        beside_b(rig)
        await settle()
        assert rig.selectors() == {k for d in MINE for k in device_keys(DEVICES[d], d)}
        rig.send_all(DEVICES)
        assert rig.reached() == MINE  # B's packets never reach A
        assert rig.subs.stats()["data_mode"] == "devices"
        assert len(rig.offered) == sum(len(device_keys(DEVICES[d], d)) for d in MINE)  # each once

        rig.offered.clear()  # B leaves: the catch-all again
        rig.own.update(B, False)
        rig.subs.set_mode(alone=True)
        await settle()
        assert rig.selectors() == set(schemas.SEL_DEVICE_DATA)
        rig.send_all(DEVICES)
        assert rig.reached() == set(DEVICES)

    run(body)


def test_a_tokenless_device_is_found_by_a_probe_and_subscribed_by_its_owner_only(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(subscriptions, "PROBE_WINDOW_S", 0.05)
    ids = [f"nt-{i}" for i in range(100)]
    mine, late = [d for d in ids if owner_of(d, (A, B)) == "A"][:2]
    theirs = next(d for d in ids if owner_of(d, (A, B)) == "B")
    tokenless = {mine: "rod", theirs: "hook"}

    async def body(rig: Rig) -> None:
        beside_b(rig)  # the live set changed: a probe starts at once
        for _ in range(100):
            await asyncio.sleep(0.001)
            if rig.selectors() >= set(schemas.SEL_DEVICE_DATA):
                break
        rig.send_all(tokenless)  # seen by the probe, which hands no packet to the inbox
        await settle()
        assert rig.offered == []
        assert set(rig.subs.tokenless) == {mine, theirs}
        assert rig.selectors() == set(device_keys("rod", mine))  # only the one A owns; the probe is over
        rig.send_all(tokenless | {late: "rod"})
        assert rig.reached() == {mine}  # `late` sent after the probe: not known, not subscribed

        rig.offered.clear()  # silent for IDLE_S: forgotten, unsubscribed
        rig.last[mine] = rig.clock.now
        rig.clock.now += subscriptions.IDLE_S - 1.0
        rig.subs.expire()
        assert mine in rig.subs.tokenless  # its packets kept it
        rig.clock.now += 2.0
        rig.subs.expire()
        await settle()
        assert rig.subs.tokenless == {} and rig.selectors() == set()
        rig.send_all(tokenless)
        assert rig.offered == []

    run(body)


def test_a_device_whose_token_goes_stays_subscribed_while_it_sends() -> None:
    mine = sorted(MINE)[0]

    async def body(rig: Rig) -> None:
        beside_b(rig)
        rig.subs.token(f"rig/{DEVICES[mine]}/{mine}", True)
        await settle()
        rig.subs.token(f"rig/{DEVICES[mine]}/{mine}", False)
        await settle()
        rig.send_all({mine: DEVICES[mine]})
        assert rig.reached() == {mine}
        rig.clock.now += subscriptions.IDLE_S + 1.0
        rig.subs.expire()
        await settle()
        assert rig.selectors() == set()

    run(body)


def test_too_many_devices_fall_back_to_the_catch_all(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(subscriptions, "MAX_DEVICE_SUBSCRIBERS", 3)

    async def body(rig: Rig) -> None:
        beside_b(rig)
        for d, kind in DEVICES.items():
            rig.subs.token(f"rig/{kind}/{d}", True)
        await settle()
        assert rig.selectors() == set(schemas.SEL_DEVICE_DATA)
        assert rig.subs.stats()["data_mode"] == "all"

    run(body)


def test_site_globs_that_exclude_each_other_do_not_overlap() -> None:
    assert not may_overlap(ShardInfo("a", ("site1-*",)), ShardInfo("b", ("site2-*",)))
    assert not may_overlap(ShardInfo("a", ("rod-1",)), ShardInfo("b", ("rod-2", "hook-*")))
    assert may_overlap(ShardInfo("a", ("site1-*",)), ShardInfo("b", ("site1-rod-*",)))
    assert may_overlap(ShardInfo("a", ("site1-*",)), ShardInfo("b"))  # b serves every id
    assert may_overlap(ShardInfo("a", ("rod-?",)), ShardInfo("b", ("hook-*",)))  # not decided: assume overlap
    assert may_overlap(ShardInfo("a", ("rod-1",)), ShardInfo("b", ("rod-*",)))


globs = st.lists(st.from_regex(r"[a-c1-2-]{0,4}\*?", fullmatch=True).filter(bool), min_size=1, max_size=3)


@given(globs, globs, st.lists(st.from_regex(r"[a-c1-2-]{1,6}", fullmatch=True), max_size=40))
def test_shards_said_not_to_overlap_never_both_serve_an_id(p: list[str], q: list[str], ids: list[str]) -> None:
    a, b = ShardInfo("a", tuple(p)), ShardInfo("b", tuple(q))
    if not may_overlap(a, b):
        assert not any(a.serves(d) and b.serves(d) for d in ids)


def test_a_site_shard_beside_other_sites_keeps_its_narrowed_catch_all(tmp_path: Path) -> None:
    """`--devices 'site1-*'` beside a `site2-*` shard: alone for its ids, so one wildcard subscriber per topic."""
    shard = ShardNode(Settings(data_dir=tmp_path, zenoh_listen=[], shard_devices=["site1-*"]), MemoryBus(), "s1")
    assert shard.alone()
    shard.ownership.update(ShardInfo("s2", ("site2-*",)), True)
    assert shard.alone()
    shard.ownership.update(ShardInfo("any"), True)  # serves every id, site1's too
    assert not shard.alone()
