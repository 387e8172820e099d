// rig-gateway dashboard: REST (/api/...) for state and writes, /ws/stream for live frames. No external assets.
"use strict";

const $ = (sel, root = document) => root.querySelector(sel);
const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k instanceof Node ? k : document.createTextNode(String(k)));
  return e;
};
const fmt = (x, d = 1) => (x === null || x === undefined || Number.isNaN(x) ? "–" : Number(x).toFixed(d));
const HISTORY_S = 300; // kept per series (the largest zoom)

// ---------------------------------------------------------------------------------------------------------
// API token (asked once for writes; sessionStorage, or localStorage when "remember" is ticked)
// ---------------------------------------------------------------------------------------------------------
const Token = {
  get() { return sessionStorage.getItem("rig_token") || localStorage.getItem("rig_token") || ""; },
  set(t, remember) {
    sessionStorage.setItem("rig_token", t);
    if (remember) localStorage.setItem("rig_token", t); else localStorage.removeItem("rig_token");
  },
  clear() { sessionStorage.removeItem("rig_token"); localStorage.removeItem("rig_token"); },
  ask() {
    return new Promise((resolve) => {
      const dlg = $("#token-dialog");
      $("#token-input").value = "";
      dlg.addEventListener("close", () => {
        const t = $("#token-input").value.trim();
        if (dlg.returnValue === "ok" && t) { Token.set(t, $("#token-remember").checked); resolve(t); } else resolve("");
      }, { once: true });
      dlg.showModal();
    });
  },
};

async function api(method, path, body) {
  const opts = { method, headers: {} };
  if (body !== undefined) { opts.headers["Content-Type"] = "application/json"; opts.body = JSON.stringify(body); }
  if (method !== "GET") {
    let t = Token.get();
    if (!t) t = await Token.ask();
    if (!t) return { ok: false, status: 0, data: { detail: "no API token given" } };
    opts.headers.Authorization = "Bearer " + t;
  }
  const r = await fetch(path, opts);
  let data = null;
  try { data = await r.json(); } catch (_) { /* empty body */ }
  if (r.status === 401 || r.status === 403) {
    Token.clear();
    toast(`token rejected (${r.status}); you will be asked again`);
  }
  return { ok: r.ok, status: r.status, data };
}

function toast(msg) { $("#stream-stats").textContent = msg; }
function detailMessages(data) {
  const d = data && data.detail;
  if (Array.isArray(d)) return d.map((x) => (typeof x === "string" ? x : `${(x.loc || []).join(".")}: ${x.msg}`));
  return [d ? String(d) : "request failed"];
}

// ---------------------------------------------------------------------------------------------------------
// Time series store and canvas chart (pause + zoom)
// ---------------------------------------------------------------------------------------------------------
class Series {
  constructor() { this.t = []; this.v = {}; }
  push(t, vals) {
    if (this.t.length && t < this.t[this.t.length - 1]) return; // keep time monotonic
    this.t.push(t);
    for (const [k, x] of Object.entries(vals)) (this.v[k] ||= []).push(x);
    const cut = t - HISTORY_S;
    let i = 0;
    while (i < this.t.length && this.t[i] < cut) i++;
    if (i > 500) { this.t.splice(0, i); for (const k in this.v) this.v[k].splice(0, i); }
  }
  addFrame(s, names) {
    if (!s || !s.t_s) return;
    for (let i = 0; i < s.t_s.length; i++) {
      const vals = {};
      for (const n of names) if (s[n]) vals[n] = s[n][i];
      this.push(s.t_s[i], vals);
    }
  }
}

const View = { windowS: 30, paused: false, pausedAt: 0, zoom: 1, clockSkew: 0 };
const COLORS = ["#e53e3e", "#2b6cb0", "#2f855a", "#b7791f", "#6b46c1"];

