// The dashboard page: live data over /ws/live into the plots, status from /api/status, gain
// sliders built from the gain declarations (/api/estimators), the viser 3-D view in an iframe.
"use strict";

const $ = (id) => document.getElementById(id);
// For tests and the curious: samples received over the WebSocket per source, frames, fps.
const gcsStats = (window.gcsStats = { received: {}, messages: 0, fps: 0, dropped: 0, client: null, lastFrameAt: 0 });
let plots = null;

async function api(method, path, body) {
  // The token travels as the HttpOnly cookie the start-up URL set: scripts never hold it.
  const headers = { "Content-Type": "application/json" };
  const res = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const data = await res.json().catch(() => ({}));
  if (!res.ok) throw new Error(typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail || res.status));
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
  else if (msg.type === "batch") msg.frames.forEach(onMessage);
  else if (msg.type === "gain") showGain(msg.estimator, msg.gain, msg.new);
  else if (msg.type === "client") { gcsStats.client = msg; gcsStats.dropped = msg.dropped_points; }
}

async function loadHistory(seconds) {
  const h = await api("GET", `/api/history?seconds=${seconds}`);
  plots.load(h.points);
}

function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/live`);
  let queue = [];  // frames that arrive while the history loads, applied after it
  ws.onopen = async () => {
    try { await loadHistory(plots.window); } catch (e) { console.warn("history:", e.message); }
    queue.forEach(onMessage); queue = null;
  };
  ws.onmessage = (ev) => { const msg = JSON.parse(ev.data); if (queue) queue.push(msg); else onMessage(msg); };
  ws.onclose = () => setTimeout(connect, 1000);
}

// ---- status --------------------------------------------------------------------------------
function fmt(x, d = 1) { return x == null ? "–" : Number(x).toFixed(d); }

function showStatus(s) {
  const l = s.link;
  $("link-state").textContent = `link ${l.state}`;
  $("link-state").className = `pill ${l.state}`;
  $("link-detail").textContent = `${l.address} · ${l.packets} packets · lost ${l.packets_lost} (${fmt(100 * l.loss_fraction, 2)} %) · `
    + `CRC errors ${l.crc_errors} · ${fmt(l.bytes_per_s / 1000)} kB/s · heartbeat ${fmt(l.heartbeat_age_s, 1)} s ago`;
  const sinceFrame = gcsStats.lastFrameAt ? performance.now() - gcsStats.lastFrameAt : null;
  $("data-age").textContent = `data is ${fmt(s.data_age_ms, 0)} ms old at the server; last frame ${fmt(sinceFrame, 0)} ms ago`;
  const me = gcsStats.client;
  $("viewer").textContent = `${s.clients.length} viewer(s)` + (me ? ` · this page: ${me.sent_points} samples, dropped ${me.dropped_points}` : "")
    + s.clients.filter((c) => c.dropped_points).map((c) => ` · viewer ${c.id} dropped ${c.dropped_points}`).join("");
  const warn = Object.entries(s.estimators).filter(([, e]) => !e.reliable).map(([n, e]) => `${n}: ${e.reason}`);
  if (l.state !== "connected") warn.unshift(`link ${l.state}: no fresh data`);
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
  const frame = $("pose");
  if (s.viser_port && !frame.src) frame.src = `${location.protocol}//${location.hostname}:${s.viser_port}/`;
  if (!s.authorised) $("gain-note").textContent = "Read-only: open the URL printed at start-up (with ?token=) to change gains.";
}

function escapeHtml(s) { return s.replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]); }

async function pollStatus() {
  try { showStatus(await api("GET", "/api/status")); } catch (e) { $("link-state").textContent = "server unreachable"; }
  $("fps").textContent = `${plots.fps} fps`;
  gcsStats.fps = plots.fps;
}

// ---- gains ---------------------------------------------------------------------------------
const gainRows = {};  // "est/gain" -> {range, number, info}

const toPosition = (info, v) => info.scale === "log" ? (v > 0 ? Math.log10(v) : info.slider_min) : v;
const fromPosition = (info, p) => info.scale === "log" ? Math.min(info.max, Math.max(info.min, 10 ** p)) : p;

function gainRow(est, info) {
  const row = document.createElement("div"); row.className = "gain";
  row.title = `${info.meaning}\n[${info.min} … ${info.max}] ${info.unit}, default ${info.default}${info.scale === "log" ? "\n(log slider)" : ""}`;
  row.innerHTML = `<label>${info.name}</label><input type="range"><input type="number"><span class="unit">${info.unit}</span>`;
  const [range, number] = row.querySelectorAll("input");
  Object.assign(range, { min: info.slider_min, max: info.slider_max, step: info.slider_step, value: toPosition(info, info.value) });
  Object.assign(number, { min: info.min, max: info.max, step: "any", value: info.value });
  range.dataset.estimator = est; range.dataset.gain = info.name;
  const send = async (value) => {
    try { await api("PUT", `/api/estimators/${est}/gains/${info.name}`, { value }); row.classList.remove("error"); $("gain-error").textContent = ""; }
    catch (e) { row.classList.add("error"); $("gain-error").textContent = e.message; }
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
    number.value = +fromPosition(info, Number(range.value)).toPrecision(6);
    moved = true;
    if (!inFlight) sendLatest();
  });
  number.addEventListener("change", () => send(Number(number.value)));
  gainRows[`${est}/${info.name}`] = { range, number, info };
  return row;
}

function showGain(est, name, value) {
  const r = gainRows[`${est}/${name}`];
  if (!r) return;
  if (document.activeElement !== r.range) r.range.value = toPosition(r.info, value);
  if (document.activeElement !== r.number) r.number.value = +Number(value).toPrecision(6);
}

function buildGains(estimators) {
  const box = $("gains");
  const err = document.createElement("p"); err.id = "gain-error"; box.appendChild(err);
  for (const e of estimators) {
    const d = document.createElement("details"); d.open = e === estimators[0];
    d.innerHTML = `<summary>${e.name} <span class="hint">(preset ${e.preset})</span></summary>`;
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
  plots = new Plots($("charts"), estimators.map((e) => e.name));
  window.gcsPlots = plots;
  window.gcsCount = (source, t0, t1) => plots.sources[source] ? plots.sources[source].count(t0, t1) : 0;
  buildGains(estimators);
  $("window").addEventListener("change", async (ev) => {
    const seconds = Number(ev.target.value);
    plots.setWindow(seconds);
    const s = Object.values(plots.sources).find((x) => x.t.length);
    if (s && plots.newest() - s.t[0] < seconds - 1) {  // not enough kept yet: fetch the rest
      try { await loadHistory(seconds); } catch (e) { console.warn("history:", e.message); }
    }
  });
  $("pause").addEventListener("click", () => plots.togglePause());
  connect();
  pollStatus(); setInterval(pollStatus, 1000);
}

main();
