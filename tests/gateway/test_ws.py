"""Live stream (/ws/stream): bounded drop-oldest client queues, raw acceleration summary, frames from real ingest."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway import schemas
from gateway.api.ws import ClientQueue, LiveSettings, LiveStream, raw_imu_summary
from tests.gateway.conftest import Running, rod_messages

BITE = [{"type": "bite", "t_s": 3.0, "depth_deg": 15.0, "duration_s": 1.5}]


@given(maxsize=st.integers(1, 20), ops=st.lists(st.booleans(), max_size=200))
def test_client_queue_is_bounded_and_keeps_the_newest(maxsize: int, ops: list[bool]) -> None:
    """True = put the next frame, False = get one if any: the queue never exceeds maxsize, nothing is lost
    silently (got + held + dropped = put), and what is held is the newest frames in order."""

    async def run() -> None:
        q = ClientQueue(maxsize)
        put, got = 0, []
        for op in ops:
            if op:
                q.put(str(put))
                put += 1
            elif len(q):
                got.append(int(await q.get()))
            assert len(q) <= maxsize
        held = [int(await q.get()) for _ in range(len(q))]
        assert len(got) + len(held) + q.dropped == put
        assert got + held == sorted(got + held)  # FIFO, no reordering
        if put:
            assert held == [] or held[-1] == put - 1  # the newest frame is never the one dropped

    asyncio.run(run())


def test_client_queue_rejects_zero_size() -> None:
    with pytest.raises(ValueError, match="maxsize"):
        ClientQueue(0)


def test_get_waits_for_a_put() -> None:
    async def run() -> str:
        q = ClientQueue(3)
        waiter = asyncio.create_task(q.get())
        await asyncio.sleep(0.01)
        assert not waiter.done()
        q.put("x")
        return await asyncio.wait_for(waiter, 1.0)

    assert asyncio.run(run()) == "x"


def _imu(acc: list[list[float]], rate_hz: float, **fields: Any) -> schemas.ImuPacket:
    """A decoded IMU packet, as the hub hands it to the stream."""
    return schemas.ImuPacket(v=1, device_id="rod-1", kind="rod", boot_id=1, seq=0, t0_us=0, rate_hz=rate_hz,
                             gyr_rad_s=[(0.0, 0.0, 0.0)] * len(acc), acc_m_s2=[tuple(r) for r in acc], **fields)  # type: ignore[arg-type]


def test_raw_imu_summary_reference_values() -> None:
    """One point per packet: per-axis mean, peak |a| (|(3, 4, 12)| = 13), at the last sample's time
    wall_t0 + (n-1)/rate; link fields come from the newest packets."""
    p1 = _imu([[3.0, 4.0, 12.0], [0.0, 0.0, 9.81]], 100.0, wall_t0_us=10_000_000, battery_v=4.0, rssi_dbm=-60.0)
    p2 = _imu([[1.0, 2.0, 2.0], [1.0, 2.0, 2.0]], 50.0, wall_t0_us=10_020_000)
    out = raw_imu_summary([p1, p2], now_s=99.0)
    acc = out["acc"]
    assert acc["norm"] == pytest.approx([13.0, 3.0], abs=1e-4)
    assert acc["ax"] == pytest.approx([1.5, 1.0]) and acc["az"] == pytest.approx([10.905, 2.0])
    assert acc["t_s"] == pytest.approx([10.01, 10.04], abs=1e-9)
    assert out["link"] == {"battery_v": 4.0, "rssi_dbm": -60.0}


def test_raw_imu_summary_without_wall_time_ends_at_now() -> None:
    assert raw_imu_summary([_imu([[0.0, 0.0, 1.0]] * 4, 4.0)], now_s=100.0)["acc"]["t_s"] == pytest.approx([99.75])


@given(st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-50, 50)), min_size=1, max_size=20))
def test_raw_imu_peak_bounds_the_mean(rows: list[tuple[float, float, float]]) -> None:
    """The plotted peak |a| is never below the norm of the plotted mean (triangle inequality)."""
    acc = raw_imu_summary([_imu([list(r) for r in rows], 100.0, wall_t0_us=0)], now_s=0.0)["acc"]
    mean_norm = math.sqrt(acc["ax"][0] ** 2 + acc["ay"][0] ** 2 + acc["az"][0] ** 2)
    assert acc["norm"][0] >= mean_norm - 1e-3


class _NoService:
    """Just enough of a GatewayService for broadcast(): nothing is read from it."""


def test_slow_client_drops_old_frames_and_never_blocks_the_producer() -> None:
    live = LiveStream(_NoService(), LiveSettings(queue_size=4))  # type: ignore[arg-type]
    slow, fast = ClientQueue(4), ClientQueue(1000)
    live.clients |= {slow, fast}
    for i in range(100):
        live.broadcast({"type": "test", "i": i})
    assert len(slow) == 4 and slow.dropped == 96
    assert len(fast) == 100 and fast.dropped == 0

    async def drain(q: ClientQueue) -> list[int]:
        return [json.loads(await q.get())["i"] for _ in range(len(q))]

    assert asyncio.run(drain(slow)) == [96, 97, 98, 99]


def _frames_until(ws: Any, pred: Callable[[dict[str, Any]], bool], limit: int = 200) -> dict[str, Any]:
    for _ in range(limit):
        f = json.loads(ws.receive_text())
        if pred(f):
            return f
    raise AssertionError("expected frame not received")


def test_stream_ticks_carry_device_series_matching_rest(running: Callable[[], Running]) -> None:
    app = running()
    with app.client.websocket_connect("/ws/stream") as ws:
        hello = json.loads(ws.receive_text())
        assert hello["type"] == "hello" and hello["queue_size"] == 256
        msgs = rod_messages(2.0)
        # raw buffers exist only for devices the pipeline knows (issue 13: no buffer per arbitrary key), so the
        # first packet introduces the device and is not in the raw summary
        app.feed(msgs[:1])
        app.feed(msgs[1:])
        n_packets = sum(1 for k, _ in msgs if k.endswith("/imu"))
        pitch: list[float] = []
        acc: list[float] = []
        card: dict[str, Any] = {}
        for _ in range(200):  # collect samples until a full tick (card) arrives after all of them
            f = json.loads(ws.receive_text())
            if f["type"] != "tick":
                continue
            rod = next((d for d in f["devices"] if d["device_id"] == "rod-1"), None)
            if rod is None:
                continue
            assert len(rod["series"]["t_s"]) == len(rod["series"].get("pitch_deg", []))
            pitch += rod["series"].get("pitch_deg", [])
            acc += rod["acc"]["norm"]
            if f["full"] and pitch and not rod["series"]["t_s"]:
                card = rod
                break
        rest = app.client.get("/api/devices/rod-1").json()
        # the last streamed pitch is the attitude REST shows (no packets arrive in between)
        assert pitch[-1] == pytest.approx(math.degrees(rest["attitude"]["pitch_rad"]), abs=1e-3)
        assert card["attitude"]["pitch_rad"] == pytest.approx(rest["attitude"]["pitch_rad"])
        assert card["reel"]["mode"] in ("stop", "in", "out", "auto")
        # one acceleration point per packet kept (raw_packets bounds what waits between ticks), a rod at rest ~ g
        assert 0 < len(acc) <= n_packets and all(8.0 < a < 12.0 for a in acc)
    stats = app.client.get("/api/live").json()
    assert stats["clients"] == 0 and stats["ticks"] >= 1


def test_stream_sends_bite_alarm_and_reel_command(running: Callable[[], Running]) -> None:
    app = running()
    with app.client.websocket_connect("/ws/stream") as ws:
        ws.receive_text()
        app.feed(rod_messages(6.0, BITE))
        alarm = _frames_until(ws, lambda f: f["type"] == "alarm")
        assert alarm["event"]["alarm"] == "bite" and alarm["event"]["state"] == "raised"
        r = app.client.post("/api/rods/rod-1/reel", json={"action": "in", "speed_m_s": 0.4}, headers=app.auth)
        assert r.status_code == 200
        cmd = _frames_until(ws, lambda f: f["type"] == "reel_cmd")
        assert cmd["command"]["action"] == "in" and cmd["command"]["speed_m_s"] == 0.4
        tick = _frames_until(ws, lambda f: f["type"] == "tick")
        assert tick["alarm_seq"] >= alarm["alarm_seq"]