class Chart {
  constructor(canvas, lines, unit, limits = () => []) {
    this.c = canvas; this.lines = lines; this.unit = unit; this.limits = limits;
    canvas.addEventListener("wheel", (ev) => {
      ev.preventDefault();
      View.zoom = Math.min(10, Math.max(0.05, View.zoom * (ev.deltaY > 0 ? 1.25 : 0.8)));
    }, { passive: false });
  }
  draw(series) {
    const c = this.c, dpr = window.devicePixelRatio || 1;
    const w = c.clientWidth, h = c.clientHeight;
    if (c.width !== w * dpr) { c.width = w * dpr; c.height = h * dpr; }
    const g = c.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    const span = View.windowS * View.zoom;
    const t1 = View.paused ? View.pausedAt : Date.now() / 1000 - View.clockSkew;
    const t0 = t1 - span;
    const L = 44, R = 6, T = 6, B = 18;
    let lo = Infinity, hi = -Infinity;
    const idx0 = lowerBound(series.t, t0);
    for (const ln of this.lines) {
      const v = series.v[ln.key]; if (!v) continue;
      for (let i = idx0; i < v.length; i++) { if (series.t[i] > t1) break; const x = v[i]; if (x < lo) lo = x; if (x > hi) hi = x; }
    }
    for (const lim of this.limits()) { if (lim.value < lo) lo = lim.value; if (lim.value > hi) hi = lim.value; }
    if (!Number.isFinite(lo)) { lo = -1; hi = 1; }
    if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
    const pad = (hi - lo) * 0.08; lo -= pad; hi += pad;
    const X = (t) => L + ((t - t0) / span) * (w - L - R);
    const Y = (v) => T + (1 - (v - lo) / (hi - lo)) * (h - T - B);
    g.font = "10px sans-serif"; g.fillStyle = "#6b7685"; g.strokeStyle = "#e5e9ee"; g.lineWidth = 1;
    for (let k = 0; k <= 4; k++) {
      const v = lo + ((hi - lo) * k) / 4, y = Y(v);
      g.beginPath(); g.moveTo(L, y); g.lineTo(w - R, y); g.stroke();
      g.fillText(v.toFixed(Math.abs(hi - lo) < 5 ? 2 : 0), 2, y + 3);
    }
    g.fillText(`-${span.toFixed(span < 10 ? 1 : 0)} s`, L, h - 4);
    g.fillText(View.paused ? "paused" : "now", w - R - 30, h - 4);
    g.fillText(this.unit, 2, h - 4);
    for (const lim of this.limits()) {
      g.strokeStyle = lim.color; g.setLineDash([5, 4]);
      g.beginPath(); g.moveTo(L, Y(lim.value)); g.lineTo(w - R, Y(lim.value)); g.stroke();
      g.setLineDash([]); g.fillStyle = lim.color; g.fillText(lim.label, w - R - 60, Y(lim.value) - 2);
    }
    this.lines.forEach((ln, j) => {
      const v = series.v[ln.key]; if (!v) return;
      g.strokeStyle = ln.color || COLORS[j]; g.lineWidth = 1.5; g.beginPath();
      let started = false;
      for (let i = Math.max(0, idx0 - 1); i < v.length; i++) {
        const t = series.t[i]; if (t > t1) break;
        const x = X(t), y = Y(v[i]);
        if (!started) { g.moveTo(x, y); started = true; } else g.lineTo(x, y);
      }
      g.stroke();
    });
  }
}
function lowerBound(a, x) { let lo = 0, hi = a.length; while (lo < hi) { const m = (lo + hi) >> 1; if (a[m] < x) lo = m + 1; else hi = m; } return lo; }

// ---------------------------------------------------------------------------------------------------------
// Devices: cards, plot panels, reel controls
// ---------------------------------------------------------------------------------------------------------
const Devices = new Map(); // id -> {card, panel, charts, att, acc, reel, thresholds}
const PLOTS = {
  rod: [
    { title: "attitude", unit: "deg", src: "att", lines: [{ key: "pitch_deg", label: "pitch" }, { key: "roll_deg", label: "roll" }, { key: "yaw_deg", label: "yaw (unwrapped)" }] },
    { title: "acceleration", unit: "m/s²", src: "acc", lines: [{ key: "norm", label: "|a| peak" }, { key: "ax", label: "ax" }, { key: "az", label: "az" }] },
    { title: "line tension", unit: "N", src: "reel", lines: [{ key: "tension_n", label: "tension" }], limits: "tension" },
  ],
  hook: [
    { title: "swing", unit: "deg", src: "att", lines: [{ key: "swing_deg", label: "swing Θ" }, { key: "torsion_deg", label: "torsion φ" }], limits: "hook" },
    { title: "swing direction", unit: "deg", src: "att", lines: [{ key: "direction_deg", label: "direction" }] },
  ],
  ball: [
    { title: "water", unit: "°C · mg/l", src: "env", lines: [{ key: "water_temp_c", label: "water °C" }, { key: "oxygen_mg_l", label: "O₂ mg/l" }, { key: "air_temp_c", label: "air °C" }] },
  ],
};

