// rig-gateway dashboard: REST (/api/...) for state, history and writes, /ws/stream for live frames. Plots use the
// vendored uPlot (web/vendor, MIT); nothing is fetched from outside this gateway.
"use strict";

const $ = (sel, root = document) => root.querySelector(sel);
const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null) continue;
    if (k === "class") e.className = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const k of kids) if (k !== null && k !== undefined) e.append(k instanceof Node ? k : document.createTextNode(String(k)));
  return e;
};
const fmt = (x, d = 1) => (x === null || x === undefined || Number.isNaN(x) ? "–" : Number(x).toFixed(d));
const DEG = 180 / Math.PI;
const KEEP_S = 3600; // client keeps at most the largest range
const MAX_POINTS = 60000; // per series store; older half thinned when exceeded
const STALE_S = 5; // a device without a packet for this long is shown stale

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
  let r;
  try { r = await fetch(path, opts); } catch (e) { return { ok: false, status: 0, data: { detail: "gateway unreachable" } }; }
  let data = null;
  try { data = await r.json(); } catch (_) { /* empty body */ }
  if (r.status === 401 || r.status === 403) {
    Token.clear();
    toast(`token rejected (${r.status}); you will be asked again`);
  }
  return { ok: r.ok, status: r.status, data };
}
async function getJSON(path) {
  try { const r = await fetch(path); return r.ok ? await r.json() : null; } catch (_) { return null; }
}

function toast(msg) { $("#stream-stats").textContent = msg; }
function detailMessages(data) {
  const d = data && data.detail;
  if (Array.isArray(d)) return d.map((x) => (typeof x === "string" ? x : `${(x.loc || []).join(".")}: ${x.msg}`));
  return [d ? String(d) : "request failed"];
}
const pad2 = (n) => String(n).padStart(2, "0");
/** Local clock time, 24 h: "14:05" or with seconds "14:05:30". */
function clock(t_s, seconds = true) {
  const d = new Date(t_s * 1000);
  return `${pad2(d.getHours())}:${pad2(d.getMinutes())}` + (seconds ? `:${pad2(d.getSeconds())}` : "");
}
const nowS = () => Date.now() / 1000 - View.clockSkew;

// ---------------------------------------------------------------------------------------------------------
// Time series store: wall time in s, one array per field; history from the gateway is prepended
// ---------------------------------------------------------------------------------------------------------
class Series {
  constructor() { this.t = []; this.v = {}; }
  push(t, vals) {
    if (this.t.length && t <= this.t[this.t.length - 1]) return; // keep time monotonic
    const n = this.t.length;
    this.t.push(t);
    for (const k of Object.keys(vals)) { if (!this.v[k]) this.v[k] = new Array(n).fill(null); }
    for (const k of Object.keys(this.v)) this.v[k].push(k in vals ? vals[k] : null);
    if (this.t.length > MAX_POINTS) this.thin();
    const cut = t - KEEP_S;
    if (this.t[0] < cut) {
      let i = 0; while (i < this.t.length && this.t[i] < cut) i++;
      this.t.splice(0, i); for (const k in this.v) this.v[k].splice(0, i);
    }
  }
  thin() { // drop every other point of the older half: recent data stays at full rate
    const h = this.t.length >> 1;
    const keep = (a) => a.filter((_, i) => i >= h || i % 2 === 0);
    this.t = keep(this.t); for (const k in this.v) this.v[k] = keep(this.v[k]);
  }
  addFrame(s, names) {
    if (!s || !s.t_s) return;
    for (let i = 0; i < s.t_s.length; i++) {
      const vals = {};
      for (const n of names) if (s[n]) vals[n] = s[n][i];
      this.push(s.t_s[i], vals);
    }
  }
  prepend(cols, names) { // history rows older than what the live stream already gave
    const t0 = this.t.length ? this.t[0] : Infinity;
    const idx = [];
    for (let i = 0; i < cols.t_s.length; i++) {
      if (cols.t_s[i] >= t0) break;
      if (names.some((n) => cols[n] && cols[n][i] !== null && cols[n][i] !== undefined)) idx.push(i);
    }
    if (!idx.length) return;
    const n = this.t.length;
    for (const k of names) if (cols[k] && !this.v[k]) this.v[k] = new Array(n).fill(null);
    this.t = idx.map((i) => cols.t_s[i]).concat(this.t);
    for (const k of Object.keys(this.v)) this.v[k] = idx.map((i) => (cols[k] ? cols[k][i] : null)).concat(this.v[k]);
  }
}

