"""The dashboard and the 3-D view in headless Chromium against the running system (see conftest.py).

Tests run in file order on one system and one browser page: live values, thresholds (token prompt, 422 message),
the scripted bite (banner, alarm row, acknowledge), a reel command reaching the simulated reel, the viser page,
and finally that no request left localhost.
"""

from __future__ import annotations

import json
import time
import urllib.request
from urllib.parse import urlparse

import pytest

from tests.browser.conftest import BITE_AT_S, OUT, Browser, System, get_json

pytestmark = pytest.mark.browser
LOCAL_HOSTS = {"127.0.0.1", "localhost"}


def _series_len(b: Browser, device: str, src: str = "att") -> int:
    return int(b.page.evaluate(f"Devices.get('{device}') ? Devices.get('{device}').{src}.t.length : 0"))


def test_dashboard_shows_live_values(system: System, browser: Browser) -> None:
    page = browser.page
    page.goto(system.base + "/")
    page.get_by_test_id("conn").filter(has_text="live").wait_for(timeout=15_000)
    page.get_by_test_id("card-rod-1").wait_for(timeout=15_000)
    page.get_by_test_id("card-ball-1").wait_for(timeout=15_000)
    page.wait_for_function("Devices.get('rod-1') && Devices.get('rod-1').acc.t.length > 20", timeout=15_000)
    n0, acc0 = _series_len(browser, "rod-1"), _series_len(browser, "rod-1", "acc")
    age0 = page.get_by_test_id("card-rod-1").locator('[data-field="last packet"]').inner_text()
    time.sleep(1.5)
    n1, acc1 = _series_len(browser, "rod-1"), _series_len(browser, "rod-1", "acc")
    assert n1 > n0 + 10, f"attitude samples did not grow: {n0} -> {n1}"
    assert acc1 > acc0 + 10, f"acceleration samples did not grow: {acc0} -> {acc1}"
    pitches = page.evaluate("Devices.get('rod-1').att.v.pitch_deg.slice(-100)")
    assert len(set(pitches)) > 5, "pitch is not changing at all"
    rest = get_json(system.base + "/api/devices/rod-1")["attitude"]["pitch_rad"]
    assert abs(pitches[-1] - rest * 57.29578) < 5.0  # plotted pitch is the gateway's (within the 1.5 s of motion)
    assert page.get_by_test_id("card-rod-1").locator('[data-field="status"]').inner_text() == "online"
    assert age0.endswith("s ago")
    assert page.get_by_test_id("spots").locator("tbody tr").first.inner_text().startswith("1")
    # the plot is really drawn: pixels of the pitch line colour (#e53e3e) on the attitude canvas
    red = page.evaluate(
        """() => { const c = document.querySelector('[data-testid="chart-rod-1-attitude"]');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
        for (let i = 0; i < d.length; i += 4) if (d[i] > 200 && d[i + 1] < 110 && d[i + 2] < 110) n++;
        return n; }"""
    )
    assert red > 100, f"pitch line not drawn ({red} red pixels)"
    page.get_by_test_id("pause").click()
    frozen = page.evaluate("View.pausedAt")
    assert page.get_by_test_id("pause").inner_text() == "Resume" and frozen > 0
    page.get_by_test_id("pause").click()
    browser.shot("dashboard_live")
    assert not browser.page_errors, browser.page_errors


def test_threshold_form_shows_validation_message_then_saves(system: System, browser: Browser) -> None:
    page = browser.page
    field = page.get_by_test_id("th-rod-bite_deviation_deg")
    field.fill("50")
    page.get_by_test_id("th-rod").get_by_role("button").click()
    # first write: the dashboard asks for the token once
    page.get_by_test_id("token-input").fill(system.token)
    page.get_by_test_id("token-ok").click()
    errors = page.get_by_test_id("th-rod-errors")
    errors.locator("li").first.wait_for(timeout=5_000)
    assert "bite_deviation_deg" in errors.inner_text() and "45" in errors.inner_text()
    browser.shot("dashboard_threshold_error")
    assert get_json(system.base + "/api/thresholds/rod")["bite_deviation_deg"] == 10.0  # nothing stored
    field.fill("9")
    page.get_by_test_id("th-rod").get_by_role("button").click()
    page.get_by_test_id("th-rod").locator("p.ok").filter(has_text="saved").wait_for(timeout=5_000)
    assert errors.locator("li").count() == 0
    assert get_json(system.base + "/api/thresholds/rod")["bite_deviation_deg"] == 9.0
    assert page.evaluate("sessionStorage.getItem('rig_token')") == system.token  # asked once, kept


