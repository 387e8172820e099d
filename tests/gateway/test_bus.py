"""MemoryBus (the in-process twin of ZenohBus): its key matching agrees with zenoh's own key-expression rules;
ZenohBus declares the keys its wildcard subscribers receive."""

from __future__ import annotations

import time
from collections.abc import Callable

import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from devices.common import zenoh_config
from gateway import schemas
from gateway.ingest.bus import MemoryBus, ZenohBus, key_matches

chunk = st.sampled_from(["rig", "gw", "rod", "hook", "a", "b1"])
sel_chunk = st.one_of(chunk, st.just("*"), st.just("**"))


@settings(max_examples=300, deadline=None)
@given(key=st.lists(chunk, min_size=1, max_size=5), sel=st.lists(sel_chunk, min_size=1, max_size=5))
def test_key_matches_agrees_with_zenoh(key: list[str], sel: list[str]) -> None:
    selector = "/".join(sel)
    canon = str(zenoh.KeyExpr.autocanonize(selector))
    k = "/".join(key)
    assert key_matches(canon, k) == zenoh.KeyExpr(canon).includes(zenoh.KeyExpr(k))


def test_memory_bus_delivers_records_and_tracks_tokens() -> None:
    bus = MemoryBus()
    got: list[str] = []
    seen: list[tuple[str, bool]] = []
    bus.subscribe("rig/*/*/imu", lambda k, p: got.append(k))
    bus.declare_token("rig/rod/r1")
    bus.watch_liveliness("rig/*/*", lambda k, alive: seen.append((k, alive)))  # history: sees r1 at once
    bus.put("rig/rod/r1/imu", b"x", encoding="e")
    bus.put("rig/rod/r1/reel", b"y", encoding="e", block=True)
    bus.set_alive("rig/rod/r1", False)
    assert got == ["rig/rod/r1/imu"]
    assert [(k, b) for k, _, b in bus.sent] == [("rig/rod/r1/imu", False), ("rig/rod/r1/reel", True)]
    assert seen == [("rig/rod/r1", True), ("rig/rod/r1", False)]


def _wait(cond: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        time.sleep(0.01)
    return cond()


def test_zenoh_bus_declares_each_key_its_wildcard_subscribers_receive_once_and_within_the_cap() -> None:
    """`RouteKeys`: zenoh caches the route of a declared key only (without it a session watching many liveliness
    tokens matched every sample's key against all of them: bench.zenoh_subscribers, `catch-all+tokens`)."""
    conf = zenoh_config("peer", connect=(), listen=())
    with zenoh.open(conf) as session:
        bus = ZenohBus(session)
        bus.route_keys.max_keys = 3
        got: list[str] = []
        bus.subscribe("rig/*/*/imu", lambda k, p: got.append(k))
        bus.subscribe("gw/exact/key", lambda k, p: got.append(k))
        keys = [f"rig/rod/r{i}/imu" for i in range(5)]
        for key in [*keys[:2], *keys[:2], "gw/exact/key", *keys[2:]]:
            bus.put(key, b"x", encoding=schemas.ENCODING_IMU)
        assert _wait(lambda: len(got) == 8), got
        assert _wait(lambda: len(bus.route_keys.declared) == 3)
        time.sleep(0.2)  # nothing more comes
        assert sorted(str(k) for k in bus.route_keys.declared) == keys[:3]  # once each, exact keys not, cap 3
        assert bus.route_keys.failed == 0
        bus.close()


def test_zenoh_bus_says_whether_a_key_has_a_subscriber_across_a_router() -> None:
    """`ZenohBus.subscribed` (zenoh's matching status) for a router session and one of its clients: False with no
    subscriber, True once a client of the router subscribes to a wildcard covering the key, False again after it
    undeclares; a key the wildcard does not cover stays False."""
    from bench.bite_latency import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(zenoh_config("router", connect=(), listen=(endpoint,))) as router, \
            zenoh.open(zenoh_config("client", connect=(endpoint,))) as client, \
            zenoh.open(zenoh_config("client", connect=(endpoint,))) as app:  # fmt: skip
        buses = [ZenohBus(router), ZenohBus(client)]
        height, attitude = "gw/rod/r1/height", "gw/rod/r1/attitude"

        def matched(key: str) -> list[bool]:
            return [b.subscribed(key, encoding=schemas.ENCODING_GW) for b in buses]

        time.sleep(0.3)
        assert matched(height) == [False, False]
        sub = app.declare_subscriber("gw/*/*/height", lambda s: None)
        assert _wait(lambda: matched(height) == [True, True]), matched(height)
        assert matched(attitude) == [False, False]
        sub.undeclare()
        assert _wait(lambda: matched(height) == [False, False]), matched(height)
        for b in buses:
            b.close()


def test_hub_encodes_and_puts_a_drop_message_only_while_its_key_has_a_subscriber() -> None:
    """The hub skips a DROP output (height) whose key no subscriber takes: not put, counted in `unmatched`, still
    handed to its listeners; BLOCK outputs (alarms, swing) are put regardless. `Hub.takes` and `Hub.taker` (which the
    pipeline asks once per batch before making heights) say the same, and yes once a listener takes the topic."""
    from gateway.hub import Hub

    class Bus(MemoryBus):
        wanted: set[str] = {"gw/rod/r2/height"}

        def subscribed(self, key: str, *, encoding: str, block: bool = False, express: bool = False) -> bool:
            return key in self.wanted

    class Writer:
        def upsert_alarm(self, alarm: object) -> None: ...

    bus = Bus()
    hub = Hub(bus, Writer())  # type: ignore[arg-type]
    assert [hub.takes(schemas.T_HEIGHT, "rod", d) for d in ("r1", "r2")] == [False, True]
    assert hub.takes(schemas.T_ALARM, "rod", "r1")  # BLOCK: always put
    height_taker = hub.taker(schemas.T_HEIGHT)
    assert height_taker is not None and [height_taker("rod", d) for d in ("r1", "r2")] == [False, True]
    assert hub.taker(schemas.T_ALARM) is None and hub.taker(schemas.T_SWING) is None  # BLOCK: no question asked
    heard: list[str] = []
    hub.listeners.append(lambda topic, model: heard.append(model.device_id))  # type: ignore[attr-defined]
    for dev in ("r1", "r2"):
        h = schemas.Height(device_id=dev, kind="rod", seq=1, t_us=10, wall_t_us=20, vz_m_s=0.0, height_m=0.1,
                           at_rest=True, aided="none")  # fmt: skip
        hub._put(schemas.T_HEIGHT, h, "rod", dev)
    assert [k for k, _, _ in bus.sent] == ["gw/rod/r2/height"]
    assert (hub.published, hub.unmatched, heard) == (1, 1, ["r1", "r2"])
    assert hub.takes(schemas.T_HEIGHT, "rod", "r1")  # a listener of every topic takes it now
    assert hub.taker(schemas.T_HEIGHT) is None