// ---------------------------------------------------------------------------------------------------------
// Plots (uPlot): clock-time x axis, one unit per plot, limits and alarm markers, wrap-aware angles
// ---------------------------------------------------------------------------------------------------------
const View = { rangeS: 300, paused: false, pausedAt: 0, clockSkew: 0 };
const COLORS = ["#e53e3e", "#2b6cb0", "#2f855a", "#b7791f", "#8e44ad"];
const SEV_COLOR = () => {
  const cs = getComputedStyle(document.documentElement);
  return Object.fromEntries(["critical", "major", "minor", "warning", "indeterminate"].map((s) => [s, cs.getPropertyValue(`--${s}`).trim()]));
};
const SEV_GLYPH = { critical: "‼", major: "!", minor: "▲", warning: "△", indeterminate: "?" };
const PLOTS = {
  rod: [
    { id: "attitude", title: "attitude", unit: "°", src: "att", lines: [{ key: "pitch_deg", label: "pitch" }, { key: "roll_deg", label: "roll" }, { key: "yaw_deg", label: "yaw (unwrapped)" }] },
    { id: "acceleration", title: "acceleration", unit: "m/s²", src: "acc", lines: [{ key: "norm", label: "|a| peak" }, { key: "ax", label: "ax" }, { key: "az", label: "az" }] },
    { id: "tension", title: "line tension", unit: "N", src: "reel", lines: [{ key: "tension_n", label: "tension" }], limits: "tension" },
  ],
  hook: [
    { id: "swing", title: "swing Θ and torsion φ", unit: "°", src: "att", lines: [{ key: "swing_deg", label: "swing Θ" }, { key: "torsion_deg", label: "torsion φ", wrap: true }], limits: "hook" },
    { id: "direction", title: "swing direction", unit: "°", src: "att", lines: [{ key: "direction_deg", label: "direction", wrap: true }] },
  ],
  ball: [
    { id: "temperature", title: "temperature", unit: "°C", src: "env", lines: [{ key: "water_temp_c", label: "water" }, { key: "air_temp_c", label: "air" }] },
    { id: "oxygen", title: "dissolved oxygen", unit: "mg/l", src: "env", lines: [{ key: "oxygen_mg_l", label: "O₂" }] },
  ],
};
const SRC_FIELDS = {
  att: ["pitch_deg", "roll_deg", "yaw_deg", "swing_deg", "direction_deg", "torsion_deg"],
  reel: ["tension_n"], env: ["water_temp_c", "air_temp_c", "oxygen_mg_l"], acc: ["norm", "ax", "ay", "az"],
};

function tensionLimits(d) {
  const th = d.thresholds;
  if (!th || !th.line_breaking_n) return [];
  return [{ value: th.line_breaking_n, label: "breaking", sev: "critical" },
    { value: th.line_breaking_n * th.tension_warn_fraction, label: "limit", sev: "minor" }];
}
function hookLimits(d) {
  const th = d.thresholds || Thresholds.hook;
  if (!th) return [];
  return [{ value: th.swing_warn_deg, label: "swing warn", sev: "minor" }, { value: th.swing_critical_deg, label: "swing crit", sev: "critical" },
    { value: th.torsion_warn_deg, label: "torsion warn", sev: "minor" }, { value: th.torsion_critical_deg, label: "torsion crit", sev: "critical" },
    { value: -th.torsion_warn_deg, label: "", sev: "minor" }, { value: -th.torsion_critical_deg, label: "", sev: "critical" }];
}

/** Values with a jump of more than 180° replaced by null, so a wrap from +179° to −179° is a gap, not a line. */
function wrapGaps(v) {
  const out = v.slice();
  let prev = null;
  for (let i = 0; i < out.length; i++) {
    const x = out[i];
    if (x === null || x === undefined) continue;
    if (prev !== null && Math.abs(x - prev) > 180) out[i] = null;
    prev = x;
  }
  return out;
}

