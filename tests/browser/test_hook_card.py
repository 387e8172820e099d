"""The dashboard's hook card in headless Chromium against a gateway with two simulated crane hooks over zenoh: one
whose crane tells its boom tip's moves (`sim_hook --crane-feed`, docs/protocol.md 3.7) and one without. The card
shows the angles as docs/protocol.md 3.5 defines them, the rope length the filter estimates and the crane feed's
state, and its values are the gateway's (REST) ones.
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bench.bite_latency import stop_process
from tests.browser.conftest import (
    REPO,
    Browser,
    System,
    _recorder,
    free_port,
    get_json,
    wait_healthy,
    wait_js,
    wait_online,
)

pytestmark = pytest.mark.browser
FED, UNFED = "hook-1", "yard-1"  # the crane that tells its moves, and the one that does not
DEG = 180.0 / math.pi


@pytest.fixture(scope="module")
def hooks(chromium_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    """A gateway (one shard) and two `devices.sim_hook` processes: FED swinging 4° on 12 m and slewing with
    `--crane-feed`, UNFED swinging on 8 m with no crane feed."""
    tmp = tmp_path_factory.mktemp("hooks")
    http, zport, vport = free_port(), free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    env = {**os.environ, "RIG_VISER_PORT": str(vport), "PYTHONUNBUFFERED": "1"}
    logs = [open(tmp / f"{name}.log", "wb") for name in ("gateway", FED, UNFED)]  # noqa: SIM115 - closed below
    gw = subprocess.Popen([sys.executable, "-m", "gateway", "--data-dir", str(tmp / "data"), "--port", str(http),
                           "--listen", endpoint, "--shards", "1"], cwd=REPO, env=env, stdout=logs[0],
                          stderr=subprocess.STDOUT)  # fmt: skip
    sysm = System(f"http://127.0.0.1:{http}", "", tmp / "data", [gw])
    try:
        wait_healthy(sysm.base, gw, tmp / "gateway.log")
        common = ["--connect", endpoint, "--no-progress", "--duration", "300", "--seed", "5"]
        for log, extra in ((logs[1], ["--id-prefix", "hook", "--rope-length", "12", "--swing-deg", "4",
                                      "--slew", "8,30,40,25", "--crane-feed"]),
                           (logs[2], ["--id-prefix", "yard", "--rope-length", "8", "--swing-deg", "3"])):  # fmt: skip
            sysm.procs.append(subprocess.Popen([sys.executable, "-m", "devices.sim_hook", *common, *extra], cwd=REPO,
                                               env=env, stdout=log, stderr=subprocess.STDOUT))  # fmt: skip
        sysm.started_s = time.monotonic()
        wait_online(sysm, {FED, UNFED}, [tmp / f"{n}.log" for n in (FED, UNFED)])
        yield sysm
    finally:
        for p in reversed(sysm.procs):
            stop_process(p, 10.0, signal.SIGINT)
        for log in logs:
            log.close()


@pytest.fixture(scope="module")
def page(hooks: System, chromium: Any) -> Iterator[Browser]:
    ctx = chromium.new_context(viewport={"width": 1280, "height": 800})
    yield _recorder(ctx)
    ctx.close()


def _facts(b: Browser, device: str) -> dict[str, str]:
    """The card's facts as the page shows them: {label: value}."""
    return dict(b.page.evaluate(
        f"""[...document.querySelectorAll('[data-testid="facts-{device}"] [data-field]')]
        .map((s) => [s.dataset.field, s.querySelector('b').textContent])"""
    ))  # fmt: skip


def _number(text: str) -> float:
    m = re.search(r"-?\d+(\.\d+)?", text)
    assert m, f"no number in {text!r}"
    return float(m.group())


def test_hook_cards_show_the_angles_the_rope_and_the_crane_feed(hooks: System, page: Browser) -> None:
    p = page.page
    p.goto(hooks.base + "/")
    p.get_by_test_id("conn").filter(has_text="live").wait_for(timeout=15_000)
    for device in (FED, UNFED):
        p.get_by_test_id(f"fleet-{device}").wait_for(timeout=15_000)
    # the crane's feed reaches the filter: "in use" (its newest sample within the gateway's MAX_HOLD_S) on the fed
    # hook's card, "none" on the other's
    wait_js(p, f"""[...document.querySelectorAll('[data-testid="facts-{FED}"] [data-field="crane feed"] b')]
            .some((b) => b.textContent === 'in use')""", timeout=30_000)  # fmt: skip
    assert _facts(page, UNFED)["crane feed"] == "none"
    rest = get_json(hooks.base + f"/api/devices/{FED}")
    assert rest["crane_feed"]["packets"] > 0
    for device, rope_m in ((FED, 12.0), (UNFED, 8.0)):
        wait_js(p, f"""[...document.querySelectorAll('[data-testid="facts-{device}"] [data-field]')]
                .some((s) => s.dataset.field === 'rope (estimated)')""", timeout=30_000)  # fmt: skip
        facts = _facts(page, device)
        for label in ("swing Θ", "displacement bearing", "torsion φ", "Φ (paper 001 eq. 7)"):
            assert label in facts, (device, facts)
        assert "CCW from E" in facts["displacement bearing"] and "CCW from above" in facts["torsion φ"]
        swing_deg = _number(facts["swing Θ"])
        assert 0.0 <= swing_deg < 10.0, facts  # swinging 3-4° (not told the rope: it may read provisional at first)
        card = get_json(hooks.base + f"/api/devices/{device}")["swing"]
        # the card's Θ is the gateway's, within what a hook's swing changes between the page's frame and this read
        assert abs(swing_deg - card["swing_angle_rad"] * DEG) < 3.0, (facts, card)
        assert 0.3 * rope_m < _number(facts["rope (estimated)"]) < 3.0 * rope_m, facts
        row = p.get_by_test_id(f"fleet-{device}").inner_text()
        assert re.search(r"swing -?\d", row), row  # the fleet table's key metric for a hook: its swing angle
    # not told its rope and swinging at start, a hook reads "provisional" until its start is redone told the length
    # it found (2-15 s of samples, docs/protocol.md 3.5); then the card says so no more, as REST
    for device in (FED, UNFED):
        wait_js(p, f"""[...document.querySelectorAll('[data-testid="facts-{device}"] [data-field="swing Θ"] b')]
                .some((b) => !b.textContent.includes('provisional'))""", timeout=40_000)  # fmt: skip
        assert not get_json(hooks.base + f"/api/devices/{device}")["swing"].get("provisional"), device
    page.shot("dashboard_hooks")
    assert not page.errors(), page.errors()


