"""The dashboard, the API docs and the 3-D view in headless Chromium against the running system (conftest.py).

Tests run in file order on one system and one desktop page (1280 x 800) plus a phone (390 x 844, dark): live values
in the fleet table and the plots, history after a reload, thresholds (token prompt, 422 message), the scripted
bite (banner, alarm row within 1 s, acknowledge), a reel command reaching the simulated reel, the phone layout, the
docs pages offline, the viser page, no request leaving localhost, and last the stale state when the devices and
then the gateway stop. Screenshots go to test-output/.
"""

from __future__ import annotations

import json
import re
import time
import urllib.request
from typing import Any
from urllib.parse import urlparse

import pytest

from tests.browser.conftest import BITE_AT_S, OUT, Browser, System, get_json, wait_js

pytestmark = pytest.mark.browser
LOCAL_HOSTS = {"127.0.0.1", "localhost"}
NO_SIDEWAYS_SCROLL = "document.documentElement.scrollWidth <= window.innerWidth"


def _series_len(b: Browser, device: str, src: str = "att") -> int:
    return int(b.page.evaluate(f"Devices.get('{device}') ? Devices.get('{device}').{src}.t.length : 0"))


def _coloured_pixels(b: Browser, testid: str, rgb_test: str) -> int:
    """Pixels of a plot's canvas that pass `rgb_test` (JS over r, g, b)."""
    return int(b.page.evaluate(
        f"""() => {{ const c = document.querySelector('[data-testid="{testid}"] canvas');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
        for (let i = 0; i < d.length; i += 4) {{ const r = d[i], g = d[i + 1], b = d[i + 2]; if ({rgb_test}) n++; }}
        return n; }}"""
    ))  # fmt: skip


def test_dashboard_shows_live_values(system: System, browser: Browser) -> None:
    page = browser.page
    page.goto(system.base + "/")
    page.get_by_test_id("conn").filter(has_text="live").wait_for(timeout=15_000)
    page.get_by_test_id("fleet-rod-1").wait_for(timeout=15_000)
    page.get_by_test_id("fleet-ball-1").wait_for(timeout=15_000)
    wait_js(page, "Devices.get('rod-1') && Devices.get('rod-1').acc.t.length > 20", timeout=15_000)
    n0, acc0 = _series_len(browser, "rod-1"), _series_len(browser, "rod-1", "acc")
    time.sleep(1.5)
    n1, acc1 = _series_len(browser, "rod-1"), _series_len(browser, "rod-1", "acc")
    assert n1 > n0 + 10, f"attitude samples did not grow: {n0} -> {n1}"
    assert acc1 > acc0 + 10, f"acceleration samples did not grow: {acc0} -> {acc1}"
    pitches = [p for p in page.evaluate("Devices.get('rod-1').att.v.pitch_deg.slice(-100)") if p is not None]
    assert len(set(pitches)) > 5, "pitch is not changing at all"
    rest = get_json(system.base + "/api/devices/rod-1")["attitude"]["pitch_rad"]
    assert abs(pitches[-1] - rest * 57.29578) < 5.0  # plotted pitch is the gateway's (within the 1.5 s of motion)
    row = page.get_by_test_id("fleet-rod-1")
    assert row.locator("[data-status]").get_attribute("data-status") == "online"
    assert "pitch" in row.inner_text() and "s ago" in row.inner_text()
    assert page.get_by_test_id("spots").locator("tbody tr").first.inner_text().startswith("1")
    # the plot is really drawn: pixels of the pitch line colour (#e53e3e) on the attitude canvas
    page.get_by_test_id("range").select_option("60")
    time.sleep(0.5)
    red = _coloured_pixels(browser, "chart-rod-1-attitude", "r > 200 && g < 110 && b < 110")
    assert red > 40, f"pitch line not drawn ({red} red pixels)"
    ticks = page.evaluate("Devices.get('rod-1').charts[0].u.axes[0]._values")  # the x tick labels drawn
    assert ticks and all(t.count(":") == 2 for t in ticks), ticks  # clock time (hh:mm:ss), not seconds-ago
    y_ticks = page.evaluate("Devices.get('rod-1').charts[0].u.axes[1]._values")
    assert all(len(t.split(".")[-1]) <= 2 and t != "-0" for t in y_ticks), y_ticks  # round: 10, 2.5, no 10.32
    page.get_by_test_id("pause").click()
    frozen = page.evaluate("View.pausedAt")
    assert page.get_by_test_id("pause").inner_text() == "Resume" and frozen > 0
    time.sleep(0.6)
    assert page.evaluate("Devices.get('rod-1').charts[0].u.scales.x.max") == pytest.approx(frozen)
    page.get_by_test_id("pause").click()
    assert page.evaluate(NO_SIDEWAYS_SCROLL)
    browser.shot("dashboard_wide", full_page=False)
    browser.shot("dashboard_wide_full")
    assert not browser.errors(), browser.errors()