class Chart {
  constructor(host, d, spec) {
    this.d = d; this.spec = spec;
    this.limits = spec.limits === "tension" ? () => tensionLimits(d) : spec.limits === "hook" ? () => hookLimits(d) : () => [];
    const cs = getComputedStyle(document.documentElement);
    const ink = cs.getPropertyValue("--muted").trim() || "#666", grid = cs.getPropertyValue("--grid").trim() || "#eee";
    const unit = spec.unit;
    const self = this;
    this.wrap = el("div", { class: "chart", "data-testid": `chart-${d.id}-${spec.id}` },
      el("div", { class: "title" }, `${spec.title} (${unit})`));
    host.append(this.wrap);
    const opts = {
      width: Math.max(200, host.clientWidth || 480), height: 150,
      cursor: { lock: true, drag: { x: true, y: false } },
      legend: { live: true },
      scales: { x: { time: true } },
      axes: [
        { stroke: ink, grid: { stroke: grid, width: 1 }, ticks: { stroke: grid }, space: 64, // local clock, round ticks
          values: (u, vals, ax, space, incr) => vals.map((v) => clock(v, incr < 60)) },
        { stroke: ink, grid: { stroke: grid, width: 1 }, ticks: { stroke: grid }, size: 48,
          values: (u, vals) => vals.map((v) => (Math.abs(v) < 1e-9 ? "0" : String(+v.toPrecision(6)))) },
      ],
      series: [{ label: "time", value: (u, v) => (v == null ? "–" : clock(v)) },
        ...spec.lines.map((ln, j) => ({ label: ln.label, stroke: COLORS[j], width: 1.5, spanGaps: !ln.wrap,
          value: (u, v) => (v == null ? "–" : `${v.toFixed(Math.abs(v) < 10 ? 2 : 1)} ${unit}`) }))],
      hooks: { draw: [(u) => self.drawOverlays(u)], setSelect: [() => { View.zoomed = true; }] },
    };
    this.u = new uPlot(opts, [[], ...spec.lines.map(() => [])], this.wrap);
    this.u.over.addEventListener("dblclick", () => { View.zoomed = false; });
  }
  resize(width) { if (width > 0 && Math.abs(width - this.u.width) > 2) this.u.setSize({ width, height: 150 }); }
  data() {
    const s = this.d[this.spec.src];
    return [s.t, ...this.spec.lines.map((ln) => { const v = s.v[ln.key] || new Array(s.t.length).fill(null); return ln.wrap ? wrapGaps(v) : v; })];
  }
  update() {
    const t1 = View.paused ? View.pausedAt : nowS();
    this.u.batch(() => {
      this.u.setData(this.data(), false);
      // the range is an upper bound: a young series fills the plot instead of hugging its right edge
      const first = this.u.data[0].length ? this.u.data[0][0] : t1;
      if (!View.zoomed) this.u.setScale("x", { min: Math.max(t1 - View.rangeS, Math.min(first, t1 - 10) - 1), max: t1 });
      // y: fit data in range and the limits, never a zero-height axis
      const [t, ...ys] = this.u.data;
      let lo = Infinity, hi = -Infinity;
      const i0 = lowerBound(t, this.u.scales.x.min ?? t1 - View.rangeS);
      for (const y of ys) for (let i = i0; i < y.length; i++) { const v = y[i]; if (v == null) continue; if (v < lo) lo = v; if (v > hi) hi = v; }
      for (const l of this.limits()) if (Number.isFinite(l.value) && (l.label || lo <= l.value)) { lo = Math.min(lo, l.value); hi = Math.max(hi, l.value); }
      if (!Number.isFinite(lo)) { lo = -1; hi = 1; }
      if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
      const pad = (hi - lo) * 0.06;
      this.u.setScale("y", { min: lo - pad, max: hi + pad });
    });
  }
  drawOverlays(u) {
    const ctx = u.ctx, { left, top, width, height } = u.bbox, dpr = devicePixelRatio || 1;
    const colors = SEV_COLOR();
    ctx.save();
    ctx.font = `${10 * dpr}px sans-serif`;
    for (const l of this.limits()) { // limits: dashed horizontal lines with their names
      const y = u.valToPos(l.value, "y", true);
      if (y < top || y > top + height) continue;
      ctx.strokeStyle = colors[l.sev]; ctx.setLineDash([5 * dpr, 4 * dpr]); ctx.lineWidth = dpr;
      ctx.beginPath(); ctx.moveTo(left, y); ctx.lineTo(left + width, y); ctx.stroke();
      if (l.label) { ctx.fillStyle = colors[l.sev]; ctx.fillText(l.label, left + width - 70 * dpr, y - 2 * dpr); }
    }
    ctx.setLineDash([]);
    for (const a of Alarms.recent) { // alarm markers: a vertical line at the start, glyph + type on top
      if (a.device_id !== this.d.id) continue;
      const x = u.valToPos(a.started_at, "x", true);
      if (x < left || x > left + width) continue;
      ctx.strokeStyle = colors[a.severity] || colors.indeterminate; ctx.lineWidth = 2 * dpr;
      ctx.beginPath(); ctx.moveTo(x, top); ctx.lineTo(x, top + height); ctx.stroke();
      ctx.fillStyle = ctx.strokeStyle;
      ctx.fillText(`${SEV_GLYPH[a.severity] || ""} ${a.type}`, x + 3 * dpr, top + 11 * dpr);
    }
    ctx.restore();
  }
  csvRows(t0, t1) { // [header, ...rows] of what the plot shows
    const [t, ...ys] = this.u.data;
    const rows = [];
    for (let i = lowerBound(t, t0); i < t.length && t[i] <= t1; i++) rows.push([t[i], ...ys.map((y) => y[i])]);
    return { header: this.spec.lines.map((ln) => `${ln.key}`), rows };
  }
}
function lowerBound(a, x) { let lo = 0, hi = a.length; while (lo < hi) { const m = (lo + hi) >> 1; if (a[m] < x) lo = m + 1; else hi = m; } return lo; }

// ---------------------------------------------------------------------------------------------------------
// Devices: fleet rows (one per device, scales to 100) and collapsible plot panels (built when opened)
// ---------------------------------------------------------------------------------------------------------
const Devices = new Map();
/** Device ids in natural order: rod-2 before rod-10. */
const byId = (a, b) => a.localeCompare(b, "en", { numeric: true });
const KEY_METRIC = { rod: ["att", "pitch_deg", "pitch", "°"], imu: ["att", "pitch_deg", "pitch", "°"], hook: ["att", "swing_deg", "swing", "°"], ball: ["env", "water_temp_c", "water", "°C"] };