function tensionLimits(d) {
  const th = d.thresholds;
  if (!th) return [];
  return [
    { value: th.line_breaking_n, label: "breaking", color: "#e53e3e" },
    { value: th.line_breaking_n * th.tension_warn_fraction, label: "limit", color: "#d69e2e" },
  ];
}
function hookLimits() {
  const th = Thresholds.hook;
  if (!th) return [];
  return [
    { value: th.swing_warn_deg, label: "swing warn", color: "#d69e2e" },
    { value: th.swing_critical_deg, label: "swing crit", color: "#e53e3e" },
  ];
}

function ensureDevice(card) {
  let d = Devices.get(card.device_id);
  if (d) return d;
  d = { id: card.device_id, kind: card.kind, att: new Series(), acc: new Series(), reel: new Series(), env: new Series(), charts: [] };
  Devices.set(d.id, d);
  const cardEl = el("div", { class: "card", "data-testid": `card-${d.id}` });
  $("#cards").querySelector("p.muted")?.remove();
  $("#cards").append(cardEl);
  d.card = cardEl;
  const panel = el("div", { class: "plot-panel", "data-testid": `panel-${d.id}` }, el("h3", {}, `${d.id} `, el("span", { class: "muted small" }, d.kind)));
  for (const spec of PLOTS[d.kind] || []) {
    const canvas = el("canvas", { class: "chart", "data-testid": `chart-${d.id}-${spec.title.replace(/ /g, "-")}` });
    const legend = el("div", { class: "legend" }, el("b", {}, spec.title + ":"),
      ...spec.lines.map((ln, j) => el("span", {}, el("i", { style: `background:${COLORS[j]}` }), ln.label)));
    const limits = spec.limits === "tension" ? () => tensionLimits(d) : spec.limits === "hook" ? hookLimits : () => [];
    panel.append(legend, canvas);
    d.charts.push({ chart: new Chart(canvas, spec.lines, spec.unit, limits), src: spec.src });
  }
  if (d.kind === "rod") panel.append(reelControls(d));
  $("#plots").append(panel);
  d.panel = panel;
  if (d.kind === "rod") loadDeviceThresholds(d);
  return d;
}

async function loadDeviceThresholds(d) {
  const r = await fetch(`/api/devices/${encodeURIComponent(d.id)}/settings`);
  if (r.ok) d.thresholds = (await r.json()).effective.thresholds;
}

function reelControls(d) {
  const speed = el("input", { type: "number", value: "0.5", min: "0.05", max: "5", step: "0.05", "data-testid": `reel-speed-${d.id}`, title: "speed, m/s" });
  const send = async (action) => {
    const body = { action };
    if (action === "in" || action === "out") body.speed_m_s = Number(speed.value);
    const r = await api("POST", `/api/rods/${encodeURIComponent(d.id)}/reel`, body);
    d.reelMsg.textContent = r.ok ? (action === "auto" ? `auto on (controller ${r.data.controller_available ? "ready" : "unavailable"})`
      : `sent ${action} #${r.data.command.cmd_id}`) : detailMessages(r.data).join("; ");
    d.reelMsg.className = r.ok ? "" : "errors";
  };
  const btn = (label, action, tid) => el("button", { onclick: () => send(action), "data-testid": `reel-${tid}-${d.id}` }, label);
  d.tensionBar = el("div", { class: "bar" });
  d.tensionLimit = el("div", { class: "limit" });
  d.tensionText = el("span", {}, "tension –");
  d.reelMsg = el("span", { "data-testid": `reel-msg-${d.id}` });
  d.reelState = el("b", { "data-testid": `reel-state-${d.id}` }, "–");
  return el("div", { class: "reel" }, el("b", {}, "Reel:"), btn("◀ In", "in", "in"), btn("Out ▶", "out", "out"), btn("■ Stop", "stop", "stop"),
    btn("Auto on", "auto", "auto"), btn("Auto off", "stop", "autooff"), speed, "m/s", el("span", {}, "state: "), d.reelState, d.reelMsg,
    el("div", { class: "tension", "data-testid": `tension-${d.id}` }, d.tensionBar, d.tensionLimit, d.tensionText));
}

