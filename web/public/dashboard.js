// The dashboard page: live data over /ws/live into the plots, status from /api/status, gain
// sliders built from the gain declarations (/api/estimators), the viser 3-D view in an iframe.
"use strict";

const $ = (id) => document.getElementById(id);
// For tests and the curious: samples received over the WebSocket per source, frames, fps.
const gcsStats = (window.gcsStats = { received: {}, messages: 0, fps: 0, dropped: 0, client: null, lastFrameAt: 0, historyLoads: 0 });
let plots = null;

async function api(method, path, body, timeoutMs) {
  // The token travels as the HttpOnly cookie the start-up URL set: scripts never hold it.
  const headers = { "Content-Type": "application/json" };
  const signal = timeoutMs ? AbortSignal.timeout(timeoutMs) : undefined;
  const res = await fetch(vehicleUrl(path), { method, headers, signal, body: body === undefined ? undefined : JSON.stringify(body) });
  const { data, message } = await readAnswer(res);
  if (!res.ok) throw new Error(message);
  return data;
}

// ---- live data -----------------------------------------------------------------------------
function ingestFrame(msg) {
  for (const [source, cols] of Object.entries(msg.points)) {
    gcsStats.received[source] = (gcsStats.received[source] || 0) + cols[0].length;
    plots.add(source, cols);
  }
}

function onMessage(msg) {
  gcsStats.messages++;
  gcsStats.lastFrameAt = performance.now();
  if (msg.type === "points") ingestFrame(msg);
  else if (msg.type === "gain") showGain(msg.estimator, msg.gain, msg.new);
  else if (msg.type === "preset") showPreset(msg.estimator, msg.preset);
  else if (msg.type === "param value") document.dispatchEvent(new CustomEvent("gcs:param", { detail: msg }));  // panels.js
  else if (msg.type === "client") { gcsStats.client = msg; gcsStats.dropped = msg.dropped_points; }
}

// History into the plots (merged, never a restart): `seconds` back from the newest sample, every
// sample for a window up to a minute (so a zoom shows samples, as for live data), else at the
// resolution the plots can show (the server sends min/max per column when a window holds more);
// or every sample after `since` (a reconnect's gap).
const EVERY_SAMPLE_S = 60;
async function loadHistory({ seconds = 60, since = null } = {}) {
  const columns = Math.max(100, Math.round(plots.charts[0].u.bbox.width / devicePixelRatio));
  const query = since != null ? `since=${since}` : seconds <= EVERY_SAMPLE_S ? `seconds=${seconds}` : `seconds=${seconds}&columns=${columns}`;
  plots.load(await api("GET", `/api/history?${query}`));
  gcsStats.historyLoads++;
}

async function catchUp() {
  const newest = plots.newest();
  if (Number.isFinite(newest)) { await loadHistory({ since: newest - 1 }); return; }  // reconnect: the gap
  await loadHistory({ seconds: KEEP_S });  // a new page: the whole store, coarse ...
  await loadHistory({ seconds: plots.window });  // ... and the window at its own resolution
}

