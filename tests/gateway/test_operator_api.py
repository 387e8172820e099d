"""Operator-facing HTTP: /metrics in the Prometheus text format, API docs served without a CDN, readiness."""

from __future__ import annotations

import re
import time
from collections.abc import Callable

from prometheus_client.parser import text_string_to_metric_families

from tests.gateway.conftest import Running, rod_messages


def _families(text: str) -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
    out: dict[str, dict[tuple[tuple[str, str], ...], float]] = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out.setdefault(s.name, {})[tuple(sorted(s.labels.items()))] = s.value
    return out


def test_metrics_count_ingest_rejects_and_active_alarms(running: Callable[[], Running]) -> None:
    r = running()
    r.feed(rod_messages(1.0))
    r.feed([("rig/rod/rod-1/imu", b"not json")])
    resp = r.client.get("/metrics")
    assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/plain")
    m = _families(resp.text)
    assert m["rig_packets_total"][(("device_id", "rod-1"), ("kind", "rod"))] >= 20  # 1 s of imu + reel packets
    assert m["rig_ingest_received_total"][()] >= 21
    assert sum(m["rig_rejects_total"].values()) >= 1
    assert m["rig_packet_loss_ratio"][(("device_id", "rod-1"), ("kind", "rod"))] == 0.0
    assert "rig_ingest_queue_depth" in m and "rig_devices_online" in m
    assert m["rig_ws_clients"][()] == 0 and m["rig_ws_dropped_frames"][()] == 0
    with r.client.websocket_connect("/ws/stream"):
        assert _families(r.client.get("/metrics").text)["rig_ws_clients"][()] == 1


def test_metrics_latency_histogram_and_alarm_gauge_after_a_bite(running: Callable[[], Running]) -> None:
    r = running()
    r.feed(rod_messages(6.0, script=[{"type": "bite", "t_s": 3.0, "depth_deg": 25.0, "duration_s": 2.0}]), paced=True)
    m = _families(r.client.get("/metrics").text)
    counts = m["rig_sample_to_publish_seconds_count"]
    assert counts[(("kind", "rod"), ("topic", "attitude"))] > 10
    assert m["rig_alarms_active"][(("severity", "major"), ("type", "bite"))] == 1


def test_docs_pages_use_only_local_files(running: Callable[[], Running]) -> None:
    r = running()
    for page in ("/docs", "/redoc"):
        html = r.client.get(page).text
        refs = re.findall(r'(?:src|href)="([^"]+)"', html) + re.findall(r"url: ?'([^']+)'", html)
        assert refs, page
        assert all(ref.startswith("/") for ref in refs), f"{page} loads from elsewhere: {refs}"
        for ref in refs:
            if ref.startswith(("/static-offline-docs/", "/redoc-assets/")):
                assert r.client.get(ref).status_code == 200, ref
        assert "cdn" not in html.lower() and "fonts.googleapis" not in html
    bundle = r.client.get("/redoc-assets/redoc.standalone.js").text
    assert len(bundle) > 100_000 and "cdn.redoc.ly" not in bundle  # ReDoc's one external image is patched out


def test_openapi_documents_token_errors_and_curl_examples(running: Callable[[], Running]) -> None:
    spec = running().client.get("/openapi.json").json()
    ack = spec["paths"]["/api/alarms/{alarm_id}/ack"]["post"]
    assert {"401", "403", "422"} <= set(ack["responses"])
    assert 'Authorization: Bearer $TOKEN' in ack["x-codeSamples"][0]["source"]
    put = spec["paths"]["/api/thresholds/{kind}"]["put"]
    assert "-d '{" in put["x-codeSamples"][0]["source"]
    get = spec["paths"]["/api/devices"]["get"]
    assert "Authorization" not in get["x-codeSamples"][0]["source"] and "401" not in get["responses"]
    assert "api_token" in spec["info"]["description"]


def test_health_is_ready_once_ingest_runs(running: Callable[[], Running]) -> None:
    assert running().client.get("/api/health").json()["ready"] is True