function updateCard(d, c) {
  const alarming = (c.active_alarms || []).length > 0;
  d.card.className = `card ${c.online ? "online" : ""} ${alarming ? "alarming" : ""}`;
  const rows = [
    ["status", c.online ? "online" : "offline"],
    ["last packet", c.last_packet_age_s == null ? "–" : `${fmt(c.last_packet_age_s, 2)} s ago`],
    ["packet loss", `${fmt(100 * (c.loss_fraction || 0), 2)} %`],
  ];
  const link = d.link || {};
  if (link.battery_v != null) rows.push(["battery", `${fmt(link.battery_v, 2)} V`]);
  if (link.rssi_dbm != null) rows.push(["link", `${fmt(link.rssi_dbm, 0)} dBm`]);
  if (c.attitude) rows.push(["pitch / roll", `${fmt(c.attitude.pitch_rad * 57.2958)}° / ${fmt(c.attitude.roll_rad * 57.2958)}°`],
    ["yaw (unwrapped)", `${fmt(c.attitude.yaw_unwrapped_rad * 57.2958)}°`]);
  if (c.swing) rows.push(["swing Θ", `${fmt(c.swing.swing_angle_rad * 57.2958)}°`], ["torsion φ", `${fmt(c.swing.torsion_rad * 57.2958)}°`]);
  if (c.height) rows.push(["height / Vz", `${fmt(c.height.height_m, 2)} m / ${fmt(c.height.vz_m_s, 2)} m/s${c.height.at_rest ? " (rest)" : ""}`]);
  if (c.readings) rows.push(["spot", c.readings.spot], ["water", `${fmt(c.readings.water_temp_c)} °C, O₂ ${fmt(c.readings.oxygen_mg_l, 2)} mg/l`]);
  if (c.reel) rows.push(["reel", `${c.reel.mode} / ${c.reel.motor}`], ["line out", `${fmt(c.reel.line_out_m)} m`]);
  if (c.kind === "rod") rows.push(["auto reel", c.auto_reel ? "on" : "off"]);
  if (alarming) rows.push(["alarms", c.active_alarms.join(", ")]);
  d.card.replaceChildren(el("div", { class: "title" }, el("span", {}, c.device_id), el("span", { class: "muted" }, c.kind)),
    el("dl", {}, ...rows.flatMap(([k, v]) => [el("dt", {}, k), el("dd", { "data-field": k }, v)])));
}

function onTick(f) {
  const now = f.wall_s;
  View.clockSkew = Date.now() / 1000 - now;
  for (const c of f.devices) {
    const d = ensureDevice(c);
    d.att.addFrame(c.series, ["pitch_deg", "roll_deg", "yaw_deg", "swing_deg", "direction_deg", "torsion_deg"]);
    if (c.acc) d.acc.addFrame(c.acc, ["norm", "ax", "ay", "az"]);
    if (c.link) d.link = c.link;
    if (c.online === undefined) continue; // a samples-only tick; cards come with full ticks (2 Hz)
    if (c.reel) {
      if (c.reel.tension_n != null) d.reel.push(now, { tension_n: c.reel.tension_n });
      d.reelState.textContent = `${c.reel.mode} / ${c.reel.motor}${c.auto_reel ? " (auto)" : ""}`;
      const lim = tensionLimits(d);
      const full = lim.length ? lim[0].value : 100;
      const t = c.reel.tension_n || 0;
      d.tensionBar.style.width = `${Math.min(100, (100 * t) / full)}%`;
      d.tensionBar.className = "bar" + (lim.length && t >= lim[1].value ? " crit" : lim.length && t >= 0.6 * lim[1].value ? " warn" : "");
      if (lim.length) d.tensionLimit.style.left = `${(100 * lim[1].value) / full}%`;
      d.tensionText.textContent = `tension ${fmt(t, 1)} N / limit ${lim.length ? fmt(lim[1].value, 0) : "?"} N (breaking ${fmt(full, 0)} N)`;
    }
    if (c.readings) d.env.push(now, { water_temp_c: c.readings.water_temp_c, oxygen_mg_l: c.readings.oxygen_mg_l, air_temp_c: c.readings.air_temp_c });
    updateCard(d, c);
  }
  if (f.spots) renderSpots(f.spots);
  if (f.alarm_seq !== Alarms.seq) { Alarms.seq = f.alarm_seq; Alarms.refresh(); }
  $("#stream-stats").textContent = `${f.devices.length} devices, tick ${new Date(now * 1000).toLocaleTimeString()}` +
    (f.client_dropped ? `, ${f.client_dropped} frames dropped (slow client)` : "");
}