function connect() {
  const ws = (window.gcsWs = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${vehicleUrl("/ws/live")}`));
  ws.binaryType = "arraybuffer";  // points come as binary frames (wire.js), control messages as JSON text
  let queue = [];  // frames that arrive while the history loads, applied after it
  ws.onopen = async () => {
    try { await catchUp(); } catch (e) { console.warn("history:", e.message); }
    queue.forEach(onMessage); queue = null;
  };
  const take = (msg) => { if (queue) queue.push(msg); else onMessage(msg); };
  ws.onmessage = (ev) => { if (typeof ev.data === "string") take(JSON.parse(ev.data)); else decodeWire(ev.data, take); };
  ws.onclose = () => setTimeout(connect, 1000);
}

function showRestart(r) {
  const note = document.createElement("div");
  note.textContent = `⟲ vehicle rebooted at ${r.at.toLocaleTimeString()} (its clock went from ${r.from.toFixed(1)} s back to ${r.to.toFixed(1)} s): plots started again`;
  $("plot-notes").prepend(note);
}

// ---- status --------------------------------------------------------------------------------
function fmt(x, d = 1) { return x == null ? "–" : Number(x).toFixed(d); }

function showStatus(s) {
  const l = s.link;
  $("link-state").textContent = `link ${l.state}`;
  $("link-state").className = `pill ${l.state}`;
  const why = l.lost_reason || l.open_error;
  $("link-state").title = why || "";
  $("link-detail").textContent = `${l.address} · ${l.packets} packets · lost ${lossText(l, s.vehicle)} · `
    + `CRC errors ${l.crc_errors} · ${fmt(l.bytes_per_s / 1000)} kB/s · heartbeat ${fmt(l.heartbeat_age_s, 1)} s ago`;
  const sinceFrame = gcsStats.lastFrameAt ? performance.now() - gcsStats.lastFrameAt : null;
  $("data-age").textContent = `data is ${fmt(s.data_age_ms, 0)} ms old at the server; last frame ${fmt(sinceFrame, 0)} ms ago`;
  const me = gcsStats.client;
  $("viewer").textContent = `${s.clients.length} viewer(s)` + (me ? ` · this page: ${me.sent_points} samples, dropped ${me.dropped_points}` : "")
    + s.clients.filter((c) => c.dropped_points).map((c) => ` · viewer ${c.id} dropped ${c.dropped_points}`).join("");
  // one line per reason, naming every estimator it holds for ("dcm, kf, ekf: raw IMU at 19.0 Hz,
  // ..."): over a 57600 radio each of the three said the same long sentence, pushing the plots down
  const unreliable = new Map();
  for (const [n, e] of Object.entries(s.estimators).filter(([, x]) => !x.reliable)) {
    unreliable.set(e.reason, [...(unreliable.get(e.reason) || []), n]);
  }
  const warn = [...unreliable].map(([reason, names]) => `${names.join(", ")}: ${reason}`);
  if (l.state !== "connected") warn.unshift(`link ${l.state}: ${why ? `${why}; ` : ""}no fresh data`);
  for (const other of s.vehicle.others || []) {
    warn.unshift(`another vehicle sends as system ${s.vehicle.sysid} on ${other}: not served; give each its own system id (MAV_SYSID or SYSID_THISMAV)`);
  }
  if (s.vehicle.two_senders) {
    warn.unshift(`two vehicles are sending as system ${s.vehicle.sysid}: their data mix; give each its own system id (MAV_SYSID or SYSID_THISMAV), or hear a vehicle through one route only`);
  }
  for (const p of s.parts.filter((x) => x.state === "failed")) warn.unshift(`station part ${p.name} failed: ${p.error}`);
  $("warnings").innerHTML = warn.map((w) => `<div>⚠ ${escapeHtml(w)}</div>`).join("");
  const rows = Object.entries(l.streams).map(([name, r]) =>
    `<tr title="${escapeHtml(r.reason || r.method || "")}"><td>${name}</td><td>${fmt(r.requested_hz)}${r.accepted_hz != null && r.accepted_hz !== r.requested_hz ? ` → ${fmt(r.accepted_hz)}` : ""}</td><td class="${r.ratio != null && r.ratio < 0.9 ? "low" : ""}">${fmt(r.achieved_hz)}</td></tr>`
    + (r.reason ? `<tr><td></td><td colspan="2" class="why">${escapeHtml(r.reason)}</td></tr>` : ""));
  const est = Object.entries(s.estimators).map(([n, e]) =>
    `<tr><td>${n} (${e.preset})</td><td>${fmt(e.imu_rate_hz)} Hz</td><td class="${e.reliable ? "" : "low"}">${e.reliable ? "reliable" : "unreliable"}`
    + `${e.lag_s == null ? "" : `, lag ${1000 * e.lag_s >= 0 ? "+" : ""}${fmt(1000 * e.lag_s, 0)} ms`}</td></tr>`);
  const dec = s.declination_rad == null ? "none (yaw against magnetic north)"
    : `${fmt(s.declination_rad * 180 / Math.PI, 2)}° from ${escapeHtml(s.declination_source)}`;
  $("streams").innerHTML = `<table><tr><th>stream (${l.stream_method || "?"})</th><th>requested Hz</th><th>achieved Hz</th></tr>${rows.join("")}`
    + `<tr><th>estimator</th><th>IMU rate</th><th>health</th></tr>${est.join("")}</table>`
    + `<div class="note">lag +20 ms = estimator 20 ms behind onboard ATTITUDE (negative: ahead) · declination ${dec}</div>`;
  // The 3-D view follows the port the server publishes now: a station restarted with another
  // viser port (a new `gcs serve`, its old one taken) left the frame on the old, dead one.
  const frame = $("pose"), port = s.viser_port ? String(s.viser_port) : "";
  if (port !== (frame.dataset.port ?? "")) {
    frame.dataset.port = port;
    const software = port && softwareWebGL();
    if (port) frame.src = `${location.protocol}//${location.hostname}:${port}/${software ? "?fixedDpr=0.5" : ""}`;
    else frame.src = "about:blank";  // served without the 3-D view now
    // viser's own notice of it is hidden (gcs.server.scene): it covered a third of the view
    $("pose-renderer").textContent = software ? "Drawn without GPU acceleration (software WebGL), at half resolution." : "";
  }
  if (!s.authorised) {  // as the side panels' controls: a gain moved here could only be refused (401)
    $("gain-note").textContent = "Read-only: open the URL printed at start-up (with ?token=) to change gains.";
    for (const el of $("gains").querySelectorAll("input, select, button")) el.disabled = true;
  }
}

