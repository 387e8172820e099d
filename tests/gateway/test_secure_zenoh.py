"""The secure setup of docs/security.md on loopback (issue 13, item 6): certificates from scripts/make-certs.sh, configs
from gateway.ingest.secure_config, the gateway started with `--zenoh-config` as the mTLS router with access control.
A device publishes its own data and receives the gateway's commands; a rogue peer with a valid certificate of another
device cannot spoof the device, pay out its line or fake an alarm, and a peer without a certificate cannot connect."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import zenoh
from fastapi.testclient import TestClient

from bench.bite_latency import free_port
from gateway import schemas
from gateway.app import create_app
from gateway.config import Settings
from gateway.ingest import secure_config
from tests.gateway.conftest import rod_messages, wait_for

REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.timeout(120),
              pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make certificates")]


def test_rogue_peer_is_refused_by_the_gateway_router(tmp_path: Path) -> None:
    certs, confs, port = tmp_path / "certs", tmp_path / "zenoh", free_port()
    subprocess.run([str(REPO / "scripts/make-certs.sh"), str(certs), "gateway", "rod-1", "rod-2", "observer"],
                   check=True, capture_output=True)  # fmt: skip
    endpoint = f"tls/127.0.0.1:{port}"
    secure_config.write(certs, confs, {"rod-1": "rod", "rod-2": "rod"}, [endpoint], [endpoint])
    settings = Settings(data_dir=tmp_path / "data", zenoh_mode="router", zenoh_listen=[endpoint],
                        zenoh_config_file=confs / "gateway.json5")  # fmt: skip

    def session(name: str) -> zenoh.Session:
        return zenoh.open(zenoh.Config.from_file(str(confs / f"{name}.json5")))

    with TestClient(create_app(settings, warm_up=False)) as client, session("rod-1") as rod, \
            session("rod-2") as rogue, session("observer") as observer:  # fmt: skip
        stats = lambda: client.get("/api/stats").json()  # noqa: E731
        seen: list[tuple[str, bytes]] = []
        for sel in ("gw/**", "rig/**"):
            observer.declare_subscriber(sel, lambda s: seen.append((str(s.key_expr), s.payload.to_bytes())))
        cmds: list[bytes] = []
        rod.declare_subscriber(schemas.reel_cmd_key("rod-1"), lambda s: cmds.append(s.payload.to_bytes()))
        token = rod.liveliness().declare_token(schemas.device_token_key("rod", "rod-1"))
        wait_for(lambda: client.get("/api/devices/rod-1").status_code == 200
                 and client.get("/api/devices/rod-1").json()["online"])  # fmt: skip
        real = [(k, p) for k, p in rod_messages(2.0) if k.endswith("/imu")]
        for k, p in real[:10]:
            rod.put(k, p, congestion_control=zenoh.CongestionControl.BLOCK)
        wait_for(lambda: stats()["received"] >= 10)

        # the rogue holds a valid certificate (of rod-2) and tries everything the issue saw work without auth
        spoof = json.loads(real[10][1]) | {"boot_id": 4242}
        for i in range(5):
            rogue.put("rig/rod/rod-1/imu", json.dumps(spoof | {"seq": i}).encode())
        rogue.put(schemas.reel_cmd_key("rod-1"), b'{"v":1,"cmd_id":1,"action":"out","speed_m_s":1.5}')
        fake = {"alarm": "hook_swing", "severity": "critical", "state": "raised"}
        rogue.put(schemas.alarm_key("hook", "hook-1"), json.dumps(fake).encode())
        rogue_token = rogue.liveliness().declare_token(schemas.device_token_key("rod", "rod-9"))
        with pytest.raises(zenoh.ZError):  # no certificate: no link at all
            zenoh.open(zenoh.Config.from_json5(json.dumps({
                "mode": "client", "connect": {"endpoints": [endpoint]},
                "transport": {"link": {"tls": {"root_ca_certificate": str(certs / "ca.pem")}}}})))  # fmt: skip

        for k, p in real[10:20]:  # the real device goes on
            rod.put(k, p, congestion_control=zenoh.CongestionControl.BLOCK)
        wait_for(lambda: stats()["received"] >= 20)
        r = client.post("/api/rods/rod-1/reel", json={"action": "in", "speed_m_s": 0.2},
                        headers={"Authorization": f"Bearer {(settings.data_dir / 'api_token').read_text().strip()}"})
        assert r.status_code == 200
        wait_for(lambda: len(cmds) == 1)  # the gateway's command reaches the device
        time.sleep(0.5)

        s = stats()
        assert s["received"] == 20, "a rogue packet reached the gateway"
        assert "device_conflict" not in s["rejected"]
        assert [d["device_id"] for d in client.get("/api/devices").json()] == ["rod-1"]  # no rod-9 token
        assert json.loads(cmds[0])["action"] == "in"
        assert not [k for k, _ in seen if k == schemas.alarm_key("hook", "hook-1")], "fake alarm delivered"
        assert [json.loads(p)["action"] for k, p in seen if k.endswith("/reel/cmd")] == ["in"]

        # a real device declares its publisher and streams (as devices.sim_rod does): a zenoh client puts only
        # where it knows a subscriber, so the router must declare the gateway's subscription to it; the ACL once
        # denied that and the stream stopped after the first packets
        pub = rod.declare_publisher("rig/rod/rod-1/imu", congestion_control=zenoh.CongestionControl.BLOCK)
        time.sleep(2.0)
        for _, p in real[20:40]:
            pub.put(p)
        wait_for(lambda: stats()["received"] >= 40, timeout_s=10.0)
        pub.undeclare()
        token.undeclare()
        rogue_token.undeclare()