function drawAll() {
  for (const d of Devices.values()) for (const { chart, src } of d.charts) chart.draw(d[src]);
  requestAnimationFrame(drawAll);
}

// ---------------------------------------------------------------------------------------------------------
// Spots
// ---------------------------------------------------------------------------------------------------------
function renderSpots(spots) {
  const body = $("#spot-rows");
  if (!spots.length) return;
  body.replaceChildren(...spots.map((s) => {
    const dev = [...Devices.values()].find((d) => d.id === s.device_id);
    const r = dev && dev.card ? dev.card.querySelector('[data-field="water"]') : null;
    return el("tr", { "data-testid": `spot-${s.spot}` }, el("td", {}, s.rank), el("td", {}, s.spot),
      el("td", {}, el("span", { class: "scorebar", style: `width:${Math.round(60 * s.score)}px` }), fmt(s.score, 2)),
      el("td", {}, r ? r.textContent : "–"), el("td", {}, el("ul", {}, ...(s.reasons || []).map((x) => el("li", {}, x)))));
  }));
}

// ---------------------------------------------------------------------------------------------------------
// Alarms: active / history, acknowledge, bite banner
// ---------------------------------------------------------------------------------------------------------
const Alarms = {
  seq: -1, view: "active", items: [],
  async refresh() {
    const q = this.view === "active" ? "?status=active&limit=200" : "?limit=200";
    const r = await fetch("/api/alarms" + q);
    if (!r.ok) return;
    this.items = (await r.json()).items;
    this.render();
    // the banner stays until a bite is acknowledged, even when the alarm already cleared (last 10 minutes)
    const bites = await fetch("/api/alarms?type=bite&acknowledged=false&limit=50").then((x) => x.json());
    this.banner(bites.items.filter((a) => a.started_at > Date.now() / 1000 - View.clockSkew - 600));
  },
  render() {
    const rows = this.items.map((a) => el("tr", { class: `sev-${a.severity} ${a.status}`, "data-testid": `alarm-${a.id}`, "data-type": a.type },
      el("td", {}, new Date(a.started_at * 1000).toLocaleTimeString()), el("td", {}, a.device_id), el("td", {}, a.type),
      el("td", {}, el("span", { class: `sev ${a.severity}` }, a.severity)),
      el("td", {}, a.status + (a.acknowledged ? " · acked" : "")), el("td", {}, fmt(a.value, 1)), el("td", {}, a.message),
      el("td", {}, a.acknowledged ? el("span", { class: "muted", "data-testid": "acked" }, `by ${a.acknowledged_by}`)
        : el("button", { onclick: () => this.ack(a.id), "data-testid": "ack" }, "Ack"))));
    $("#alarm-rows").replaceChildren(...(rows.length ? rows : [el("tr", {}, el("td", { colspan: 8, class: "muted" }, "no alarms"))]));
  },
  banner(active) {
    const bites = active.filter((a) => a.type === "bite" && !a.acknowledged);
    const b = $("#bite");
    b.classList.toggle("hidden", bites.length === 0);
    if (bites.length) {
      $("#bite-text").textContent = `BITE on ${[...new Set(bites.map((a) => a.device_id))].join(", ")}!`;
      b.dataset.alarmIds = bites.map((a) => a.id).join(",");
      document.title = "BITE! rig-gateway";
    } else document.title = "rig-gateway dashboard";
  },
  async ack(id) {
    const r = await api("POST", `/api/alarms/${encodeURIComponent(id)}/ack`);
    if (!r.ok) toast("ack failed: " + detailMessages(r.data).join("; "));
    await this.refresh();
  },
};