def test_plot_reads_values_on_click_and_exports_csv(system: System, browser: Browser) -> None:
    page = browser.page
    over = page.get_by_test_id("chart-rod-1-attitude").locator(".u-over")
    box = over.bounding_box()
    assert box is not None
    over.click(position={"x": box["width"] - 20, "y": box["height"] / 2})  # pins the cursor near "now"
    legend = page.get_by_test_id("chart-rod-1-attitude").locator(".u-legend").inner_text()
    assert "°" in legend and ":" in legend, legend  # a value with its unit and the clock time
    over.click(position={"x": box["width"] - 20, "y": box["height"] / 2})  # unpin
    with page.expect_download() as dl:
        page.get_by_test_id("csv-rod-1").click()
    text = open(dl.value.path(), encoding="utf-8").read().splitlines()
    assert text[0].startswith("time_utc,t_s,pitch_deg,roll_deg,yaw_deg")
    assert len(text) > 50
    assert not browser.errors(), browser.errors()


def test_history_is_there_after_a_reload(system: System, browser: Browser) -> None:
    page = browser.page

    def first_s(device: str) -> float:
        t = get_json(f"{system.base}/api/history/{device}?seconds=3600")["series"]["t_s"]
        return t[0] if t else time.time()

    deadline = time.monotonic() + 30
    while time.time() - min(first_s("rod-1"), first_s("ball-1")) < 8.0:  # >= 8 s of history in the gateway
        assert time.monotonic() < deadline, "the gateway keeps no history"
        time.sleep(0.5)
    rod0, ball0 = first_s("rod-1"), first_s("ball-1")
    page.reload()
    page.get_by_test_id("conn").filter(has_text="live").wait_for(timeout=15_000)
    # the page starts where the gateway's history starts, not at the reload
    wait_js(page, f"Devices.get('rod-1') && Devices.get('rod-1').att.t[0] <= {rod0 + 1.0}", timeout=5_000)
    wait_js(page, f"Devices.get('ball-1') && Devices.get('ball-1').env.t[0] <= {ball0 + 1.5}", timeout=5_000)
    assert not browser.errors(), browser.errors()


def test_threshold_form_shows_validation_message_then_saves(system: System, browser: Browser) -> None:
    page = browser.page
    page.locator("#thresholds-section > summary").click()  # folded by default
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
    # the browser logs the deliberate 422 as a failed resource; nothing else may be there
    assert [e for e in browser.errors() if "status of 422" not in e] == [], browser.errors()
    browser.console.clear()


def _save_hook_form(page: Any, name: str, shown: str) -> None:
    """Save the hook thresholds form and wait until the page has drawn it again from the API with `name` showing
    `shown` (a save re-draws the form; a field filled before that would be overwritten by it)."""
    field = f"document.querySelector('[data-testid=th-hook-{name}]')"
    page.evaluate(f"{field}.dataset.stale = '1'")
    page.get_by_test_id("th-hook").get_by_role("button").click()
    wait_js(page, f"{field} && !{field}.dataset.stale && {field}.value === '{shown}'", timeout=5_000)