function ensureDevice(c) {
  let d = Devices.get(c.device_id);
  if (d) return d;
  d = { id: c.device_id, kind: c.kind, att: new Series(), acc: new Series(), reel: new Series(), env: new Series(),
    charts: [], card: null, recvAt: 0, spark: [] };
  Devices.set(d.id, d);
  buildRow(d); buildPanel(d);
  if (d.kind === "rod" || d.kind === "hook") loadDeviceThresholds(d);
  applyFilter();
  return d;
}

function buildRow(d) {
  const body = $("#fleet-rows");
  body.querySelector("td.muted")?.parentElement.remove();
  d.cells = { status: el("td", {}, el("span", { class: "dot" }), el("span", {}, "–")), now: el("td", { class: "num" }, "–"),
    alarm: el("td", {}, "–"), age: el("td", { class: "num" }, "–") };
  d.sparkCanvas = el("canvas", { class: "spark", width: 110, height: 24 });
  d.row = el("tr", { "data-testid": `fleet-${d.id}`, onclick: () => { d.panel.open = true; d.panel.scrollIntoView({ block: "start" }); } },
    d.cells.status, el("td", {}, el("b", {}, d.id), " ", el("span", { class: "muted" }, d.kind)), d.cells.now,
    el("td", { class: "spark-col" }, d.sparkCanvas), d.cells.alarm, d.cells.age);
  const rows = [...body.children];
  const after = rows.find((r) => r.dataset.testid && byId(r.dataset.testid.slice(6), d.id) > 0);
  body.insertBefore(d.row, after || null);
  $("#fleet-count").textContent = `(${Devices.size})`;
  $("#device-ids").append(el("option", { value: d.id })); // suggestions for the alarm filter (exact id)
}

function buildPanel(d) {
  const open = Math.max(Devices.size, View.fleetSize || 0) <= 4; // a big fleet starts folded: open what you need
  d.facts = el("div", { class: "facts", "data-testid": `facts-${d.id}` });
  d.body = el("div", {});
  d.panel = el("details", { class: "device-panel", "data-testid": `panel-${d.id}`, "data-id": d.id },
    el("summary", {}, `${d.id} `, el("span", { class: "muted small" }, d.kind)), d.facts, d.body);
  d.panel.addEventListener("toggle", () => { if (d.panel.open) openPanel(d); });
  const panels = [...$("#plots").children];
  $("#plots").insertBefore(d.panel, panels.find((p) => byId(p.dataset.id, d.id) > 0) || null);
  if (open) d.panel.open = true;
}

async function openPanel(d) {
  if (!d.charts.length) {
    const bar = el("div", { class: "bar" }, el("button", { onclick: () => exportCsv(d), "data-testid": `csv-${d.id}` }, "CSV of what is shown"));
    d.body.append(bar);
    for (const spec of PLOTS[d.kind] || []) d.charts.push(new Chart(d.body, d, spec));
    if (d.kind === "rod") d.body.append(reelControls(d));
    new ResizeObserver(() => { for (const ch of d.charts) ch.resize(d.body.clientWidth); }).observe(d.body);
  }
  await loadHistory(d);
}

async function loadHistory(d) {
  const h = await getJSON(`/api/history/${encodeURIComponent(d.id)}?seconds=${KEEP_S}&max_points=8000`);
  if (!h) return;
  for (const [src, names] of Object.entries(SRC_FIELDS)) if (src !== "acc") d[src].prepend(h.series, names);
  d.historyLoaded = true;
  for (const ch of d.charts) ch.update();
}

