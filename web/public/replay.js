// The replay view: one recorded session or log through the estimators, beside the live page and
// never in it. GET /api/replay computes the whole replay in the server's worker process (the live
// link never waits on it); this page then plays it by itself: play, pause, speed and seek move a
// cursor over the data it holds, so nothing of it reaches the live plots or any other viewer.
// URL: /replay.html?source=NAME[&estimator=E ...][&gain=EST.NAME=VALUE ...]
"use strict";

const $ = (id) => document.getElementById(id);
// For tests and the curious: state, cursor and samples handed to the plots per source.
const gcsReplay = (window.gcsReplay = { state: "idle", position: 0, duration: 0, added: {}, error: null });

// ---- the plots: plots.js's public API, used here and nowhere else in this file --------------
const chart = {
  create: (parent, estimators) => new Plots(parent, estimators),
  add: (plots, source, cols) => plots.add(source, cols),
  clear: (plots) => plots.restart(),
  setWindow: (plots, seconds) => plots.setWindow(seconds),
};

// ---- playing -------------------------------------------------------------------------------
// Each sample's play time (column PLAY, the server's PlayClock): its vehicle time, with every boot
// of a vehicle that rebooted after the one before, not from 0 again under it. Samples are handed to
// the plots boot by boot (`boots`: the play time each starts at), every source's samples of one boot
// before any of the next: the plots restart at a clock that went back, clearing every source, so
// one source's new boot must not come before another's old one (which would clear it).
const PLAY = 4;
class Player {
  constructor(replay) {
    this.replay = replay;
    this.series = Object.entries(replay.points).filter(([, cols]) => cols[0].length);
    this.t0 = Math.min(...this.series.map(([, c]) => c[PLAY][0]));
    const t1 = Math.max(...this.series.map(([, c]) => c[PLAY][c[PLAY].length - 1]));
    this.duration = Number.isFinite(t1 - this.t0) ? t1 - this.t0 : 0;
    this.boots = replay.boots.length ? replay.boots : [this.t0];
    this.plots = chart.create($("charts"), replay.estimators);
    this.next = {};  // source -> index of the first sample not yet given to the plots
    this.position = 0; this.playing = false; this.speed = 1; this.last = null;
    this.rewind();
    requestAnimationFrame((ts) => this.tick(ts));
  }
  rewind() {
    chart.clear(this.plots);
    for (const [s] of this.series) { this.next[s] = 0; gcsReplay.added[s] = 0; }
    this.position = 0; this.boot = 0;
  }
  // Hand the plots every sample up to `position` seconds from the start, boot by boot.
  advanceTo(position) {
    this.position = Math.min(Math.max(0, position), this.duration);
    const tEnd = this.t0 + this.position;
    for (;;) {
      const next = this.boot + 1 < this.boots.length ? this.boots[this.boot + 1] : Infinity;
      for (const [source, cols] of this.series) {
        const play = cols[PLAY], i = this.next[source];
        let j = i;
        while (j < play.length && play[j] <= tEnd && play[j] < next) j++;
        if (j > i) {
          chart.add(this.plots, source, cols.map((c) => c.slice(i, j)));
          gcsReplay.added[source] += j - i;
          this.next[source] = j;
        }
      }
      if (next > tEnd) break;
      this.boot++;
    }
    this.show();
  }
  seek(position) {
    if (position < this.position) this.rewind();
    this.advanceTo(position);
  }
  play() {
    if (this.position >= this.duration) this.rewind();
    this.playing = true; this.last = null;
    if (this.speed === 0) { this.advanceTo(this.duration); this.playing = false; }
    this.show();
  }
  pause() { this.playing = false; this.show(); }
  tick(ts) {
    if (this.playing) {
      if (this.last !== null) this.advanceTo(this.position + ((ts - this.last) / 1000) * this.speed);
      this.last = ts;
      if (this.position >= this.duration) this.playing = false;
    } else this.last = null;
    requestAnimationFrame((t) => this.tick(t));
  }
  show() {
    gcsReplay.position = this.position;
    gcsReplay.state = this.playing ? "playing" : this.position >= this.duration ? "finished" : "paused";
    $("replay-play").textContent = this.playing ? "pause" : "play";
    const seek = $("replay-seek");
    if (document.activeElement !== seek) seek.value = this.position;
    $("replay-position").textContent = `${this.position.toFixed(1)} / ${this.duration.toFixed(1)} s · ${gcsReplay.state}`;
  }
}

