"""Browser side (issue 13, item 9): /ws/stream checks Origin and token, the Host header is checked (DNS rebinding),
responses carry CSP and frame options, the database is 0600 in a 0700 folder."""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

import pytest
from starlette.websockets import WebSocketDisconnect

from gateway.api.security import host_allowed
from gateway.config import Settings
from gateway.store import Store
from tests.gateway.conftest import Running


def test_ws_from_a_foreign_origin_needs_the_token(running: Callable[[], Running]) -> None:
    """Old code: any page the operator visited could open /ws/stream and read the live data."""
    app = running()
    with pytest.raises(WebSocketDisconnect) as exc:
        with app.client.websocket_connect("/ws/stream", headers={"Origin": "http://evil.example"}) as ws:
            ws.receive_text()
    assert exc.value.code == 1008
    with pytest.raises(WebSocketDisconnect):
        with app.client.websocket_connect("/ws/stream?token=wrong", headers={"Origin": "http://evil.example"}) as ws:
            ws.receive_text()
    with app.client.websocket_connect(f"/ws/stream?token={app.token}", headers={"Origin": "http://evil.example"}) as ws:
        assert '"hello"' in ws.receive_text()
    # the dashboard itself (same origin) and non-browser clients (no Origin) need no token
    with app.client.websocket_connect("/ws/stream", headers={"Origin": "http://testserver"}) as ws:
        assert '"hello"' in ws.receive_text()
    with app.client.websocket_connect("/ws/stream") as ws:
        assert '"hello"' in ws.receive_text()


def test_rebound_host_names_are_refused(running: Callable[[], Running]) -> None:
    """Old code answered any Host, so a DNS-rebinding page (Host: attacker's name) could read /api and the stream."""
    app = running()
    r = app.client.get("/api/health", headers={"Host": "attacker.example:8000"})
    assert r.status_code == 421
    with pytest.raises(WebSocketDisconnect):
        with app.client.websocket_connect("/ws/stream", headers={"Host": "attacker.example"}) as ws:
            ws.receive_text()
    for host in ("127.0.0.1:8000", "[::1]:8000", "localhost:8000", "rig-gw", "rig-gw.local", "192.168.1.20"):
        assert app.client.get("/api/health", headers={"Host": host}).status_code == 200, host


def test_allowed_hosts_extend_the_list() -> None:
    assert not host_allowed("gw.example.org")
    assert host_allowed("gw.example.org:8000", ["gw.example.org"])
    assert not host_allowed("a;script-src *")  # never into the CSP header


def test_responses_carry_csp_and_frame_options(running: Callable[[], Running]) -> None:
    app = running()
    for path in ("/", "/api/health"):
        h = app.client.get(path).headers
        assert "frame-ancestors 'none'" in h["content-security-policy"] and "script-src 'self'" in h[
            "content-security-policy"]
        assert h["x-frame-options"] == "DENY" and h["x-content-type-options"] == "nosniff"
    assert "content-security-policy" not in app.client.get("/docs").headers  # Swagger UI needs inline script


def test_database_and_folder_are_owner_only(tmp_path: Path) -> None:
    """Old code: 0644 database in a 0755 folder (with the usual umask 022)."""
    old = os.umask(0o022)
    try:
        settings = Settings(data_dir=tmp_path / "data", zenoh_listen=[])
        with Store(settings.db_path) as store:
            store.log_event(0.0, "x")
        assert stat.S_IMODE(settings.data_dir.stat().st_mode) == 0o700
        for f in settings.data_dir.iterdir():
            assert stat.S_IMODE(f.stat().st_mode) == 0o600, f
        loose = tmp_path / "loose"
        loose.mkdir(mode=0o755)
        (loose / "gateway.sqlite3").touch(mode=0o644)
        with Store(loose / "gateway.sqlite3"):
            pass
        assert stat.S_IMODE(loose.stat().st_mode) == 0o700
        assert stat.S_IMODE((loose / "gateway.sqlite3").stat().st_mode) == 0o600
    finally:
        os.umask(old)


def test_huge_request_bodies_are_refused_before_the_token_check(running: Callable[[], Running]) -> None:
    """FastAPI reads a body before its dependencies check the token: a 20 MB body without a token was read whole."""
    app = running()
    big = b'{"x": "' + b"y" * 20_000_000 + b'"}'
    r = app.client.put("/api/thresholds/rod", content=big, headers={"Content-Type": "application/json"})
    assert r.status_code == 413

    def chunks():  # no Content-Length: counted as it arrives
        for _ in range(40):
            yield b"y" * 100_000

    r = app.client.put("/api/thresholds/rod", content=chunks(), headers={"Content-Type": "application/json"})
    assert r.status_code == 413
    ok = app.client.put("/api/thresholds/rod", json={"sensitivity": 4}, headers=app.auth)
    assert ok.status_code == 200, ok.text
    assert app.client.get("/api/health").status_code == 200
