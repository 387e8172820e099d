"""Real-browser fixtures: the whole system (gateway + simulated rod and ball over zenoh on loopback, multicast off)
and headless Debian Chromium driven by Playwright. Every request the browser makes is recorded.

Needs `/usr/bin/chromium` (scripts/ci-apt.sh) and the `playwright` pip package; never `playwright install`.
Screenshots go to test-output/.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from bench.bite_latency import stop_process

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]  # fmt: skip
REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "test-output"
BITE_AT_S = 30.0  # device time of the scripted bite: after the page is open and the first tests ran


def wait_js(page: Any, expression: str, timeout: float = 30_000) -> None:
    """Wait until a JS expression is truthy in the page. Polls `page.evaluate` (DevTools evaluation) instead of
    `page.wait_for_function`, whose in-page polling compiles the string and so breaks the dashboard's CSP
    (no 'unsafe-eval'): the tests keep the real CSP and would see any violation by the page itself."""
    deadline = time.monotonic() + timeout / 1000.0
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            raise TimeoutError(f"not true within {timeout / 1000.0:g} s: {expression}")
        time.sleep(0.05)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def get_json(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=5) as r:
        return json.loads(r.read())


def wait_healthy(base: str, gateway: subprocess.Popen[bytes], log: Path, timeout_s: float = 120.0) -> None:
    """Wait until the gateway at `base` answers /api/health; fail with its log if it exits or takes too long."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            get_json(base + "/api/health")
            return
        except OSError:
            assert gateway.poll() is None, log.read_text()
            assert time.monotonic() < deadline, "gateway did not start"
            time.sleep(0.2)


@dataclass
class System:
    base: str
    token: str
    data_dir: Path
    procs: list[subprocess.Popen[bytes]] = field(default_factory=list)
    started_s: float = 0.0


def wait_online(system: System, devices: set[str], logs: list[Path], timeout_s: float = 120.0) -> None:
    """Wait until every one of `devices` is online at the gateway (from `system.started_s`); fail with the device
    processes' logs if one of them (`system.procs` after the gateway) exits or it takes too long."""
    while {d["device_id"] for d in get_json(system.base + "/api/devices") if d.get("online")} < devices:
        assert all(p.poll() is None for p in system.procs[1:]), [log.read_text() for log in logs]
        assert time.monotonic() - system.started_s < timeout_s, f"devices did not come online: {sorted(devices)}"
        time.sleep(0.2)


@pytest.fixture(scope="session")
def chromium_path() -> Path:
    # CI sets RIG_REQUIRE_BROWSER=1 after installing Chromium: there a missing browser is a failure, not a skip.
    missing = pytest.fail if os.environ.get("RIG_REQUIRE_BROWSER") == "1" else pytest.skip
    if not CHROMIUM.exists():
        missing(f"{CHROMIUM} not found: run scripts/ci-apt.sh (apt-get install chromium) for the browser tests")
    try:
        import playwright  # noqa: F401
    except ImportError:
        missing("pip install playwright (never `playwright install`)")
    return CHROMIUM


def child_serves_all(devices: tuple[str, ...]) -> str:
    """A parent shard id for `--shards 2` whose child shard (`<id>-1`) serves every one of `devices` (rendezvous
    hashing, gateway/shard/ownership.py): the dashboard on the parent's endpoint then shows only another shard's
    devices, and its writes (reel, acknowledge) must reach that shard."""
    from gateway.shard.ownership import ShardInfo, owner_of

    for k in range(1000):
        sid = f"browser{k}"
        shards = (ShardInfo(sid), ShardInfo(f"{sid}-1"))
        if all(owner_of(d, shards) == f"{sid}-1" for d in devices):
            return sid
    raise AssertionError("no shard id found")