// WebGL drawn on the CPU (no GPU driver: SwiftShader, llvmpipe; the renderer names viser's own
// notice looks for): the 3-D view then renders at half resolution, a quarter of the pixels, on the
// cores the plots need too (viser's `fixedDpr`; bench.page_fps).
function softwareWebGL() {
  const gl = document.createElement("canvas").getContext("webgl");
  const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
  const renderer = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : "";
  gl?.getExtension("WEBGL_lose_context")?.loseContext();
  return /swiftshader|llvmpipe|softpipe|software/i.test(renderer);
}

// ---- numbers at a glance: current attitude per source, errors per estimator and reference ----
// Two decimals in degrees everywhere (what /api/estimates carries, rounded once here: no float noise).
const deg = (x) => x == null ? "–" : Number(x).toFixed(2);
const triple = (xs) => xs ? xs.map(deg).join(" / ") : "–";

function showNumbers(est, status) {
  const src = Object.values(est.sources);
  // a source that stopped (onboard-unready once the EKF is ready) is not the attitude now: left out
  const now = src.filter((a) => !a.stale);
  $("now-table").innerHTML = `<tr><th>now (°)</th>${now.map((a) => `<th style="color:${COLORS[a.source] || "#555"}">${a.source}</th>`).join("")}</tr>`
    + ["roll", "pitch", "yaw"].map((ax) => `<tr><td>${ax}</td>${now.map((a) => `<td data-source="${a.source}" data-axis="${ax}">${deg(a[`${ax}_deg`])}</td>`).join("")}</tr>`).join("");
  const rows = [];
  for (const a of src.filter((x) => x.kind === "estimator")) {
    const e = status.estimators[a.source] || {};
    // the reason is in the warnings above (and this cell's tooltip): in every row it wrapped each
    // row to five lines and pushed the plots below a laptop's fold
    const health = e.reliable === false ? `<td class="health low" title="${escapeHtml(e.reason || "")}">unreliable</td>`
      : `<td class="health">reliable</td>`;
    for (const [ref, st] of Object.entries(a.errors)) {
      // the lag is searched against onboard ATTITUDE only: shown in every row, "dcm − truth" read
      // as dcm being that far behind (or ahead of) the truth
      const lag = ref !== "onboard" || e.lag_s == null ? "–" : `${e.lag_s >= 0 ? "+" : ""}${Math.round(1000 * e.lag_s)} ms`;
      rows.push(`<tr data-estimator="${a.source}" data-reference="${ref}"><td>${a.source} − ${ref}</td>`
        + `<td class="triple rms-window">${triple(st.window_rms_deg)}</td><td class="triple">${triple(st.window_max_deg)}</td>`
        + `<td class="triple rms-session">${triple(st.session_rms_deg)}</td><td class="triple">${triple(st.session_max_deg)}</td>`
        + `<td class="lag">${lag}</td><td>${fmt(e.imu_rate_hz)} Hz</td>${health}</tr>`);
    }
  }
  // the first header on two lines: on one it alone widened the table past its column at 1366 px
  $("numbers-table").innerHTML = "<tr><th>estimator −<br>reference</th><th>RMS 10 s (°)</th><th>max 10 s (°)</th><th>RMS session (°)</th>"
    + `<th>max session (°)</th><th>lag</th><th>IMU rate</th><th>health</th></tr>${rows.join("")}`;
}