def test_scripted_bite_raises_loud_alarm_and_ack_clears_banner(system: System, browser: Browser) -> None:
    page = browser.page
    remaining_s = BITE_AT_S - (time.monotonic() - system.started_s)
    banner = page.get_by_test_id("bite-banner")
    banner.wait_for(state="visible", timeout=int((max(remaining_s, 0) + 60) * 1000))
    assert "BITE on rod-1" in banner.inner_text()
    row = page.locator('[data-testid="alarms"] tr[data-type="bite"]').first
    row.wait_for(timeout=5_000)
    assert "major" in row.inner_text() and "rod-1" in row.inner_text()
    assert "sev-major" in (row.get_attribute("class") or "")
    browser.shot("dashboard_bite")
    page.get_by_test_id("bite-ack").click()
    banner.wait_for(state="hidden", timeout=5_000)
    row.get_by_test_id("acked").wait_for(timeout=5_000)
    bites = get_json(system.base + "/api/alarms?type=bite")["items"]
    assert bites and bites[0]["acknowledged"] and bites[0]["acknowledged_by"] == "api"
    page.get_by_test_id("alarms-history-tab").click()
    page.locator('[data-testid="alarms"] tr[data-type="bite"]').first.wait_for(timeout=5_000)
    browser.shot("dashboard_alarm_history")
    page.get_by_test_id("alarms-active-tab").click()


def test_reel_button_reaches_the_simulated_reel(system: System, browser: Browser) -> None:
    page = browser.page
    page.get_by_test_id("reel-speed-rod-1").fill("0.3")
    page.get_by_test_id("reel-in-rod-1").click()
    page.get_by_test_id("reel-msg-rod-1").filter(has_text="sent in").wait_for(timeout=5_000)
    cmd_id = int(page.get_by_test_id("reel-msg-rod-1").inner_text().rsplit("#", 1)[1])
    page.get_by_test_id("reel-state-rod-1").filter(has_text="in /").wait_for(timeout=10_000)
    reel = get_json(system.base + "/api/devices/rod-1")["reel"]
    assert reel["mode"] == "in" and reel["last_cmd_id"] == cmd_id  # the sim reel acknowledged this command
    assert "tension" in page.get_by_test_id("tension-rod-1").inner_text()
    browser.shot("dashboard_reel_in")
    page.get_by_test_id("reel-stop-rod-1").click()
    page.get_by_test_id("reel-state-rod-1").filter(has_text="stop /").wait_for(timeout=10_000)


def test_viser_page_connects_without_errors(system: System, browser: Browser) -> None:
    page = browser.page
    with page.context.expect_page(timeout=15_000) as new:
        page.get_by_test_id("view3d").click()
    view = new.value
    console: list[str] = []
    view.on("console", lambda m: console.append(f"{m.type}: {m.text}"))
    view.wait_for_load_state()
    view.get_by_text("rig-gateway 3D").first.wait_for(timeout=30_000)
    view.get_by_text("rod-1 (rod)").first.wait_for(timeout=30_000)  # status line: picked device, live angles
    info = get_json(system.base + "/api/view3d")
    assert info["running"] and info["clients"] >= 1 and "rod-1" in info["devices"]
    assert urlparse(view.url).port == info["port"] and urlparse(view.url).hostname in LOCAL_HOSTS
    time.sleep(4.0)  # let the scene fade in before the screenshot
    assert view.locator("canvas").count() >= 1
    errors = [c for c in console if c.startswith("error")]
    assert not errors, errors
    assert view.get_by_role("button", name="Share").count() == 0  # share button hidden (no external tunnel)
    view.screenshot(path=str(OUT / "view3d.png"))
    view.close()


def test_no_request_left_localhost(system: System, browser: Browser) -> None:
    assert browser.requests, "no requests recorded"
    outside = sorted({u for u in browser.requests if urlparse(u).hostname not in LOCAL_HOSTS and
                      not u.startswith(("data:", "blob:"))})  # fmt: skip
    assert not outside, outside
    hosts = {urlparse(u).netloc for u in browser.requests if "://" in u}
    assert len(hosts) >= 2, hosts  # the dashboard and the viser server both served pages
    assert not browser.page_errors, browser.page_errors
    with urllib.request.urlopen(system.base + "/api/live", timeout=5) as r:
        assert json.loads(r.read())["ticks"] > 0