async function loadDeviceThresholds(d) {
  const r = await getJSON(`/api/devices/${encodeURIComponent(d.id)}/settings`);
  if (r) d.thresholds = r.effective.thresholds;
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

function ageOf(d) { return d.card && d.card.last_packet_age_s != null ? d.card.last_packet_age_s + (Date.now() - d.recvAt) / 1000 : null; }

function updateDevice(d, c) {
  d.card = c; d.recvAt = Date.now();
  const alarms = c.active_alarms || [];
  d.cells.alarm.replaceChildren(...(alarms.length ? alarms.map((t) => {
    const a = Alarms.recent.find((x) => x.device_id === d.id && x.type === t && x.status === "active");
    const sev = a ? a.severity : "indeterminate";
    return el("span", { class: `sev ${sev}`, title: a ? a.message : t, "data-severity": sev }, `${SEV_GLYPH[sev]} ${t}`);
  }) : ["–"]));
  const [src, key, label, unit] = KEY_METRIC[d.kind] || [];
  let v = null;
  if ((d.kind === "rod" || d.kind === "imu") && c.attitude) v = c.attitude.pitch_rad * DEG;
  else if (d.kind === "hook" && c.swing) v = c.swing.swing_angle_rad * DEG;
  else if (d.kind === "ball" && c.readings) v = c.readings.water_temp_c;
  d.cells.now.textContent = v == null ? "–" : `${label} ${fmt(v)} ${unit}`;
  if (v != null) { d.spark.push([nowS(), v]); if (d.spark.length > 600) d.spark.shift(); }
  const facts = [];
  const link = d.link || {};
  facts.push(["loss", `${fmt(100 * (c.loss_fraction || 0), 2)} %`]);
  if (link.battery_v != null) facts.push(["battery", `${fmt(link.battery_v, 2)} V`]);
  if (link.rssi_dbm != null) facts.push(["link", `${fmt(link.rssi_dbm, 0)} dBm`]);
  if (c.attitude) facts.push(["pitch / roll", `${fmt(c.attitude.pitch_rad * DEG)}° / ${fmt(c.attitude.roll_rad * DEG)}°`], ["yaw", `${fmt(c.attitude.yaw_unwrapped_rad * DEG)}°`]);
  if (c.swing) { // angles as docs/protocol.md section 3.5 defines them
    const sw = c.swing;
    facts.push(["swing Θ", `${fmt(sw.swing_angle_rad * DEG)}°${sw.provisional ? " (provisional: rope length not known yet, alarms wait)" : ""}`],
      ["displacement bearing", `${fmt(sw.swing_direction_rad * DEG)}° CCW from E`],
      ["torsion φ", `${fmt(sw.torsion_rad * DEG)}°${sw.torsion_std_rad != null ? ` ± ${fmt(sw.torsion_std_rad * DEG)}° (1σ)` : ""} CCW from above`]);
    if (sw.swing_phi_rad != null) facts.push(["Φ (paper 001 eq. 7)", `${fmt(sw.swing_phi_rad * DEG)}° from ψ`]);
    if (sw.rope_length_m != null) facts.push(["rope (estimated)", `${fmt(sw.rope_length_m, 1)} m`]);
  }
  if (d.kind === "hook") { // what the crane tells of its boom tip (docs/protocol.md 3.7): the filter's known input
    const cf = c.crane_feed;
    facts.push(["crane feed", cf ? (cf.in_use ? "in use" : `quiet ${fmt(cf.newest_age_s, 0)} s`) : "none"]);
  }
  if (c.imu_calibration != null) facts.push(["IMU calibration", c.imu_calibration ? "applied" : "none"]); // docs/calibration.md
  if (c.height) facts.push(["height / Vz", `${fmt(c.height.height_m, 2)} m / ${fmt(c.height.vz_m_s, 2)} m/s${c.height.at_rest ? " (rest)" : ""}`]);
  if (c.readings) facts.push(["spot", c.readings.spot], ["water", `${fmt(c.readings.water_temp_c)} °C`], ["O₂", `${fmt(c.readings.oxygen_mg_l, 2)} mg/l`]);
  if (c.reel) facts.push(["reel", `${c.reel.mode} / ${c.reel.motor}`], ["line out", `${fmt(c.reel.line_out_m)} m`]);
  if (c.kind === "rod") facts.push(["auto reel", c.auto_reel ? "on" : "off"]);
  d.facts.replaceChildren(...facts.map(([k, x]) => el("span", { "data-field": k }, `${k} `, el("b", {}, x))));
  if (c.reel && d.reelState) {
    d.reelState.textContent = `${c.reel.mode} / ${c.reel.motor}${c.auto_reel ? " (auto)" : ""}`;
    const lim = tensionLimits(d), full = lim.length ? lim[0].value : 100, t = c.reel.tension_n || 0;
    d.tensionBar.style.width = `${Math.min(100, (100 * t) / full)}%`;
    d.tensionBar.className = "bar" + (lim.length && t >= lim[1].value ? " crit" : lim.length && t >= 0.6 * lim[1].value ? " warn" : "");
    if (lim.length) d.tensionLimit.style.left = `${(100 * lim[1].value) / full}%`;
    d.tensionText.textContent = `tension ${fmt(t, 1)} N / limit ${lim.length ? fmt(lim[1].value, 0) : "?"} N (breaking ${fmt(full, 0)} N)`;
  }
  refreshStatus(d);
}

function refreshStatus(d) { // status and age from the last card, aged on the client: frozen values never look fresh
  const c = d.card; if (!c) return;
  const age = ageOf(d);
  const stale = Live.down || !c.online || age == null || age > STALE_S;
  const text = Live.down ? "unknown (gateway unreachable)" : !c.online ? "offline" : stale ? "stale" : "online";
  d.cells.status.lastChild.textContent = text;
  d.cells.status.setAttribute("data-status", text.split(" ")[0]);
  d.cells.age.textContent = age == null ? "–" : age < 60 ? `${fmt(age, 1)} s ago` : `${fmt(age / 60, 0)} min ago`;
  // toggled one by one: the fleet filter's "hidden" class on the same row must survive this 4 Hz refresh
  const cls = { online: c.online && !stale, stale, offline: !c.online, alarming: (c.active_alarms || []).length > 0 };
  for (const [k, on] of Object.entries(cls)) d.row.classList.toggle(k, on);
  d.panel.classList.toggle("stale", stale);
  d.alarming = (c.active_alarms || []).length > 0;
}

function drawSpark(d) {
  const cv = d.sparkCanvas; if (!cv || cv.offsetParent === null) return;
  const pts = d.histSpark ? d.histSpark.concat(d.spark.filter((p) => p[0] > d.histSpark.at(-1)?.[0])) : d.spark;
  const g = cv.getContext("2d"), w = cv.width, h = cv.height;
  g.clearRect(0, 0, w, h);
  const t1 = nowS(), t0 = t1 - 300;
  const vis = pts.filter((p) => p[0] >= t0 && p[1] != null);
  if (vis.length < 2) return;
  let lo = Math.min(...vis.map((p) => p[1])), hi = Math.max(...vis.map((p) => p[1]));
  if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
  g.strokeStyle = getComputedStyle(document.documentElement).getPropertyValue("--link"); g.lineWidth = 1.2; g.beginPath();
  vis.forEach((p, i) => { const x = ((p[0] - t0) / 300) * w, y = h - 2 - ((p[1] - lo) / (hi - lo)) * (h - 4); if (i) g.lineTo(x, y); else g.moveTo(x, y); });
  g.stroke();
}

async function loadSparks() {
  const h = await getJSON("/api/history?seconds=300&max_points=60");
  if (!h) return;
  for (const [id, cols] of Object.entries(h.devices)) {
    const d = Devices.get(id); if (!d) continue;
    const key = (KEY_METRIC[d.kind] || [])[1];
    if (key && cols[key]) d.histSpark = cols.t_s.map((t, i) => [t, cols[key][i]]).filter((p) => p[1] != null);
  }
}

function applyFilter() {
  const text = $("#f-text").value.trim().toLowerCase(), kind = $("#f-kind").value, alarming = $("#f-alarming").checked;
  let shown = 0;
  for (const d of Devices.values()) {
    const ok = (!text || d.id.toLowerCase().includes(text)) && (!kind || d.kind === kind) && (!alarming || d.alarming);
    d.row.classList.toggle("hidden", !ok); d.panel.classList.toggle("hidden", !ok);
    if (ok) shown++;
  }
  $("#fleet-count").textContent = shown === Devices.size ? `(${Devices.size})` : `(${shown} of ${Devices.size})`;
}

function exportCsv(d) {
  const t1 = View.paused ? View.pausedAt : nowS();
  const x = d.charts.length ? d.charts[0].u.scales.x : null;
  const t0 = x && View.zoomed ? x.min : t1 - View.rangeS, tEnd = x && View.zoomed ? x.max : t1;
  const cols = new Map(); // time -> {field: value}
  const header = [];
  for (const ch of d.charts) {
    const { header: h, rows } = ch.csvRows(t0, tEnd);
    const names = h.map((k) => `${k}`);
    header.push(...names);
    for (const r of rows) { const row = cols.get(r[0]) || {}; names.forEach((n, i) => { row[n] = r[i + 1]; }); cols.set(r[0], row); }
  }
  const lines = [["time_utc", "t_s", ...header].join(",")];
  for (const t of [...cols.keys()].sort((a, b) => a - b)) {
    const row = cols.get(t);
    lines.push([new Date(t * 1000).toISOString(), t.toFixed(3), ...header.map((n) => (row[n] == null ? "" : row[n]))].join(","));
  }
  const blob = new Blob([lines.join("\n") + "\n"], { type: "text/csv" });
  const a = el("a", { href: URL.createObjectURL(blob), download: `${d.id}_${new Date(t0 * 1000).toISOString().replace(/[:.]/g, "-")}.csv` });
  document.body.append(a); a.click(); a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 5000);
  return lines.length - 1;
}

