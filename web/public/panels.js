// The side panels besides the live view: vehicle tuning (/api/tuning, /api/params), recording and
// sessions (/api/recording, /api/sessions, export and replay links) and what-if
// (/api/whatif), test protocols (/api/protocol). Uses api(), $, fmt and escapeHtml from dashboard.js,
// readAnswer from answer.js.
"use strict";

// One request, never throwing: {ok, status, data, message} (message: the server's reason, readAnswer).
async function call(method, path, body) {
  const headers = { "Content-Type": "application/json" };
  try {
    const res = await fetch(vehicleUrl(path), { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
    return { ok: res.ok, status: res.status, ...(await readAnswer(res)) };
  } catch (e) {
    return { ok: false, status: 0, data: {}, message: `server unreachable (${e.message})` };
  }
}

const html = (s) => escapeHtml(String(s ?? ""));
const num = (x, d = 4) => x == null ? "–" : String(+Number(x).toPrecision(d + 2));
function bytes(n) {
  if (n == null) return "–";
  for (const u of ["B", "KiB", "MiB", "GiB"]) { if (n < 1024 || u === "GiB") return u === "B" ? `${n} B` : `${n.toFixed(1)} ${u}`; n /= 1024; }
}
// A poll that keeps one request waiting at a time: a server that stops answering must not gather
// one more each period, all sent in a burst when it comes back.
function oneAtATime(refresh) {
  let pending = null;
  return () => { pending ??= refresh().finally(() => { pending = null; }); return pending; };
}
// A refresh that, asked while one is on its way, runs once more after it: that one may carry an
// answer from before what the caller just learnt of.
function andAgain(refresh) {
  let pending = null, again = false;
  const run = () => {
    if (pending) { again = true; return pending; }
    pending = refresh().finally(() => { pending = null; if (again) { again = false; run(); } });
    return pending;
  };
  return run;
}
function say(id, text, kind = "") { const el = $(id); el.textContent = text; el.className = `message ${kind}`; }
const panelState = (window.gcsPanels = { tab: "live", authorised: false, tuning: null, sessions: [], whatif: null });

// ---- tabs ----------------------------------------------------------------------------------
function showTab(name) {
  panelState.tab = name;
  for (const b of document.querySelectorAll("#tabs button")) b.classList.toggle("active", b.dataset.tab === name);
  for (const p of document.querySelectorAll(".tab-panel")) p.hidden = p.id !== `tab-${name}`;
  if (name === "tuning") refreshTuning();
  if (name === "sessions") { refreshSessions(); refreshRecording(); }
  if (name === "whatif") refreshSessions();
  if (name === "protocol") refreshProtocol();
}

// ---- tuning --------------------------------------------------------------------------------
const tuningRows = {};  // name -> {tr, range, number, result}
let downloadPoll = null;

async function refreshTuning() {
  const p = await call("GET", "/api/params");
  if (!p.ok) { $("param-progress-text").textContent = `parameters: ${p.message}`; return; }
  showDownload(p.data);
  if (!p.data.complete) return;  // GET /api/tuning would download the table itself and wait
  const t = await call("GET", "/api/tuning");
  if (!t.ok) { say("tuning-message", `tuning: ${t.message}`, "error"); return; }
  showTuning(t.data);
}

function showDownload(p) {
  const prog = p.progress || {}, bar = $("param-progress"), btn = $("param-download-btn");
  const got = prog.received ?? p.params.length, count = prog.count ?? null;
  if (p.complete) {
    $("param-progress-text").textContent = `parameter table: ${p.params.length} parameters downloaded`;
    bar.hidden = true; btn.hidden = true;
  } else if (prog.state === "downloading") {
    $("param-progress-text").textContent = `downloading parameters… ${got}${count ? ` / ${count}` : ""}`;
    bar.hidden = false; bar.max = count || 1; bar.value = got; btn.hidden = true;
  } else {
    $("param-progress-text").textContent = prog.state === "incomplete"
      ? `parameter download incomplete: ${got} / ${count ?? "?"} received${prog.error ? ` (${prog.error})` : ""}; try again`
      : "the parameter table is not downloaded yet: tuning needs it (the pre-flight record of every value).";
    bar.hidden = true; btn.hidden = false;
  }
  const busy = !p.complete && prog.state === "downloading";
  if (busy && !downloadPoll) downloadPoll = setInterval(oneAtATime(pollDownload), 400);
  if (!busy && downloadPoll) { clearInterval(downloadPoll); downloadPoll = null; }
}

async function pollDownload() {
  const p = await call("GET", "/api/params");
  if (!p.ok) return;
  showDownload(p.data);
  if (p.data.complete) refreshTuning();
}

async function startDownload() {
  const r = await call("POST", "/api/params/download");
  if (!r.ok) { $("param-progress-text").textContent = `download: ${r.message}`; return; }
  showDownload({ complete: false, params: [], progress: r.data.progress.state === "downloading" ? r.data.progress : { state: "downloading" } });
}

function showTuning(t) {
  panelState.tuning = t;
  $("tuning-profile").textContent = `${t.title} (profile ${t.profile})`;
  $("tuning-limits").textContent = `at most one write per parameter every ${t.limits.per_param_interval_s} s, `
    + `${t.limits.max_writes_per_s} writes per s` + (t.started ? ` · pre-flight snapshot ${new Date(t.started * 1000).toLocaleTimeString()}` : "");
  // changed null: the vehicle did not echo a write, and may hold it: Revert all writes it back
  $("tuning-revert").disabled = !canChange() || t.params.every((r) => r.changed === false);
  const table = $("tuning-table");
  if (!table.rows.length) {
    table.innerHTML = "<tr><th>parameter</th><th>current</th><th>pre-flight</th><th>bounds · max step</th></tr>";
  }
  for (const row of t.params) {
    let r = tuningRows[row.name];
    if (!r) r = tuningRows[row.name] = tuningRow(table, row);
    r.spec = row;
    const unknown = row.changed === null && row.current != null && row.preflight != null;
    r.current.textContent = unknown ? `? (${num(row.current)} before a write it did not echo)` : num(row.current);
    r.preflight.textContent = num(row.preflight);
    r.tr.classList.toggle("changed", row.changed !== false);
    if (row.current != null) {
      if (document.activeElement !== r.range) centre(r.range, row);
      if (document.activeElement !== r.number) r.number.value = num(row.current);
    }
  }
}

// The slider spans the largest step either side of the vehicle's value: it cannot ask for a write
// the profile refuses.
function centre(range, row) {
  const round = (x) => Number(x.toPrecision(6));  // float32 values: keep the slider grid clean
  const lo = round(Math.max(row.min, row.current - row.step)), hi = round(Math.min(row.max, row.current + row.step));
  Object.assign(range, { min: lo, max: hi, value: row.current });
}

function tuningRow(table, row) {
  const tr = table.insertRow(); tr.dataset.param = row.name; tr.className = "tune";
  tr.title = row.meaning;
  tr.innerHTML = `<td><b>${html(row.name)}</b><div class="hint">${html(row.meaning)}</div></td><td class="cur"></td><td class="pre"></td>`
    + `<td class="hint">[${num(row.min)} … ${num(row.max)}]<br>± ${num(row.step)} per write</td>`;
  const tr2 = table.insertRow(); tr2.className = "tune-edit"; tr2.dataset.param = row.name;
  tr2.innerHTML = `<td colspan="2"><input type="range" class="needs-token"></td>`
    + `<td><input type="number" class="needs-token"></td><td class="result"></td>`;
  const [range, number] = tr2.querySelectorAll("input");
  range.step = row.step / 20;
  range.dataset.param = number.dataset.param = row.name;
  Object.assign(number, { min: row.min, max: row.max, step: "any" });
  range.title = `the slider moves at most the largest step (${row.step}) from the current value`;
  range.addEventListener("input", () => { number.value = num(range.value); });
  range.addEventListener("change", () => queueWrite(row.name, Number(range.value)));
  // an emptied box (or one the browser could not read: "1e") is no value, not a write of 0
  number.addEventListener("change", () => {
    const r = tuningRows[row.name];
    if (number.value !== "") queueWrite(row.name, Number(number.value));
    else if (r.spec && r.spec.current != null) number.value = num(r.spec.current);
  });
  if (!canChange()) { range.disabled = number.disabled = true; }
  return { tr, tr2, range, number, current: tr.querySelector(".cur"), preflight: tr.querySelector(".pre"), result: tr2.querySelector(".result") };
}

const WRITE_RESULT = {
  409: ["mismatch", "the vehicle stored another value"],
  412: ["stale", "changed elsewhere"],
  422: ["refused", "refused"],
  429: ["ratelimited", "rate-limited"],
  504: ["timeout", "no answer from the vehicle"],
  401: ["refused", "not allowed"],
  404: ["refused", "unknown"],
};

// The keyboard's arrows fire `change` at every step of the slider: one write at a time, the newest
// value next, each once the per-parameter interval has passed since the last answer. Each step was
// a write of its own: six presses made six writes, five refused as rate-limited, and the vehicle
// kept the first.
async function queueWrite(name, value) {
  const r = tuningRows[name];
  const writing = r.wanted !== undefined;
  r.wanted = value;
  if (writing) return;
  while (r.wanted !== null) {
    const wait = (r.answeredAt ?? -Infinity) + 1000 * panelState.tuning.limits.per_param_interval_s - performance.now();
    if (wait > 0) await new Promise((done) => setTimeout(done, wait));
    const next = r.wanted;
    r.wanted = null;
    await writeParam(name, next);
    r.answeredAt = performance.now();
  }
  delete r.wanted;
}

async function writeParam(name, value) {
  const r = tuningRows[name];
  r.result.className = "result pending"; r.result.textContent = `writing ${num(value)}…`;
  // the value this write was chosen from: the server refuses it (412) if the gain holds another now
  // (another page's write this page had not yet shown), rather than put the old value back
  const res = await call("PUT", `/api/tuning/${encodeURIComponent(name)}`, { value, expected: r.spec?.current ?? null });
  let text, kind;
  if (res.ok) {
    kind = "verified";
    text = `✓ verified: ${num(res.data.old)} → ${num(res.data.new)} (pre-flight ${num(res.data.preflight)})`;
  } else {
    const [k, label] = WRITE_RESULT[res.status] || ["refused", `error ${res.status}`];
    kind = k; text = `✗ ${label}: ${res.message}`;
  }
  r.result.className = `result ${kind}`; r.result.textContent = text;
  r.tr2.dataset.result = kind;
  say("tuning-message", `${name}: ${text}`, kind === "verified" ? "ok" : "error");
  await refreshTuning();
  // Show what the vehicle holds now, not the value asked for (a refused value must not linger
  // in the box, to be sent again when the box loses focus); not while the slider has moved on.
  // The slider, focused since the click or the arrows that moved it, spans the steps from the new
  // value (it kept those from the old one: the next drag or arrow could go no further).
  if (r.spec && r.spec.current != null && r.wanted == null) { r.number.value = num(r.spec.current); centre(r.range, r.spec); }
}

async function revertAll() {
  const btn = $("tuning-revert"); btn.disabled = true;
  // a slider's value still waiting for its turn would be written after the revert, undoing it
  const dropped = [];
  for (const [name, r] of Object.entries(tuningRows)) {
    if (r.wanted != null) { dropped.push(`${name} = ${num(r.wanted)}`); r.wanted = null; }
  }
  const unsent = dropped.length ? `; not sent: ${dropped.join(", ")}` : "";
  say("tuning-message", "reverting every change to its pre-flight value…", "pending");
  const res = await call("POST", "/api/tuning/revert");
  if (res.ok) {
    const names = res.data.restored.map((p) => `${p.name} = ${num(p.value)}`);
    say("tuning-message", (names.length ? `✓ reverted and verified: ${names.join(", ")}` : "nothing to revert: every value is the pre-flight one") + unsent, "ok");
    for (const r of Object.values(tuningRows)) { r.result.textContent = ""; r.result.className = "result"; delete r.tr2.dataset.result; }
    showTuning({ ...panelState.tuning, params: res.data.params });
  } else {
    say("tuning-message", `✗ revert failed (${res.status}): ${res.message}${unsent}`, "error");
  }
  await refreshTuning();
}

// ---- recording -----------------------------------------------------------------------------
// Sessions a crash left open, closed at this start (recover_sessions' reports: {session, end, ...},
// or {session, error} for one that could not be, left as it was): named, and why not.
function recoveries(reports) {
  const done = reports.filter((r) => !r.error).map((r) => r.session);
  const failed = reports.filter((r) => r.error).map((r) => `${r.session} (${r.error})`);
  return (done.length ? ` · recovered after a crash: ${html(done.join(", "))}` : "")
    + (failed.length ? ` · <span class="low">not recovered: ${html(failed.join(", "))}</span>` : "");
}

async function refreshRecording() {
  const r = await call("GET", "/api/recording");
  if (!r.ok) return;
  const s = r.data;
  panelState.recording = s;
  const pill = $("rec-pill");
  pill.hidden = false;
  pill.textContent = s.state === "recording" ? "● REC" : `rec ${s.state}`;
  pill.className = `pill rec-${s.state}`;
  pill.title = s.folder || s.root || "";
  const flush = s.last_flush_age_s == null ? "" : ` · last flush ${fmt(s.last_flush_age_s, 1)} s ago`;
  $("rec-status").innerHTML = `<span class="pill rec-${html(s.state)}">${html(s.state)}</span> `
    + (s.state === "off" ? "this station runs without recording (--no-record)"
      : `${html(s.folder || `(no session open) in ${s.root}`)} · ${bytes(s.bytes_written)}${flush}`
        + ` · ${s.packets_received} packets received, ${s.packets_sent} sent`
        + (s.dropped ? ` · <span class="low">${s.dropped} dropped</span>` : "")
        + recoveries(s.recovered || []));
  const err = $("rec-error");
  err.hidden = !s.error; err.textContent = s.error ? `⚠ recording ${s.state}: ${s.error}` : "";
  $("panel-warnings").innerHTML = s.error ? `<div class="rec-failed">⚠ recording ${html(s.state)}: ${html(s.error)}</div>` : "";
  $("rec-start").disabled = !canChange() || s.state === "recording" || s.state === "off";
  $("rec-stop").disabled = !canChange() || s.state !== "recording";
}

async function recordingAction(path, body, done) {
  const res = await call("POST", path, body);
  say("rec-message", res.ok ? done : `✗ ${res.message}`, res.ok ? "ok" : "error");
  await refreshRecording();
  await refreshSessions();
  return res.ok;
}

// ---- sessions ------------------------------------------------------------------------------
// the export route's formats (gcs.sessions.export.FORMATS): [format, link text, what opens it]
const EXPORTS = [
  ["csv", "CSV", "attitude of every source, degrees"],
  ["parquet", "Parquet", "attitude of every source, degrees"],
  ["mat", "MAT", "MATLAB/Octave: one struct per source, errors, gain changes"],
  ["mcap", "MCAP", "Foxglove Studio, PlotJuggler: attitude, raw IMU, comparisons, events"],
];
async function refreshSessions() {
  const [s, l] = await Promise.all([call("GET", "/api/sessions"), call("GET", "/api/logs")]);
  if (!s.ok) { $("sessions-table").innerHTML = `<tr><td class="low">${html(s.message)}</td></tr>`; return; }
  panelState.sessions = s.data;
  const rows = s.data.slice().reverse().map((x) => {
    const start = x.start ? new Date(x.start * 1000).toLocaleString() : "?";
    const state = x.open ? "open" : x.recovered ? "recovered" : "";
    const q = encodeURIComponent(x.name);
    return `<tr data-session="${html(x.name)}"><td title="${html(x.name)}">${html(start)}${state ? ` <span class="hint">(${state})</span>` : ""}</td>`
      + `<td>${x.duration_s == null ? "–" : `${fmt(x.duration_s, 1)} s`}</td><td>${bytes(x.size_bytes)}</td><td>${html(x.vehicle || "–")}</td>`
      + `<td><a class="replay" href="replay.html?source=${q}" target="_blank">replay</a> ${EXPORTS.map(([f, label, title]) => `<a class="export-${f}" href="/api/sessions/${q}/export?format=${f}" title="${title}" download>${label}</a>`).join(" ")}</td></tr>`;
  });
  $("sessions-table").innerHTML = `<tr><th>start</th><th>duration</th><th>size</th><th>vehicle</th><th>export</th></tr>`
    + (rows.join("") || `<tr><td colspan="5" class="hint">no recorded sessions yet</td></tr>`);
  const logs = l.ok ? l.data : [];
  // a session by its start and vehicle: several vehicles' sessions start in the same second
  const options = [...s.data.slice().reverse().map((x) => ({ name: x.name, label: `session ${x.start ? new Date(x.start * 1000).toLocaleString() : x.name}${x.vehicle ? ` · ${x.vehicle}` : ""}` })),
    ...logs.map((x) => ({ name: x.name, label: `log ${x.name}` }))];
  for (const id of ["whatif-source"]) {
    const sel = $(id), keep = sel.value;
    sel.innerHTML = options.map((o) => `<option value="${html(o.name)}">${html(o.label)}</option>`).join("")
      || `<option value="">(nothing recorded yet)</option>`;
    if (options.some((o) => o.name === keep)) sel.value = keep;
  }
}

// ---- what-if -------------------------------------------------------------------------------
let estimatorInfo = [];
let whatifPlot = null;

function buildWhatifGains() {
  const est = estimatorInfo.find((e) => e.name === $("whatif-estimator").value);
  const box = $("whatif-gains");
  box.innerHTML = "";
  if (!est) return;
  for (const g of est.gains) {
    const row = document.createElement("div"); row.className = "gain";
    row.title = `${g.meaning}\n[${num(g.min)} … ${num(g.max)}] ${g.unit}; leave empty to keep the session's value`;
    row.innerHTML = `<label>${html(g.name)}</label><span class="hint">live ${num(g.value)}</span><input type="number" step="any"><span class="unit">${html(g.unit)}</span>`;
    const input = row.querySelector("input");
    Object.assign(input, { min: g.min, max: g.max, placeholder: num(g.value) });
    input.dataset.gain = g.name;
    box.appendChild(row);
  }
}

async function runWhatif() {
  const source = $("whatif-source").value, estimator = $("whatif-estimator").value, gains = {};
  for (const input of $("whatif-gains").querySelectorAll("input")) if (input.value !== "") gains[input.dataset.gain] = Number(input.value);
  if (!source) { say("whatif-message", "record a session first (or put a log in the recording folder)", "error"); return; }
  if (!Object.keys(gains).length) { say("whatif-message", "type at least one gain value to try", "error"); return; }
  say("whatif-message", `running ${estimator} over ${source} with ${JSON.stringify(gains)}…`, "pending");
  $("whatif-run").disabled = true;
  const res = await call("POST", "/api/whatif", { source, estimator, gains });
  $("whatif-run").disabled = false;
  if (!res.ok) { say("whatif-message", `✗ ${res.message}`, "error"); return; }
  panelState.whatif = res.data;
  say("whatif-message", `✓ ${estimator} with ${Object.entries(res.data.gains).map(([k, v]) => `${k} = ${v}`).join(", ")}: `
    + `${res.data.t.length} points plotted, new run in ${fmt(res.data.elapsed_s, 2)} s`, "ok");
  const cell = (o, n) => { const better = n < o - 1e-9, worse = n > o + 1e-9; return `<td>${fmt(o, 2)}</td><td class="${better ? "better" : worse ? "worse" : ""}">${fmt(n, 2)}</td>`; };
  $("whatif-table").innerHTML = `<tr><th rowspan="2">reference</th><th colspan="2">roll RMS °</th><th colspan="2">pitch RMS °</th><th colspan="2">yaw RMS °</th></tr>`
    + `<tr><th>old</th><th>new</th><th>old</th><th>new</th><th>old</th><th>new</th></tr>`
    + res.data.table.map((r) => `<tr data-reference="${html(r.reference)}"><td>${html(r.reference)}</td>${[0, 1, 2].map((k) => cell(r.old_rms[k], r.new_rms[k])).join("")}</tr>`).join("");
  drawWhatif();
}

function drawWhatif() {
  const w = panelState.whatif, box = $("whatif-plot");
  if (!w) return;
  const axis = $("whatif-axis").value;
  const data = [w.t, w.old[axis], w.new[axis]];
  if (whatifPlot) whatifPlot.destroy();
  box.innerHTML = "";
  whatifPlot = new uPlot({
    width: Math.max(300, box.clientWidth || 410), height: 200, title: `${w.estimator} ${axis}: old gains vs new`,
    scales: { x: { time: false } }, legend: { live: true },
    series: [{ label: "t (s)", value: (u, v) => v == null ? "–" : v.toFixed(2) },
      { label: "old", stroke: "#999", width: 1, points: { show: false }, value: (u, v) => v == null ? "–" : v.toFixed(2) + "°" },
      { label: "new", stroke: COLORS[w.estimator] || "#d62728", width: 1.5, points: { show: false }, value: (u, v) => v == null ? "–" : v.toFixed(2) + "°" }],
    axes: [{}, { size: 50, values: (u, ticks) => ticks.map((t) => t + "°") }],
  }, data, box);
}

// ---- test protocol (/api/protocol) ------------------------------------------------------------
async function refreshProtocol() {
  const r = await call("GET", "/api/protocol");
  if (!r.ok) { say("protocol-message", `protocol: ${r.message}`, "error"); return; }
  const select = $("protocol-name");
  if (!select.options.length) select.innerHTML = r.data.available.map((n) => `<option>${html(n)}</option>`).join("");
  showProtocol(r.data.run);
}

function showProtocol(run) {
  panelState.protocol = run;
  // skip, repeat and stop act on a run in progress: with none they could only be refused
  for (const id of ["protocol-skip", "protocol-repeat", "protocol-stop"]) $(id).disabled = !run?.running || !canChange();
  if (!run) { $("protocol-prompt").textContent = "no protocol run yet"; return; }
  const s = run.state;
  $("protocol-prompt").textContent = run.running ? `Step ${s.step + 1}: ${s.prompt}` : s.finished ? "protocol finished" : "protocol stopped";
  $("protocol-progress").max = s.steps; $("protocol-progress").value = s.completed;
  $("protocol-step").textContent = `${s.protocol}: ${s.completed} of ${s.steps} steps done, ${s.skipped} skipped`
    + `${s.attempt > 1 && run.running ? `, attempt ${s.attempt}` : ""}; holds seen by ${run.detect_source}`;
  const sources = [...new Set(run.results.map((m) => m.source))];
  const steps = [...new Set(run.results.map((m) => m.step))];
  const cell = new Map(run.results.map((m) => [`${m.step}/${m.source}`, m]));
  $("protocol-table").innerHTML = !steps.length ? "" : `<tr><th>step</th>${sources.map((s) => `<th>${html(s)}</th>`).join("")}</tr>`
    + steps.map((k) => {
      const label = cell.get(`${k}/${sources.find((s) => cell.has(`${k}/${s}`))}`).label;
      return `<tr data-step="${k}"><td>${html(label)}</td>${sources.map((s) => `<td>${pct(cell.get(`${k}/${s}`)?.mre_last_pct)}</td>`).join("")}</tr>`;
    }).join("");
}

const pct = (x) => x == null ? "–" : Number(x).toFixed(2);

async function protocolAction(path, body) {
  const r = await call("POST", path, body);
  if (!r.ok) { say("protocol-message", r.message, "error"); return; }
  say("protocol-message", "");
  showProtocol(r.data.run);
}

// ---- start ---------------------------------------------------------------------------------
function canChange() { return panelState.authorised; }

function readOnly() {
  for (const el of document.querySelectorAll(".needs-token")) el.disabled = true;
  for (const el of document.querySelectorAll(".readonly-note")) el.hidden = false;
}

async function initPanels() {
  for (const b of document.querySelectorAll("#tabs button")) b.addEventListener("click", () => showTab(b.dataset.tab));
  const st = await call("GET", "/api/status");
  panelState.authorised = st.ok && st.data.authorised;
  if (!canChange()) readOnly();
  // A server restarted under the page with another token (gcs serve without --token makes a new
  // one): this page's cookie no longer allows changes, so its controls say so instead of each
  // click being refused.
  document.addEventListener("gcs:status", (e) => { if (canChange() && !e.detail.authorised) { panelState.authorised = false; readOnly(); } });
  $("param-download-btn").addEventListener("click", startDownload);
  $("tuning-revert").addEventListener("click", revertAll);
  $("tuning-refresh").addEventListener("click", refreshTuning);
  // a tuned gain's new value, whoever wrote it (pushed over /ws/live by dashboard.js): shown now,
  // not at the next poll, so that a slider here moves from it
  const tuningNow = andAgain(refreshTuning);
  document.addEventListener("gcs:param", (e) => { if (panelState.tab === "tuning" && tuningRows[e.detail.name]) tuningNow(); });
  $("rec-start").addEventListener("click", () => recordingAction("/api/recording/start", undefined, "recording started"));
  $("rec-stop").addEventListener("click", () => recordingAction("/api/recording/stop", undefined, "recording stopped; the session is in the list below"));
  $("rec-note-btn").addEventListener("click", async () => {
    const text = $("rec-note").value.trim();
    if (!text) { say("rec-message", "type a note first", "error"); return; }
    if (await recordingAction("/api/recording/note", { text }, `note added: “${text}”`)) $("rec-note").value = "";
  });
  $("sessions-refresh").addEventListener("click", refreshSessions);
  const est = await call("GET", "/api/estimators");
  estimatorInfo = est.ok ? est.data : [];
  $("whatif-estimator").innerHTML = estimatorInfo.map((e) => `<option>${html(e.name)}</option>`).join("");
  $("whatif-estimator").addEventListener("change", buildWhatifGains);
  buildWhatifGains();
  $("whatif-run").addEventListener("click", runWhatif);
  $("whatif-axis").addEventListener("change", drawWhatif);
  $("protocol-start").addEventListener("click", () => protocolAction("/api/protocol/start",
    { name: $("protocol-name").value, detect_source: $("protocol-detect").value.trim() || null }));
  $("protocol-skip").addEventListener("click", () => protocolAction("/api/protocol/skip"));
  $("protocol-repeat").addEventListener("click", () => protocolAction("/api/protocol/repeat"));
  $("protocol-stop").addEventListener("click", () => protocolAction("/api/protocol/stop"));
  const protocolPoll = oneAtATime(refreshProtocol), recordingPoll = oneAtATime(refreshRecording);
  const tuningPoll = oneAtATime(refreshTuning);
  setInterval(() => { if (panelState.tab === "protocol" || panelState.protocol?.running) protocolPoll(); }, 1000);
  refreshRecording(); refreshSessions();
  setInterval(recordingPoll, 2000);
  setInterval(() => { if (panelState.tab === "tuning" && !downloadPoll) tuningPoll(); }, 5000);
}

initPanels();