// ---------------------------------------------------------------------------------------------------------
// Threshold forms (validation messages from the API's 422)
// ---------------------------------------------------------------------------------------------------------
const Thresholds = {};
const LABELS = {
  bite_deviation_deg: "θ1 bite deviation (°)", line_switch_deg: "θ2 reel switch (°)", line_limit_deg: "θ3 line limit (°)",
  sensitivity: "sensitivity (1–5)", swing_warn_deg: "swing warn (°)", swing_critical_deg: "swing critical (°)",
  torsion_warn_deg: "torsion warn (°)", torsion_critical_deg: "torsion critical (°)", hysteresis_deg: "hysteresis (°)",
  drop_back_rise_deg: "drop-back rise (°)", line_breaking_n: "line breaking strength (N)",
  line_critical_fraction: "θ3 critical at (fraction)", tension_warn_fraction: "tension warn (fraction of breaking)",
  rearm_quiet_s: "re-arm after quiet (s)", baseline_tau_s: "rest baseline time constant (s)",
  rope_length_m: "rope length (m)", rest_heading_deg: "rest heading (°, empty = first fused)",
};
async function loadThresholds(kind) {
  const r = await fetch(`/api/thresholds/${kind}`);
  if (!r.ok) return;
  const th = await r.json();
  Thresholds[kind] = th;
  const form = $(`#th-${kind}`);
  form.querySelector(".fields").replaceChildren(...Object.entries(th).flatMap(([k, v]) => [
    el("label", { for: `f-${kind}-${k}` }, LABELS[k] || k.replace(/_/g, " "), el("small", {}, k)),
    el("input", { id: `f-${kind}-${k}`, name: k, type: "number", step: "any", value: v == null ? "" : String(v), "data-testid": `th-${kind}-${k}` }),
  ]));
}
async function saveThresholds(ev) {
  ev.preventDefault();
  const form = ev.target, kind = form.dataset.kind, body = {};
  for (const inp of form.querySelectorAll("input")) body[inp.name] = inp.value === "" ? null : Number(inp.value);
  const r = await api("PUT", `/api/thresholds/${kind}`, body);
  const errs = form.querySelector("ul.errors"), ok = form.querySelector("p.ok");
  if (r.ok) {
    errs.replaceChildren(); ok.textContent = `saved ${new Date().toLocaleTimeString()}`;
    await loadThresholds(kind);
    for (const d of Devices.values()) if (d.kind === "rod") loadDeviceThresholds(d);
  } else {
    ok.textContent = "";
    errs.replaceChildren(...detailMessages(r.data).map((m) => el("li", {}, m)));
  }
}

// ---------------------------------------------------------------------------------------------------------
// Live stream
// ---------------------------------------------------------------------------------------------------------
function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/stream`);
  const conn = $("#conn");
  ws.onopen = () => { conn.textContent = "live"; conn.className = "pill on"; };
  ws.onclose = () => { conn.textContent = "disconnected – retrying"; conn.className = "pill off"; setTimeout(connect, 1000); };
  ws.onmessage = (m) => {
    const f = JSON.parse(m.data);
    if (f.type === "tick") onTick(f);
    else if (f.type === "alarm") { Alarms.seq = f.alarm_seq; Alarms.refresh(); }
    else if (f.type === "hello") Alarms.refresh();
  };
}

function init() {
  $("#window").addEventListener("change", (e) => { View.windowS = Number(e.target.value); View.zoom = 1; });
  $("#pause").addEventListener("click", (e) => {
    View.paused = !View.paused;
    View.pausedAt = Date.now() / 1000 - View.clockSkew;
    e.target.textContent = View.paused ? "Resume" : "Pause";
  });
  $("#token-btn").addEventListener("click", () => Token.ask());
  $("#bite-ack").addEventListener("click", async () => {
    for (const id of ($("#bite").dataset.alarmIds || "").split(",").filter(Boolean)) await Alarms.ack(id);
  });
  for (const tab of document.querySelectorAll(".tab")) tab.addEventListener("click", () => {
    for (const t of document.querySelectorAll(".tab")) t.classList.toggle("active", t === tab);
    Alarms.view = tab.dataset.view; Alarms.refresh();
  });
  for (const f of document.querySelectorAll("form.th")) f.addEventListener("submit", saveThresholds);
  loadThresholds("rod"); loadThresholds("hook");
  connect();
  requestAnimationFrame(drawAll);
}
init();