// ---- loading -------------------------------------------------------------------------------
function say(text, kind = "") { const el = $("replay-message"); el.textContent = text; el.className = `message ${kind}`; }
const fmt = (x) => x == null ? "–" : String(+Number(x).toFixed(2));

function showTable(rows) {
  $("replay-table").innerHTML = `<tr><th>estimator</th><th>reference</th><th>n</th><th>RMS roll / pitch / yaw (°)</th><th>max roll / pitch / yaw (°)</th></tr>`
    + rows.map((r) => `<tr data-estimator="${r.estimator}" data-reference="${r.reference}"><td>${r.estimator}</td><td>${r.reference}</td><td>${r.n}</td>`
      + `<td>${r.rms_deg.map(fmt).join(" / ")}</td><td>${r.max_deg.map(fmt).join(" / ")}</td></tr>`).join("");
}

async function listSources(selected) {
  const [s, l] = await Promise.all([fetch("/api/sessions"), fetch("/api/logs")].map((p) => p.then((r) => r.ok ? r.json() : [])));
  const names = [...s.slice().reverse().map((x) => [x.name, `session ${x.start ? new Date(x.start * 1000).toLocaleString() : x.name}`]),
    ...l.map((x) => [x.name, `log ${x.name}`])];
  const sel = $("replay-source");
  sel.innerHTML = names.map(([n, label]) => `<option value="${encodeURIComponent(n)}">${label.replace(/[&<>"]/g, "")}</option>`).join("")
    || `<option value="">(nothing recorded yet)</option>`;
  if (selected) sel.value = encodeURIComponent(selected);
}

async function load(params) {
  const source = params.get("source");
  $("replay-title").textContent = `${source}: computing the replay in the worker process…`;
  gcsReplay.state = "loading";
  const res = await fetch(`/api/replay?${params}`);
  const { data: body, message } = await readAnswer(res);
  if (!res.ok) {
    gcsReplay.state = "error"; gcsReplay.error = message;
    $("replay-title").textContent = source; say(`✗ ${gcsReplay.error}`, "error");
    return;
  }
  const player = (window.gcsPlayer = new Player(body));
  gcsReplay.duration = player.duration;
  $("replay-title").textContent = `${body.kind} ${body.source}: ${body.duration_s.toFixed(1)} s, ${body.imu_samples} IMU samples`
    + (body.damage ? ` · damage: ${body.damage}` : "");
  const seek = $("replay-seek");
  seek.max = Math.max(0.1, player.duration); seek.disabled = false; $("replay-play").disabled = false;
  seek.addEventListener("change", () => player.seek(Number(seek.value)));
  $("replay-play").addEventListener("click", () => player.playing ? player.pause() : player.play());
  $("replay-speed").addEventListener("change", (ev) => { player.speed = Number(ev.target.value); if (player.playing) player.play(); });
  $("window").addEventListener("change", (ev) => chart.setWindow(player.plots, Number(ev.target.value)));
  showTable(body.table);
  player.speed = Number($("replay-speed").value);
  player.play();
}

function main() {
  const params = new URLSearchParams(location.search);
  listSources(params.get("source"));
  $("replay-open").addEventListener("click", () => {
    const name = decodeURIComponent($("replay-source").value);
    if (name) location.search = `?source=${encodeURIComponent(name)}`;
  });
  if (params.get("source")) load(params);
}

main();