// ---------------------------------------------------------------------------------------------------------
// Live stream
// ---------------------------------------------------------------------------------------------------------
const Live = { down: true, ready: false };

function onTick(f) {
  const now = f.wall_s;
  View.clockSkew = Date.now() / 1000 - now;
  View.fleetSize = f.devices.length;
  for (const c of f.devices) {
    const d = ensureDevice(c);
    const keep = d.panel.open; // closed panels keep no live series: their history comes when opened
    if (keep) {
      d.att.addFrame(c.series, SRC_FIELDS.att);
      if (c.acc) d.acc.addFrame(c.acc, SRC_FIELDS.acc);
    }
    if (c.link) d.link = c.link;
    if (c.online === undefined) continue; // a samples-only tick; cards come with full ticks (2 Hz)
    if (keep && c.reel && c.reel.tension_n != null) d.reel.push(now, { tension_n: c.reel.tension_n });
    if (keep && c.readings) d.env.push(now, { water_temp_c: c.readings.water_temp_c, oxygen_mg_l: c.readings.oxygen_mg_l, air_temp_c: c.readings.air_temp_c });
    updateDevice(d, c);
  }
  if (f.spots) renderSpots(f.spots);
  if (f.alarm_seq !== Alarms.seq) { Alarms.seq = f.alarm_seq; Alarms.refresh(); }
  if (f.full) applyFilter();
  $("#stream-stats").textContent = `${f.devices.length} devices, tick ${new Date(now * 1000).toLocaleTimeString()}` +
    (f.client_dropped ? `, ${f.client_dropped} frames dropped (slow client)` : "");
}

function setConn(text, cls) { const c = $("#conn"); c.textContent = text; c.className = `pill ${cls}`; }
function notice(text) { const n = $("#notice"); n.textContent = text || ""; n.classList.toggle("hidden", !text); }