def _wait(pred: Callable[[], bool], timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, "condition not reached in time"
        time.sleep(0.05)


def test_device_offline_alarm_is_raised_then_cleared_by_presence(running: Callable[[], Running]) -> None:
    r = running()
    r.bus.set_alive("rig/hook/hook-3", True)
    _wait(lambda: r.client.get("/api/health").json()["devices_online"] == 1)
    r.bus.set_alive("rig/hook/hook-3", False)
    active = lambda: r.client.get("/api/alarms?status=active&type=device_offline").json()["items"]  # noqa: E731
    _wait(lambda: len(active()) == 1)
    [a] = active()
    assert (a["device_id"], a["severity"]) == ("hook-3", "major") and "offline" in a["message"]
    assert [e["alarm"] for e in r.bus.sent_json("gw/hook/hook-3/alarm")] == ["device_offline"]
    r.bus.set_alive("rig/hook/hook-3", True)
    _wait(lambda: not active())
    assert r.client.get("/api/alarms?type=device_offline").json()["items"][0]["status"] == "cleared"


def test_manual_clear_needs_the_token_and_publishes_the_clear(running: Callable[[], Running]) -> None:
    r = running()
    r.bus.set_alive("rig/rod/rod-2", True)
    r.bus.set_alive("rig/rod/rod-2", False)  # a device that will not come back: its offline alarm is stale
    _wait(lambda: r.client.get("/api/alarms?status=active").json()["total"] == 1)
    alarm_id = r.client.get("/api/alarms?status=active").json()["items"][0]["id"]
    assert r.client.post(f"/api/alarms/{alarm_id}/clear").status_code == 401
    assert r.client.post(f"/api/alarms/{alarm_id}/clear", headers={"Authorization": "Bearer nope"}).status_code == 403
    resp = r.client.post(f"/api/alarms/{alarm_id}/clear", headers=r.auth)
    assert resp.status_code == 200, resp.text
    assert resp.json()["status"] == "cleared" and "cleared by hand" in resp.json()["message"]
    assert r.client.get("/api/alarms?status=active").json()["total"] == 0
    assert r.bus.sent_json("gw/rod/rod-2/alarm")[-1]["state"] == "cleared"
    assert r.client.post(f"/api/alarms/{alarm_id}/clear", headers=r.auth).status_code == 404


def test_history_is_bounded_decimated_and_keeps_peaks() -> None:
    from gateway.api.routes.history import DeviceHistory

    h = DeviceHistory(bucket_s=0.5, maxlen=10)
    for k in range(1000):  # 10 s at 100 Hz: 20 buckets, only the newest 10 kept (+ the open one)
        t = 1000.0 + k / 100
        h.add(t, pitch_deg=float(k), tension_n=100.0 if k == 955 else 1.0, direction_deg=179.0 if k % 2 else -179.0)
    cols = h.columns(0.0, 10_000)
    assert len(cols["t_s"]) == 11 and cols["t_s"] == sorted(cols["t_s"])
    assert cols["pitch_deg"][-2:] == [924.5, 974.5]  # bucket means of samples 900..949 and (open) 950..999
    assert max(cols["tension_n"]) == 100.0  # a one-sample spike survives decimation (max)
    assert set(cols["direction_deg"]) <= {179.0, -179.0}  # no mean across the ±180 wrap
    small = h.columns(0.0, 4)
    assert len(small["t_s"]) <= 4 and small["t_s"][-1] == cols["t_s"][-1]


def test_history_memory_is_fixed_once_a_device_has_sent_its_fields() -> None:
    """An hour of a rod's history fits in ~200 kB allocated up front, and a second hour adds nothing (the deque
    of dicts it replaced held 2.8 MB per rod-hour, growing all hour: 2.8 GB at 1000 devices)."""
    import tracemalloc

    from gateway.api.routes.history import DeviceHistory

    fields = ("roll_deg", "pitch_deg", "yaw_deg", "tension_n", "line_out_m")
    tracemalloc.start()
    try:
        h = DeviceHistory(bucket_s=0.5, maxlen=7200)
        sizes = []
        for hour in range(2):
            for k in range(36_000):  # 10 Hz for an hour
                h.add(hour * 3600.0 + k / 10, **{f: float(k % 97) for f in fields})
            sizes.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    assert sizes[0] < 300_000, sizes
    assert abs(sizes[1] - sizes[0]) < 20_000, sizes
    cols = h.columns(0.0, 100_000)
    assert len(cols["t_s"]) == 7201 and cols["t_s"][0] > 3599.0  # the newest hour (+ the open bucket)


def test_history_field_that_arrives_late_is_null_before() -> None:
    from gateway.api.routes.history import DeviceHistory

    h = DeviceHistory(bucket_s=0.5, maxlen=100)
    for k in range(40):
        extra = {"tension_n": 2.5} if k >= 20 else {}
        h.add(k * 0.25, pitch_deg=1.125, **extra)
    cols = h.columns(0.0, 1000)
    assert cols["tension_n"][:10] == [None] * 10 and cols["tension_n"][10:] == [2.5] * 10
    assert cols["pitch_deg"] == [1.125] * 20 and "roll_deg" not in cols
    assert h.columns(1e9, 10) == {"t_s": []}


def test_history_route_fills_from_the_live_pipeline(running: Callable[[], Running]) -> None:
    r = running()
    r.feed(rod_messages(3.0), paced=True)
    _wait(lambda: len(r.client.get("/api/history/rod-1").json()["series"]["t_s"]) >= 3)
    series = r.client.get("/api/history/rod-1?seconds=3600").json()["series"]
    assert {"pitch_deg", "roll_deg", "yaw_deg"} <= set(series)
    assert all(abs(p) < 90 for p in series["pitch_deg"] if p is not None)
    overview = r.client.get("/api/history?max_points=5").json()["devices"]["rod-1"]
    assert 1 <= len(overview["t_s"]) <= 5
    assert r.client.get("/api/history/nope").status_code == 404
