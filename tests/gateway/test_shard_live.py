"""The dashboard stream across shards (gateway/shard/live.py): another shard's tick frames merged into this
endpoint's, bounded, and forgotten when that shard goes or stops serving the device."""

from __future__ import annotations

import json
from typing import Any

from gateway.ingest.bus import MemoryBus
from gateway.shard.live import STALE_S, WANT_TTL_S, LivePeers, merge_spots
from gateway.shard.ownership import Ownership, ShardInfo, owner_of

A, B = ShardInfo("A"), ShardInfo("B")
DEVICES = [f"rod-{i}" for i in range(1, 30)]
OF_B = [d for d in DEVICES if owner_of(d, (A, B)) == "B"]
OF_A = [d for d in DEVICES if owner_of(d, (A, B)) == "A"]


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def peers(series_max: int = 200) -> tuple[LivePeers, MemoryBus, Clock]:
    """A's side with B live; bus callbacks run at once (no event loop)."""
    bus, clock = MemoryBus(), Clock()
    own = Ownership(A)
    own.update(B, True)
    p = LivePeers(bus, own, "A", lambda fn, *args: fn(*args), series_max=series_max, clock=clock)
    p.subscribe()
    return p, bus, clock


def entry(device_id: str, t: list[float], full: bool = False) -> dict[str, Any]:
    e: dict[str, Any] = {"device_id": device_id, "kind": "rod", "series": {"t_s": t, "pitch_deg": [1.0] * len(t)},
                         "acc": {"t_s": t, "norm": [9.8] * len(t)}, "link": {"battery_v": 3.9}}  # fmt: skip
    if full:
        e.update(online=True, reel={"mode": "in"}, active_alarms=["bite"])
    return e


def frame_from_b(bus: MemoryBus, entries: list[dict[str, Any]], spots: list[dict[str, Any]] | None = None) -> None:
    f: dict[str, Any] = {"type": "tick", "full": spots is not None, "devices": entries}
    if spots is not None:
        f["spots"] = spots
    bus.put("gw/shard/B/live", json.dumps(f).encode(), encoding="application/json")


def test_the_other_shards_devices_are_merged_once_with_their_cards() -> None:
    assert OF_A and OF_B
    p, bus, _ = peers()
    d = OF_B[0]
    frame_from_b(bus, [entry(d, [1.0, 1.1])])
    frame_from_b(bus, [entry(d, [1.2], full=True)])  # two of B's ticks before one of A's
    mine: dict[str, Any] = {"full": True, "devices": [{"device_id": OF_A[0], "kind": "rod", "series": {"t_s": []}}]}
    p.merge(mine)
    got = {e["device_id"]: e for e in mine["devices"]}
    assert set(got) == {OF_A[0], d}
    assert got[d]["series"]["t_s"] == [1.0, 1.1, 1.2] and got[d]["acc"]["norm"] == [9.8] * 3
    assert got[d]["online"] is True and got[d]["reel"] == {"mode": "in"} and got[d]["link"] == {"battery_v": 3.9}
    again: dict[str, Any] = {"full": False, "devices": []}
    p.merge(again)  # samples are moved, not copied; a samples-only tick carries no card
    assert again["devices"] == [{"device_id": d, "kind": "rod", "series": {"t_s": []}, "link": {"battery_v": 3.9}}]


def test_entries_of_devices_the_sender_does_not_serve_are_ignored() -> None:
    p, bus, _ = peers()
    frame_from_b(bus, [entry(OF_A[0], [1.0]), entry(OF_B[0], [1.0])])
    bus.put("gw/shard/C/live", json.dumps({"devices": [entry(OF_B[1], [1.0])]}).encode(), encoding="x")  # not live
    bus.put("gw/shard/B/live", b"not json", encoding="x")
    assert set(p.remote) == {OF_B[0]}


def test_samples_are_bounded_and_devices_forgotten_when_their_shard_goes_or_goes_quiet() -> None:
    p, bus, clock = peers(series_max=5)
    for k in range(4):
        frame_from_b(bus, [entry(OF_B[0], [k + 0.1 * i for i in range(3)])], spots=[{"spot": "s", "score": 0.5}])
    merged: dict[str, Any] = {"full": False, "devices": []}
    p.merge(merged)
    assert merged["devices"][0]["series"]["t_s"] == [2.1, 2.2, 3.0, 3.1, 3.2]  # the newest 5
    clock.now += STALE_S + 0.1
    p.listening(False)
    assert not p.remote and not p.spots  # no frame from B for STALE_S
    frame_from_b(bus, [entry(OF_B[0], [5.0])], spots=[])
    assert p.remote
    p.ownership.update(B, False)  # B leaves: A serves its devices now and forgets B's buffers at its next tick
    p.listening(False)
    assert not p.remote and not p.spots


def test_frames_are_asked_for_while_clients_watch_and_sent_while_asked() -> None:
    p, bus, clock = peers()
    p.listening(False)
    assert not bus.sent_json("gw/shard/A/want_live")
    p.listening(True)
    p.listening(True)  # at most once a second
    assert len(bus.sent_json("gw/shard/A/want_live")) == 1
    assert not p.wanted()  # its own request does not count
    bus.put("gw/shard/B/want_live", b"{}", encoding="x")
    assert p.wanted()
    clock.now += WANT_TTL_S + 0.1
    assert not p.wanted()


def test_spot_rankings_of_the_shards_merge_into_one() -> None:
    a = [{"spot": "bay", "score": 0.4, "rank": 1}]
    b = [{"spot": "reef", "score": 0.9, "rank": 1}, {"spot": "bay", "score": 0.6, "rank": 2}]
    got = merge_spots([a, b])
    assert [(s["spot"], s["score"], s["rank"]) for s in got] == [("reef", 0.9, 1), ("bay", 0.6, 2)]


def test_a_shards_stream_carries_only_the_devices_it_serves() -> None:
    """The mirrored attitude of another shard's device (for the 3-D view) must not start a series here: that
    device's samples come with its owner's frames, and a second copy would plot every point twice."""
    from types import SimpleNamespace

    from gateway import schemas
    from gateway.api.ws import ClientQueue, LiveStream
    from gateway.views import plot_points

    kinds = {"rod-a": "rod", "rod-b": "rod"}
    svc = SimpleNamespace(pipeline=SimpleNamespace(kinds=kinds), accept=lambda d: d == "rod-a")
    live = LiveStream(svc)  # type: ignore[arg-type]
    live.clients.add(ClientQueue(8))
    atts = [schemas.Attitude(v=1, device_id=d, kind="rod", seq=1, t_us=1, wall_t_us=10**15,
                             quat_wxyz=(1.0, 0.0, 0.0, 0.0), roll_rad=0.0, pitch_rad=0.1, yaw_rad=0.0,
                             yaw_unwrapped_rad=0.0) for d in kinds]  # fmt: skip
    for a in atts:
        live.on_hub("attitude", a)  # the other shard's, mirrored for the 3-D view: not plotted here
    live.on_plot(plot_points(atts))  # this shard's hub outputs (rod-b: ownership moved away mid-batch)
    frame = live.tick_frame(1.0, full=False)
    assert [e["device_id"] for e in frame["devices"]] == ["rod-a"]
    assert len(frame["devices"][0]["series"]["t_s"]) == 1
    assert set(live._series) == {"rod-a"}