// Packets lost by sequence number; unknown while two senders' numbers interleave (as gcs status).
function lossText(link, vehicle) {
  if (vehicle.two_senders) return "unknown (two senders' sequence numbers interleave)";
  return `${link.packets_lost} (${fmt(100 * link.loss_fraction, 2)} %)`;
}

// ---- the vehicle panel ---------------------------------------------------------------------
function showVehicle(v, link) {
  const kv = [
    ["mode", v.mode ?? "–"], ["armed", v.armed ? "ARMED" : "disarmed"],
    ["battery", v.battery_v == null ? "–" : `${v.battery_v.toFixed(2)} V${v.battery_a == null ? "" : ` · ${v.battery_a.toFixed(1)} A`}${v.battery_remaining_pct == null ? "" : ` · ${v.battery_remaining_pct} %`}`],
    ["GPS", v.gps_fix == null ? "–" : `${v.gps_fix} · ${v.gps_satellites ?? "?"} satellites · HDOP ${v.gps_hdop == null ? "?" : v.gps_hdop.toFixed(2)}`],
    ["EKF", v.ekf_flags.length ? `${v.ekf_flags.join(", ")}${v.ekf_variance_max == null ? "" : ` · largest variance ${v.ekf_variance_max.toFixed(2)}`}` : "no EKF_STATUS_REPORT or ESTIMATOR_STATUS yet"],
    ["sensors", v.sensors_unhealthy.length ? `unhealthy: ${v.sensors_unhealthy.join(", ")}` : "all healthy"],
    ["link", `${link.state} · loss ${lossText(link, v)} · heartbeat ${fmt(link.heartbeat_age_s, 1)} s ago`],
    ["autopilot", `${v.autopilot ?? "?"} ${v.vehicle_type ?? ""} ${v.firmware ?? ""} · ${v.system_status ?? ""}`],
  ];
  $("vehicle-state").innerHTML = kv.map(([k, x]) => `<div class="k">${k}</div><div class="v" id="vehicle-${k}">${escapeHtml(String(x))}</div>`).join("");
  $("vehicle-armed").classList.toggle("armed", v.armed);
  $("autopilot-messages").innerHTML = v.messages.map((m) => `<li class="sev${m.severity}"><span class="hint">${new Date(m.wall_time * 1000).toLocaleTimeString()}</span> `
    + `<b>${m.severity_name}</b> ${escapeHtml(m.text)}</li>`).join("") || "<li class=\"hint\">none yet</li>";
  drawTrack($("track"), v.track_ne_m);
}