@pytest.fixture(scope="module", params=[1, 2], ids=["one-shard", "two-shards"])
def system(request: pytest.FixtureRequest, chromium_path: Path,
           tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:  # fmt: skip
    """Gateway (REST on a free port, zenoh listening on another, viser on a third) and `python -m devices`
    (one rod with a scripted bite at BITE_AT_S, one ball) connected to it. With two shards (`--shards 2`) the rod
    and the ball are served by the local child shard, not by the process whose endpoint the tests use."""
    shards: int = request.param
    tmp = tmp_path_factory.mktemp("browser")
    http, zport, vport = free_port(), free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    env = {**os.environ, "RIG_VISER_PORT": str(vport), "PYTHONUNBUFFERED": "1"}
    script = tmp / "bite.json"
    script.write_text(json.dumps([{"type": "bite", "t_s": BITE_AT_S, "depth_deg": 25.0, "duration_s": 4.0}]))
    log_gw = open(tmp / "gateway.log", "wb")  # noqa: SIM115 - closed at teardown
    log_dev = open(tmp / "devices.log", "wb")  # noqa: SIM115
    argv = [sys.executable, "-m", "gateway", "--data-dir", str(tmp / "data"), "--port", str(http), "--listen", endpoint,
            "--shards", str(shards)]  # fmt: skip
    if shards == 2:
        argv += ["--shard-id", child_serves_all(("rod-1", "ball-1"))]
    gw = subprocess.Popen(argv, cwd=REPO, env=env, stdout=log_gw, stderr=subprocess.STDOUT)
    sysm = System(f"http://127.0.0.1:{http}", "", tmp / "data", [gw])
    try:
        wait_healthy(sysm.base, gw, tmp / "gateway.log")
        sysm.token = (tmp / "data" / "api_token").read_text().strip()
        dev = subprocess.Popen(
            [sys.executable, "-m", "devices", "--connect", endpoint, "--only", "rod", "--only", "ball", "--seed", "7",
             "--no-random-events", "--rod-args", f"--script {script} --no-progress"],
            cwd=REPO, env=env, stdout=log_dev, stderr=subprocess.STDOUT,
        )  # fmt: skip
        sysm.procs.append(dev)
        sysm.started_s = time.monotonic()
        wait_online(sysm, {"rod-1", "ball-1"}, [tmp / "devices.log"])
        if shards == 2:  # the devices really are the other shard's (a child that joins late takes them over)
            me = get_json(sysm.base + "/api/shards")["me"]
            deadline = time.monotonic() + 60.0
            while (served := {d["shard"] for d in get_json(sysm.base + "/api/devices")}) != {f"{me}-1"}:
                assert time.monotonic() < deadline, f"devices served by {served}, not by the child {me}-1"
                time.sleep(0.5)
        yield sysm
    finally:
        for p in reversed(sysm.procs):
            stop_process(p, 10.0, signal.SIGINT)
        log_gw.close()
        log_dev.close()


@dataclass
class Browser:
    page: Any
    requests: list[str]
    console: list[str]
    page_errors: list[str]

    def errors(self) -> list[str]:
        """Console errors and uncaught exceptions so far."""
        return [c for c in self.console if c.startswith("error")] + self.page_errors

    def shot(self, name: str, full_page: bool = True) -> Path:
        OUT.mkdir(exist_ok=True)
        path = OUT / f"{name}.png"
        self.page.evaluate("window.scrollTo(0, 0)")  # else the sticky banner lands mid-page in full-page shots
        self.page.screenshot(path=str(path), full_page=full_page)
        return path


@pytest.fixture(scope="module")
def chromium(chromium_path: Path) -> Iterator[Any]:
    """One headless Chromium per module (Playwright's sync API allows one driver per thread at a time)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(chromium_path), args=CHROMIUM_ARGS)
        yield b
        b.close()


DESKTOP = {"width": 1280, "height": 800}
PHONE = {"width": 390, "height": 844}


def _recorder(ctx: Any) -> Browser:
    rec = Browser(ctx.new_page(), [], [], [])
    ctx.on("request", lambda r: rec.requests.append(r.url))
    rec.page.on("console", lambda m: rec.console.append(f"{m.type}: {m.text}"))
    rec.page.on("pageerror", lambda e: rec.page_errors.append(str(e)))
    return rec


@pytest.fixture(scope="module")
def browser(system: System, chromium: Any) -> Iterator[Browser]:
    """A 1280 x 800 desktop page (light theme)."""
    ctx = chromium.new_context(viewport=DESKTOP, accept_downloads=True)
    yield _recorder(ctx)
    ctx.close()


@pytest.fixture(scope="module")
def phone(system: System, chromium: Any) -> Iterator[Browser]:
    """A 390 x 844 touch screen in dark mode (the system setting the page follows)."""
    ctx = chromium.new_context(viewport=PHONE, is_mobile=True, has_touch=True, device_scale_factor=2,
                               color_scheme="dark")  # fmt: skip
    yield _recorder(ctx)
    ctx.close()