def test_hook_form_sets_the_imu_offset_as_three_numbers(system: System, browser: Browser) -> None:
    """The hook's `imu_offset_m` (a list of three metres) is a text field "x, y, z": saved as a list, shown back the
    same way; a value out of a metre gets the API's 422 message; emptied, it is cleared (null)."""
    page = browser.page
    if not page.url.startswith(system.base):  # run alone: load the dashboard with the operator token
        page.goto(system.base + "/")
        page.evaluate("(t) => sessionStorage.setItem('rig_token', t)", system.token)
    summary = page.locator("#thresholds-section")
    if summary.get_attribute("open") is None:
        page.locator("#thresholds-section > summary").click()
    field = page.get_by_test_id("th-hook-imu_offset_m")
    field.fill("0.3, 0, 2")
    page.get_by_test_id("th-hook").get_by_role("button").click()
    errors = page.get_by_test_id("th-hook-errors")
    errors.locator("li").first.wait_for(timeout=5_000)
    assert "imu_offset_m" in errors.inner_text(), errors.inner_text()
    field.fill("0.3, -0.02, 0.05")
    _save_hook_form(page, "imu_offset_m", "0.3, -0.02, 0.05")
    assert get_json(system.base + "/api/thresholds/hook")["imu_offset_m"] == [0.3, -0.02, 0.05]
    # the accelerometer's x/y offset on the hook is two numbers the same way (a number field would lose it)
    page.get_by_test_id("th-hook-acc_bias_xy_m_s2").fill("0.03, -0.01")
    _save_hook_form(page, "acc_bias_xy_m_s2", "0.03, -0.01")
    assert get_json(system.base + "/api/thresholds/hook")["acc_bias_xy_m_s2"] == [0.03, -0.01]
    assert get_json(system.base + "/api/thresholds/hook")["imu_offset_m"] == [0.3, -0.02, 0.05], "kept"
    field.fill("")
    page.get_by_test_id("th-hook-acc_bias_xy_m_s2").fill("")
    page.get_by_test_id("th-hook").get_by_role("button").click()
    # the first save's "saved" is still on the form: wait for the API to hold the cleared value, not for the note
    deadline = time.monotonic() + 5.0
    while get_json(system.base + "/api/thresholds/hook")["imu_offset_m"] is not None and time.monotonic() < deadline:
        time.sleep(0.1)
    assert get_json(system.base + "/api/thresholds/hook")["imu_offset_m"] is None
    assert get_json(system.base + "/api/thresholds/hook")["acc_bias_xy_m_s2"] is None
    assert [e for e in browser.errors() if "status of 422" not in e] == [], browser.errors()
    browser.console.clear()