function drawTrack(canvas, track) {  // north up, east right, equal metres on both axes, a 1-2-5 grid
  const ctx = canvas.getContext("2d"), w = canvas.width, h = canvas.height;
  ctx.clearRect(0, 0, w, h); ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
  if (!track.length) { ctx.fillStyle = "#777"; ctx.fillText("no 3D fix yet", 10, 20); return; }
  const ns = track.map((p) => p[0]), es = track.map((p) => p[1]);
  const span = Math.max(10, Math.max(...ns) - Math.min(...ns), Math.max(...es) - Math.min(...es)) * 1.2;
  const cn = (Math.max(...ns) + Math.min(...ns)) / 2, ce = (Math.max(...es) + Math.min(...es)) / 2, k = Math.min(w, h) / span;
  const x = (e) => w / 2 + (e - ce) * k, y = (n) => h / 2 - (n - cn) * k;
  const step = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000].find((s) => span / s <= 8) || 2000;
  ctx.strokeStyle = "#e6e6e6"; ctx.fillStyle = "#999"; ctx.lineWidth = 1;
  for (let g = Math.ceil((ce - span) / step) * step; g <= ce + span; g += step) { ctx.beginPath(); ctx.moveTo(x(g), 0); ctx.lineTo(x(g), h); ctx.stroke(); }
  for (let g = Math.ceil((cn - span) / step) * step; g <= cn + span; g += step) { ctx.beginPath(); ctx.moveTo(0, y(g)); ctx.lineTo(w, y(g)); ctx.stroke(); }
  ctx.fillText(`grid ${step} m · N ↑`, 6, h - 6);
  ctx.strokeStyle = COLORS.onboard || "#333"; ctx.lineWidth = 2; ctx.beginPath();
  track.forEach((p, i) => (i ? ctx.lineTo(x(p[1]), y(p[0])) : ctx.moveTo(x(p[1]), y(p[0])))); ctx.stroke();
  const last = track[track.length - 1]; ctx.fillStyle = "#c0392b"; ctx.beginPath(); ctx.arc(x(last[1]), y(last[0]), 4, 0, 7); ctx.fill();
}

function escapeHtml(s) { return s.replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]); }

// A server that stops answering without closing (hung, or a network that drops packets) is
// unreachable after STATUS_TIMEOUT_MS, and one poll waits at a time: a request a second piled up
// behind it, and the page went on showing its last answer as live.
const STATUS_TIMEOUT_MS = 5000;
let statusPending = false;
async function pollStatus() {
  if (statusPending) return;
  statusPending = true;
  try {
    const [status, est] = await Promise.all([api("GET", "/api/status", undefined, STATUS_TIMEOUT_MS), api("GET", "/api/estimates", undefined, STATUS_TIMEOUT_MS)]);
    showStatus(status); showNumbers(est, status); showVehicle(status.vehicle, status.link);
    document.dispatchEvent(new CustomEvent("gcs:status", { detail: status }));  // radio.js, without a poll of its own
  } catch (e) {  // the pill was green and the numbers below read as live: neither is true now
    $("link-state").textContent = "server unreachable"; $("link-state").className = "pill lost";
    const why = e.name === "TimeoutError" ? `none in ${STATUS_TIMEOUT_MS / 1000} s` : e.message;
    $("warnings").innerHTML = `<div>⚠ no answer from the station's server (${escapeHtml(why)}): what this page shows is from before</div>`;
    console.warn("status:", why);
  } finally { statusPending = false; }
  $("fps").textContent = `${plots.fps} fps`;
  gcsStats.fps = plots.fps;
}

// ---- gains ---------------------------------------------------------------------------------
const gainRows = {};  // "est/gain" -> {range, number, info}

// A gain as a person reads it: π as 3.142, not 3.141592653589793 (the bounds checked stay exact).
const shown = (x, digits = 4) => +Number(x).toPrecision(digits);
const toPosition = (info, v) => info.scale === "log" ? (v > 0 ? Math.log10(v) : info.slider_min) : v;
const fromPosition = (info, p) => info.scale === "log" ? Math.min(info.max, Math.max(info.min, 10 ** p)) : p;

