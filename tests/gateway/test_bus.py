"""MemoryBus (the in-process twin of ZenohBus): its key matching agrees with zenoh's own key-expression rules."""

from __future__ import annotations

import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.ingest.bus import MemoryBus, key_matches

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