def test_scripted_bite_raises_loud_alarm_and_ack_clears_banner(system: System, browser: Browser) -> None:
    page = browser.page
    if not page.url.startswith(system.base):  # run alone (`-k`): no earlier test of this module loaded the dashboard
        page.goto(system.base + "/")  # nor gave it the operator token the acknowledgement needs (asked once, kept)
        page.evaluate("(t) => sessionStorage.setItem('rig_token', t)", system.token)
    page.locator("#alarm-rows").wait_for(state="attached", timeout=15_000)
    # record when each alarm row first appears (page clock), to compare with the alarm's own start time
    page.evaluate("""() => { window.__seen = {}; new MutationObserver(() => {
        for (const r of document.querySelectorAll('#alarm-rows tr[data-type]'))
          window.__seen[r.dataset.testid] ??= Date.now() / 1000; }).observe(
        document.querySelector('#alarm-rows'), { childList: true, subtree: true }); }""")
    remaining_s = BITE_AT_S - (time.monotonic() - system.started_s)
    banner = page.get_by_test_id("bite-banner")
    banner.wait_for(state="visible", timeout=int((max(remaining_s, 0) + 60) * 1000))
    assert "BITE on rod-1" in banner.inner_text()
    row = page.locator('[data-testid="alarms"] tr[data-type="bite"]').first
    row.wait_for(timeout=5_000)
    text = row.inner_text()
    assert "major" in text and "rod-1" in text and "°" in text
    assert "sev-major" in (row.get_attribute("class") or "")
    bite = get_json(system.base + "/api/alarms?type=bite")["items"][0]
    seen = page.evaluate(f"window.__seen['alarm-{bite['id']}']")
    assert seen is not None, "the bite row was there before the observer: BITE_AT_S too early for the tests before"
    assert seen - bite["started_at"] < 1.0, f"alarm shown {seen - bite['started_at']:.2f} s after it started"
    banner_h = page.evaluate("document.querySelector('#bite').getBoundingClientRect().height")
    assert banner_h < 0.15 * 800, f"the banner covers {banner_h} px"
    wait_js(page, "Devices.get('rod-1').charts[0] && Alarms.recent.some((a) => a.type === 'bite')")
    browser.shot("dashboard_bite", full_page=False)
    page.get_by_test_id("bite-ack").click()
    banner.wait_for(state="hidden", timeout=5_000)
    row.get_by_test_id("acked").wait_for(timeout=5_000)
    bites = get_json(system.base + "/api/alarms?type=bite")["items"]
    assert bites and bites[0]["acknowledged"] and bites[0]["acknowledged_by"] == "api"
    page.get_by_test_id("alarms-history-tab").click()
    page.locator('[data-testid="alarms"] tr[data-type="bite"]').first.wait_for(timeout=5_000)
    page.get_by_test_id("alarm-filter-type").select_option("bite")
    wait_js(page,
        "(() => { const r = [...document.querySelectorAll('#alarm-rows tr[data-type]')];"
        " return r.length > 0 && r.every((x) => x.dataset.type === 'bite'); })()"
    )
    browser.shot("dashboard_alarm_history")  # history filtered to bites
    page.get_by_test_id("alarm-filter-severity").select_option("critical")
    wait_js(page, "!document.querySelector('#alarm-rows tr[data-type=\"bite\"]')")  # bites are major
    page.get_by_test_id("alarm-filter-severity").select_option("")
    page.get_by_test_id("alarm-filter-type").select_option("")
    page.get_by_test_id("alarms-active-tab").click()
    assert not browser.errors(), browser.errors()


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


def test_phone_layout_has_no_sideways_scroll(system: System, phone: Browser) -> None:
    page = phone.page
    page.goto(system.base + "/")
    page.get_by_test_id("conn").filter(has_text="live").wait_for(timeout=15_000)
    page.get_by_test_id("fleet-rod-1").wait_for(timeout=15_000)
    wait_js(page, "Devices.get('rod-1') && Devices.get('rod-1').charts.length > 0", timeout=15_000)
    time.sleep(1.0)
    assert page.evaluate(NO_SIDEWAYS_SCROLL), page.evaluate("document.documentElement.scrollWidth")
    token = page.get_by_test_id("token-btn").bounding_box()
    assert token is not None and token["x"] + token["width"] <= 390  # the token button is on screen
    for tid in ("fleet-section", "alarms-section", "chart-rod-1-attitude"):
        b = page.get_by_test_id(tid).bounding_box()
        assert b is not None and b["x"] >= 0 and b["x"] + b["width"] <= 390, (tid, b)
    # the bite banner, when shown, is a strip, not 40 % of the screen
    page.evaluate("document.querySelector('#bite').classList.remove('hidden')")
    assert page.evaluate("document.querySelector('#bite').getBoundingClientRect().height") < 0.1 * 844
    page.evaluate("document.querySelector('#bite').classList.add('hidden')")
    assert page.evaluate("matchMedia('(prefers-color-scheme: dark)').matches")
    assert page.evaluate("getComputedStyle(document.body).backgroundColor") != "rgb(244, 246, 248)"  # dark theme
    page.get_by_test_id("fleet-filter").fill("ball")
    time.sleep(0.6)  # past two 4 Hz status refreshes: the filter must survive them
    assert page.get_by_test_id("fleet-rod-1").is_hidden() and page.get_by_test_id("panel-rod-1").is_hidden()
    assert page.get_by_test_id("fleet-ball-1").is_visible()
    page.get_by_test_id("fleet-filter").fill("")
    phone.shot("dashboard_phone", full_page=False)
    phone.shot("dashboard_phone_full")
    assert not phone.errors(), phone.errors()