def test_a_configured_rest_heading_brings_the_torsion_sigma_to_the_card(hooks: System, page: Browser) -> None:
    """With `rest_heading_deg` set over REST the hook's Swing carries `torsion_std_rad` (docs/protocol.md 3.5) and
    the card shows it as "± σ° (1σ)" after the torsion; the other hook, torsion from its first fused heading, has
    neither."""
    import httpx

    p = page.page
    p.goto(hooks.base + "/")
    p.get_by_test_id(f"fleet-{FED}").wait_for(timeout=15_000)
    token = (hooks.data_dir / "api_token").read_text().strip()
    r = httpx.put(f"{hooks.base}/api/devices/{FED}/settings", headers={"Authorization": f"Bearer {token}"},
                  json={"kind": "hook", "thresholds": {"rest_heading_deg": 20.0}}, timeout=10.0)  # fmt: skip
    assert r.status_code == 200, r.text
    wait_js(p, f"""[...document.querySelectorAll('[data-testid="facts-{FED}"] [data-field="torsion φ"] b')]
            .some((b) => b.textContent.includes('(1σ)'))""", timeout=30_000)  # fmt: skip
    sigma_deg = float(re.findall(r"± (\d+(?:\.\d+)?)°", _facts(page, FED)["torsion φ"])[0])
    swing = get_json(hooks.base + f"/api/devices/{FED}")["swing"]
    assert swing["rest_heading_rad"] == pytest.approx(math.radians(20.0))
    # the gateway's σ: at least the 0.5° floor, and the card's within what the σ moves between frame and read
    assert 0.5 <= swing["torsion_std_rad"] * DEG < 90.0 and 0.5 <= sigma_deg < 90.0, (swing, sigma_deg)
    assert "±" not in _facts(page, UNFED)["torsion φ"]
    assert get_json(hooks.base + f"/api/devices/{UNFED}")["swing"].get("torsion_std_rad") is None
    assert not page.errors(), page.errors()


def test_a_calibration_set_over_rest_shows_on_the_hook_card(hooks: System, page: Browser) -> None:
    """The compass calibration `calibrate --hook-mount` prints, set with `PUT /api/devices/{id}/settings`: the card
    says "IMU calibration: applied" and REST's card `imu_calibration` true; the other hook's says "none". (Its fusion
    restarts on the change, so this runs last.)"""
    import httpx

    p = page.page
    p.goto(hooks.base + "/")
    p.get_by_test_id(f"fleet-{UNFED}").wait_for(timeout=15_000)
    wait_js(p, f"""[...document.querySelectorAll('[data-testid="facts-{UNFED}"] [data-field="IMU calibration"] b')]
            .some((b) => b.textContent === 'none')""", timeout=15_000)  # fmt: skip
    token = (hooks.data_dir / "api_token").read_text().strip()
    cal = {"acc_offset_m_s2": [0.0, 0.0, 0.0], "acc_scale": [1.0, 1.0, 1.0], "mag_offset_uT": [1.5, -2.0, 0.0],
           "mag_soft_iron": [[1.01, 0.0, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.0]]}  # fmt: skip
    r = httpx.put(f"{hooks.base}/api/devices/{UNFED}/settings", json={"kind": "hook", "calibration": cal},
                  headers={"Authorization": f"Bearer {token}"}, timeout=10.0)  # fmt: skip
    assert r.status_code == 200, r.text
    wait_js(p, f"""[...document.querySelectorAll('[data-testid="facts-{UNFED}"] [data-field="IMU calibration"] b')]
            .some((b) => b.textContent === 'applied')""", timeout=15_000)  # fmt: skip
    assert get_json(hooks.base + f"/api/devices/{UNFED}")["imu_calibration"] is True
    assert _facts(page, FED)["IMU calibration"] == "none"
    assert get_json(hooks.base + f"/api/devices/{FED}")["imu_calibration"] is False