async function waitReady() { // the gateway serves this page while it warms up; live data starts when it is ready
  for (;;) {
    const h = await getJSON("/api/health");
    if (h && h.ready) { notice(""); return; }
    if (h) { setConn("warming up", "warm"); notice("The gateway is warming up (loading its fusion kernels); live data starts in a few seconds."); }
    else { setConn("gateway unreachable", "off"); notice("The gateway does not answer; retrying. Values shown are frozen."); }
    await new Promise((r) => setTimeout(r, 1000));
  }
}

async function connect() {
  await waitReady();
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/stream`);
  ws.onopen = () => { Live.down = false; document.body.classList.remove("stale"); setConn("live", "on"); notice(""); };
  ws.onclose = () => {
    Live.down = true; document.body.classList.add("stale");
    setConn("disconnected – retrying", "off");
    notice("Connection to the gateway lost: values below are frozen (greyed) until it is back.");
    for (const d of Devices.values()) refreshStatus(d);
    setTimeout(connect, 1000);
  };
  ws.onmessage = (m) => {
    const f = JSON.parse(m.data);
    if (f.type === "tick") onTick(f);
    else if (f.type === "alarm") { Alarms.seq = f.alarm_seq; Alarms.refresh(); }
    else if (f.type === "hello") { Alarms.refresh(); loadSparks(); for (const d of Devices.values()) if (d.panel.open) loadHistory(d); }
  };
}

// ---------------------------------------------------------------------------------------------------------
// Spots
// ---------------------------------------------------------------------------------------------------------
function renderSpots(spots) {
  if (!spots.length) return;
  $("#spot-rows").replaceChildren(...spots.map((s) => el("tr", { "data-testid": `spot-${s.spot}` }, el("td", {}, s.rank), el("td", {}, s.spot),
    el("td", {}, el("span", { class: "scorebar", style: `width:${Math.round(60 * s.score)}px` }), fmt(s.score, 2)),
    el("td", {}, el("ul", {}, ...(s.reasons || []).map((x) => el("li", {}, x)))))));
}

// ---------------------------------------------------------------------------------------------------------
// Alarms: active / history with filters, acknowledge, manual clear, bite banner, plot markers
// ---------------------------------------------------------------------------------------------------------
const UNITS = { bite: "°", drop_back: "°", hook_swing: "°", hook_torsion: "°" };
const Alarms = {
  seq: -1, view: "active", items: [], recent: [], types: new Set(),
  query() {
    const q = new URLSearchParams({ limit: "200" });
    if (this.view === "active") q.set("status", "active");
    const dev = $("#a-device").value.trim(), type = $("#a-type").value, sev = $("#a-severity").value;
    if (dev) q.set("device_id", dev);
    if (type) q.set("type", type);
    if (sev) q.set("severity", sev);
    return q.toString();
  },
  async refresh() {
    const [list, recent, bites] = await Promise.all([getJSON("/api/alarms?" + this.query()), getJSON("/api/alarms?limit=300"),
      getJSON("/api/alarms?type=bite&acknowledged=false&limit=50")]);
    if (list) { this.items = list.items; $("#alarm-count").textContent = `(${list.total}${this.view === "active" ? " active" : ""})`; }
    if (recent) {
      this.recent = recent.items;
      for (const a of recent.items) if (!this.types.has(a.type)) { this.types.add(a.type); $("#a-type").append(el("option", {}, a.type)); }
    }
    this.render();
    // the banner stays until a bite is acknowledged, even when the alarm already cleared (last 10 minutes)
    if (bites) this.banner(bites.items.filter((a) => a.started_at > nowS() - 600));
    for (const d of Devices.values()) for (const ch of d.charts) ch.u.redraw(false, false);
  },
  valueText(a) {
    // line_tension is judged by angle (°) or by reel tension (N): the message says which
    const unit = a.details && a.details.unit === "deg" ? "°" : UNITS[a.type] ?? (/\d N\b/.test(a.message || "") ? " N" : "°");
    if (a.type === "device_offline") return "–";
    return `${fmt(Math.abs(a.peak || a.value), 1)}${unit} / ${fmt(Math.abs(a.threshold), 1)}${unit}`; // magnitudes: signs are in the message
  },
  render() {
    const rows = this.items.map((a) => el("tr", { class: `sev-${a.severity} ${a.status}`, "data-testid": `alarm-${a.id}`, "data-type": a.type, "data-severity": a.severity },
      el("td", { title: new Date(a.started_at * 1000).toString() }, clock(a.started_at)), el("td", {}, a.device_id), el("td", {}, a.type),
      el("td", {}, el("span", { class: `sev ${a.severity}` }, `${SEV_GLYPH[a.severity] || ""} ${a.severity}`)),
      el("td", {}, a.status + (a.acknowledged ? " · acked" : "")), el("td", { class: "num" }, this.valueText(a)), el("td", {}, a.message),
      el("td", {}, a.acknowledged ? el("span", { class: "muted", "data-testid": "acked" }, `by ${a.acknowledged_by}`)
        : a.status === "active" ? el("button", { onclick: () => this.ack(a.id), "data-testid": "ack" }, "Ack") : null,
      a.status === "active" ? el("button", { onclick: () => this.clear(a.id), "data-testid": "clear", title: "clear a stale alarm by hand" }, "Clear") : null)));
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
  async clear(id) {
    const r = await api("POST", `/api/alarms/${encodeURIComponent(id)}/clear`);
    if (!r.ok) toast("clear failed: " + detailMessages(r.data).join("; "));
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
  rope_length_m: "rope length (m, empty = estimated)", rest_heading_deg: "rest heading (°, empty = first fused)",
  imu_offset_m: "IMU offset from the rope axis (m: x, y, z; empty = assumed 0.1, 0, 0)",
  imu_tilt_deg: "IMU tilt on the hook (° about its x, y; empty = square to the rope)",
  acc_bias_xy_m_s2: "accelerometer x/y offset on the hook (m/s²: x, y, as calibrate --hook-mount fits it; empty = not measured)",
};
const VECTOR_FIELDS = new Set(["imu_offset_m", "imu_tilt_deg", "acc_bias_xy_m_s2"]); // lists of numbers: a text field "x, y, z"
function vectorValue(text) { // "0.3, 0, 0.05" -> [0.3, 0, 0.05]; empty -> null; a bad entry goes to the API as is (its 422 says why)
  const t = text.trim();
  if (t === "") return null;
  return t.split(/[\s,;]+/).filter(Boolean).map((x) => (Number.isFinite(Number(x)) ? Number(x) : x));
}
async function loadThresholds(kind) {
  const th = await getJSON(`/api/thresholds/${kind}`);
  if (!th) return;
  Thresholds[kind] = th;
  $(`#th-${kind}`).querySelector(".fields").replaceChildren(...Object.entries(th).flatMap(([k, v]) => [
    el("label", { for: `f-${kind}-${k}` }, LABELS[k] || k.replace(/_/g, " "), el("small", {}, k)),
    VECTOR_FIELDS.has(k)
      ? el("input", { id: `f-${kind}-${k}`, name: k, type: "text", "data-vector": "1", value: v == null ? "" : v.join(", "), "data-testid": `th-${kind}-${k}` })
      : el("input", { id: `f-${kind}-${k}`, name: k, type: "number", step: "any", value: v == null ? "" : String(v), "data-testid": `th-${kind}-${k}` }),
  ]));
}
async function saveThresholds(ev) {
  ev.preventDefault();
  const form = ev.target, kind = form.dataset.kind, body = {};
  for (const inp of form.querySelectorAll("input")) {
    body[inp.name] = inp.dataset.vector ? vectorValue(inp.value) : inp.value === "" ? null : Number(inp.value);
  }
  const r = await api("PUT", `/api/thresholds/${kind}`, body);
  const errs = form.querySelector("ul.errors"), ok = form.querySelector("p.ok");
  if (r.ok) {
    errs.replaceChildren(); ok.textContent = `saved ${new Date().toLocaleTimeString()}`;
    await loadThresholds(kind);
    for (const d of Devices.values()) if (d.kind === kind) loadDeviceThresholds(d);
  } else {
    ok.textContent = "";
    errs.replaceChildren(...detailMessages(r.data).map((m) => el("li", {}, m)));
  }
}