def test_page_says_warming_up_until_the_gateway_is_ready(system: System, browser: Browser) -> None:
    """The gateway serves the page while its kernels load (`ready: false`); the page says so, then goes live."""
    page = browser.page.context.new_page()
    ready = {"now": False}

    def health(route: Any) -> None:
        if ready["now"]:
            route.continue_()
        else:
            route.fulfill(json={"status": "ok", "ready": False, "uptime_s": 0.5, "devices_online": 0})

    page.route("**/api/health", health)
    page.goto(system.base + "/")
    page.get_by_test_id("conn").filter(has_text="warming up").wait_for(timeout=5_000)
    assert "warming up" in page.get_by_test_id("notice").inner_text()
    time.sleep(1.5)
    assert page.get_by_test_id("conn").inner_text() == "warming up"  # no live stream before ready
    ready["now"] = True
    page.get_by_test_id("conn").filter(has_text="live").wait_for(timeout=10_000)
    assert page.get_by_test_id("notice").is_hidden()
    page.close()


@pytest.mark.parametrize(("path", "ready"), [("/docs", ".swagger-ui .info .title"), ("/redoc", "h1")])
def test_api_docs_render_offline(system: System, browser: Browser, path: str, ready: str) -> None:
    page = browser.page.context.new_page()
    errors: list[str] = []
    requests: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("request", lambda r: requests.append(r.url))
    page.goto(system.base + path)
    title = page.locator(ready).first
    title.wait_for(timeout=20_000)
    assert "rig-gateway" in title.inner_text()
    if path == "/docs":
        page.get_by_role("button", name="Authorize").first.wait_for(timeout=5_000)
    else:
        page.get_by_text("curl", exact=False).first.wait_for(timeout=10_000)  # the x-codeSamples
    page.wait_for_timeout(500)
    page.screenshot(path=str(OUT / f"docs{path.replace('/', '_')}.png"))
    page.close()
    assert not errors, errors
    outside = [u for u in requests if urlparse(u).hostname not in LOCAL_HOSTS and not u.startswith(("data:", "blob:"))]
    assert not outside, outside


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


def test_stale_state_when_devices_then_gateway_stop(system: System, browser: Browser) -> None:
    """Last: stops the devices (offline alarm, greyed row), then the gateway (everything marked frozen)."""
    page = browser.page
    page.bring_to_front()
    devices = system.procs[1]
    devices.send_signal(2)
    devices.wait(timeout=20)
    row = page.get_by_test_id("fleet-rod-1")
    wait_js(page,
        "document.querySelector('[data-testid=\"fleet-rod-1\"] [data-status]').dataset.status !== 'online'",
        timeout=15_000)  # fmt: skip
    assert "stale" in (row.get_attribute("class") or "") or "offline" in (row.get_attribute("class") or "")
    page.locator('[data-testid="alarms"] tr[data-type="device_offline"]').first.wait_for(timeout=15_000)
    browser.shot("dashboard_devices_offline", full_page=False)
    gateway = system.procs[0]
    gateway.send_signal(2)
    gateway.wait(timeout=30)
    page.get_by_test_id("conn").filter(has_text=re.compile("disconnected|unreachable")).wait_for(timeout=10_000)
    assert page.evaluate("document.body.classList.contains('stale')")
    page.get_by_test_id("notice").filter(has_text="frozen").wait_for(timeout=5_000)
    assert row.locator("[data-status]").get_attribute("data-status") == "unknown"
    browser.shot("dashboard_gateway_down", full_page=False)