function gainRow(est, info) {
  const row = document.createElement("div"); row.className = "gain";
  row.innerHTML = `<label>${info.name}</label><input type="range"><input type="number"><span class="unit">${escapeHtml(info.unit)}</span>`
    + `<div class="meaning">${escapeHtml(info.meaning)} [${shown(info.min)} … ${shown(info.max)}]${info.scale === "log" ? ", log slider" : ""}</div><div class="why"></div>`;
  const [range, number] = row.querySelectorAll("input");
  Object.assign(range, { min: info.slider_min, max: info.slider_max, step: info.slider_step, value: toPosition(info, info.value) });
  Object.assign(number, { min: info.min, max: info.max, step: "any", value: shown(info.value, 6) });
  range.dataset.estimator = est; range.dataset.gain = info.name; number.dataset.gain = info.name;
  const r = gainRows[`${est}/${info.name}`] = { range, number, info, accepted: info.value };
  const send = async (value) => {
    try {
      const change = await api("PUT", `/api/estimators/${est}/gains/${info.name}`, { value });
      r.accepted = change.new; row.classList.remove("error"); row.querySelector(".why").textContent = ""; $("gain-error").textContent = "";
    } catch (e) {  // refused: back to the value the estimator keeps, and why
      row.classList.add("error"); row.querySelector(".why").textContent = `✗ ${value} refused: ${e.message}; kept ${shown(r.accepted, 6)}`;
      number.value = shown(r.accepted, 6); range.value = toPosition(info, r.accepted);
    }
  };
  // While dragging: one request in flight at a time, the newest position next. Not paced by
  // animation frames, which come seldom when the page draws slowly.
  let inFlight = false, moved = false;
  const sendLatest = async () => {
    inFlight = true;
    while (moved) { moved = false; await send(fromPosition(info, Number(range.value))); }
    inFlight = false;
  };
  range.addEventListener("input", () => {
    number.value = shown(fromPosition(info, Number(range.value)), 6);
    moved = true;
    if (!inFlight) sendLatest();
  });
  // an emptied box (or one the browser could not read: "1e") is no value, not 0: back to the gain held
  number.addEventListener("change", () => { if (number.value === "") number.value = shown(r.accepted, 6); else send(Number(number.value)); });
  return row;
}

function showGain(est, name, value) {
  const r = gainRows[`${est}/${name}`];
  if (!r) return;
  if (document.activeElement !== r.range) r.range.value = toPosition(r.info, value);
  if (document.activeElement !== r.number) r.number.value = shown(value, 6);
  r.accepted = value;
}

// A reset to a preset (this page's, another page's or a script's): the estimator's heading names it.
function showPreset(est, preset) {
  const hint = document.querySelector(`#gains summary[data-estimator="${CSS.escape(est)}"] .hint`);
  if (hint) hint.textContent = `(preset ${preset})`;
}

function buildGains(estimators) {
  const box = $("gains");
  const err = document.createElement("p"); err.id = "gain-error"; box.appendChild(err);
  for (const e of estimators) {
    const d = document.createElement("details"); d.open = e === estimators[0];
    d.innerHTML = `<summary data-estimator="${escapeHtml(e.name)}">${e.name} <span class="hint">(preset ${escapeHtml(e.preset)})</span></summary>`;
    for (const g of e.gains) d.appendChild(gainRow(e.name, g));
    const reset = document.createElement("div");
    reset.innerHTML = `<select>${e.presets.map((p) => `<option ${p === e.default_preset ? "selected" : ""}>${p}</option>`).join("")}</select> <button type="button">reset to preset</button>`;
    reset.querySelector("button").addEventListener("click", async () => {
      try { await api("POST", `/api/estimators/${e.name}/preset`, { preset: reset.querySelector("select").value }); }
      catch (x) { $("gain-error").textContent = x.message; }
    });
    d.appendChild(reset); box.appendChild(d);
  }
}

// ---- start ---------------------------------------------------------------------------------
async function main() {
  const estimators = await api("GET", "/api/estimators");
  plots = new Plots($("charts"), estimators.map((e) => e.name), showRestart);
  window.gcsPlots = plots;
  window.gcsCount = (source, t0, t1) => plots.sources[source] ? plots.sources[source].count(t0, t1) : 0;
  buildGains(estimators);
  $("window").addEventListener("change", async (ev) => {
    const seconds = Number(ev.target.value);
    plots.setWindow(seconds);
    try { await loadHistory({ seconds }); } catch (e) { console.warn("history:", e.message); }
  });
  $("pause").addEventListener("click", () => plots.togglePause());
  connect();
  pollStatus(); setInterval(pollStatus, 1000);
}

main();