// ---------------------------------------------------------------------------------------------------------
function redraw() { // plots at 4 Hz (not per frame: 100 devices stay cheap); statuses age on the client
  for (const d of Devices.values()) {
    refreshStatus(d);
    if (d.panel.open && !d.panel.classList.contains("hidden")) for (const ch of d.charts) ch.update();
  }
}

function init() {
  $("#range").addEventListener("change", (e) => { View.rangeS = Number(e.target.value); View.zoomed = false; redraw(); });
  $("#pause").addEventListener("click", (e) => {
    View.paused = !View.paused;
    View.pausedAt = nowS();
    e.target.textContent = View.paused ? "Resume" : "Pause";
    e.target.setAttribute("aria-pressed", String(View.paused));
  });
  $("#token-btn").addEventListener("click", () => Token.ask());
  $("#bite-ack").addEventListener("click", async () => {
    for (const id of ($("#bite").dataset.alarmIds || "").split(",").filter(Boolean)) await Alarms.ack(id);
  });
  for (const tab of document.querySelectorAll(".tab")) tab.addEventListener("click", () => {
    for (const t of document.querySelectorAll(".tab")) t.classList.toggle("active", t === tab);
    Alarms.view = tab.dataset.view; Alarms.refresh();
  });
  for (const id of ["#a-device", "#a-type", "#a-severity"]) $(id).addEventListener("input", () => Alarms.refresh());
  for (const id of ["#f-text", "#f-kind", "#f-alarming"]) $(id).addEventListener("input", applyFilter);
  for (const f of document.querySelectorAll("form.th")) f.addEventListener("submit", saveThresholds);
  loadThresholds("rod"); loadThresholds("hook");
  connect();
  setInterval(redraw, 250);
  setInterval(() => { for (const d of Devices.values()) drawSpark(d); }, 1000);
  setInterval(loadSparks, 15000);
}
init();
