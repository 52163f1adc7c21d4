// Live attitude plots: every received sample is kept (last 10 minutes per source); each frame
// draws the visible window reduced to min and max per pixel column, so a one-sample spike is
// never hidden, at any window length. Columns sit on an absolute time grid, so a live view only
// bins the samples that arrived since the previous frame.
// History (GET /api/history) is merged in, never a reason to start again: every sample fills a gap
// (a page opened late, a reconnect), min/max columns of a long window fill only what lies before the
// first sample this page holds one by one. Error traces over history come from the server (the same
// rule as ErrorSeries). Only the vehicle clock going back in a live frame (a reboot) restarts the
// plots, and the page says so. Yaw lines never cross the ±180° wrap.
"use strict";

const KEEP_S = 620;           // seconds of samples kept per source (10 min window + margin)
const AXES = ["roll", "pitch", "yaw"];
const REFERENCES = ["onboard", "ahrs2", "truth"];
const ERROR_REFERENCES = ["onboard", "truth"];
const COLORS = window.GCS_COLORS;  // from the server (gcs/server/colors.py), shared with the 3-D view
const DASH = { onboard: [], truth: [6, 3] };

// A time series: t and [roll, pitch, yaw] arrays; `base` counts samples trimmed from the front,
// so absolute index i lives at i - base. Samples before `rawFrom` are min/max columns of a long
// history; from `rawFrom` on, every sample.
class Series {
  constructor() { this.clear(); }
  clear() { this.t = []; this.v = [[], [], []]; this.base = 0; this.rawFrom = Infinity; }
  get end() { return this.base + this.t.length; }
  last() { return this.t.length ? this.t[this.t.length - 1] : -Infinity; }
  push(t, r, p, y) {
    if (this.rawFrom === Infinity) this.rawFrom = t;
    this.t.push(t); this.v[0].push(r); this.v[1].push(p); this.v[2].push(y);
  }
  trim(t0) {
    let n = 0; while (n < this.t.length && this.t[n] < t0) n++;
    if (n > 1000 || (n && n === this.t.length)) {
      this.t.splice(0, n); for (const a of this.v) a.splice(0, n); this.base += n;
    }
  }
  firstAtOrAfter(t) {  // absolute index of the first sample with time >= t
    let lo = 0, hi = this.t.length;
    while (lo < hi) { const m = (lo + hi) >> 1; if (this.t[m] < t) lo = m + 1; else hi = m; }
    return lo + this.base;
  }
  count(t0, t1) { return this.firstAtOrAfter(t1 + 1e-9) - this.firstAtOrAfter(t0); }
  // Every-sample history [[t...],[r...],[p...],[y...]]: the union by time with what is held (a
  // sample already held is not doubled); it replaces min/max columns from its first sample on.
  mergeRaw(cols) {
    const [ht] = cols;
    if (!ht.length) return;
    const from = Math.min(this.rawFrom, ht[0]);
    const out = [[], [], [], []];
    let i = 0, j = 0;
    const take = (src, k) => { for (let a = 0; a < 4; a++) out[a].push(src[a][k]); };
    const mine = [this.t, ...this.v];
    while (i < this.t.length && this.t[i] < this.rawFrom && this.t[i] < from) take(mine, i++);  // older columns
    while (i < this.t.length && this.t[i] < this.rawFrom) i++;  // columns the samples replace
    while (i < this.t.length || j < ht.length) {
      if (j >= ht.length || (i < this.t.length && this.t[i] <= ht[j])) {
        if (j < ht.length && Math.abs(this.t[i] - ht[j]) < 1e-6) j++;
        take(mine, i++);
      } else take(cols, j++);
    }
    this.replace(out, from);
  }
  // Min/max-column history: it replaces the columns held from its first one on, and fills only
  // what lies before the first sample held one by one.
  mergeColumns(cols) {
    const [ht] = cols, out = [[], [], [], []], from = Math.min(ht.length ? ht[0] : Infinity, this.rawFrom);
    const mine = [this.t, ...this.v], take = (src, k) => { for (let a = 0; a < 4; a++) out[a].push(src[a][k]); };
    for (let i = 0; i < this.t.length && this.t[i] < from; i++) take(mine, i);  // older columns
    for (let j = 0; j < ht.length && ht[j] < this.rawFrom; j++) take(cols, j);
    for (let i = this.firstAtOrAfter(this.rawFrom) - this.base; i < this.t.length; i++) take(mine, i);
    this.replace(out, this.rawFrom);
  }
  replace(cols, rawFrom) { this.t = cols[0]; this.v = cols.slice(1); this.rawFrom = rawFrom; }
}

const wrap180 = (d) => ((d + 540) % 360) - 180;

// Errors estimator − reference at each reference time, the estimator interpolated there (the
// same scoring as gcs.estimators.compare), computed as soon as the estimator has passed it.
class ErrorSeries extends Series {
  constructor(est, ref) { super(); this.est = est; this.ref = ref; this.next = 0; }
  // After history was merged: carry on from the reference sample after the last error held.
  resync() { this.next = this.ref.firstAtOrAfter(this.last() + 1e-9); }
  update() {
    const est = this.est, ref = this.ref;
    if (!est.t.length) return;
    // never over min/max columns (their errors come with the history), nor before the estimator starts
    this.next = Math.max(this.next, ref.base, ref.firstAtOrAfter(Math.max(ref.rawFrom, est.rawFrom, est.t[0])));
    const tEst = est.last();
    while (this.next < ref.end) {
      const i = this.next - ref.base, t = ref.t[i];
      if (t > tEst) break;
      const k = est.firstAtOrAfter(t) - est.base;
      const e = [0, 0, 0];
      for (let a = 0; a < 3; a++) {
        let v = est.v[a][k];
        if (est.t[k] > t && k > 0) {
          const u = (t - est.t[k - 1]) / (est.t[k] - est.t[k - 1]);
          v = est.v[a][k - 1] + u * wrap180(est.v[a][k] - est.v[a][k - 1]);
        }
        e[a] = wrap180(v - ref.v[a][i]);
      }
      this.push(t, e[0], e[1], e[2]);
      this.next++;
    }
  }
}

// Min and max of one series axis per column of width dt on an absolute grid (column c covers
// [c*dt, (c+1)*dt)), in a ring of `size` columns; fed incrementally.
class Binner {
  constructor(series, axis, size) {
    this.series = series; this.axis = axis; this.size = size;
    this.col = new Float64Array(size).fill(NaN); this.mn = new Float64Array(size); this.mx = new Float64Array(size);
    this.minFirst = new Uint8Array(size); this.dt = 0; this.done = 0;
  }
  reset(dt, t0) {
    this.dt = dt; this.col.fill(NaN); this.done = this.series.firstAtOrAfter(t0 - dt);
  }
  update(t1) {
    const s = this.series, vals = s.v[this.axis];
    this.done = Math.max(this.done, s.base);
    while (this.done < s.end) {
      const i = this.done - s.base, t = s.t[i];
      if (t > t1) break;
      const c = Math.floor(t / this.dt), j = ((c % this.size) + this.size) % this.size, v = vals[i];
      if (this.col[j] !== c) { this.col[j] = c; this.mn[j] = v; this.mx[j] = v; this.minFirst[j] = 1; }
      else if (v < this.mn[j]) { this.mn[j] = v; this.minFirst[j] = 0; }
      else if (v > this.mx[j]) { this.mx[j] = v; this.minFirst[j] = 1; }
      this.done++;
    }
  }
  fill(c0, ncols, out) {  // two values per column, min and max in the order they happened
    for (let k = 0; k < ncols; k++) {
      const c = c0 + k, j = ((c % this.size) + this.size) % this.size;
      if (this.col[j] === c) {
        out[2 * k] = this.minFirst[j] ? this.mn[j] : this.mx[j];
        out[2 * k + 1] = this.minFirst[j] ? this.mx[j] : this.mn[j];
      } else { out[2 * k] = null; out[2 * k + 1] = null; }
    }
  }
}

// Pixel spans between consecutive drawn points of a yaw line that jump by more than 180°: the
// angle wrapped (±180°), it did not swing across the chart, so no line is drawn there. The gap
// runs past each point by the line's half-width and a pixel of antialiasing (canvas pixels: a
// CSS pixel is devicePixelRatio of them): one between the points would be empty for points a
// pixel or two apart (a min/max column's two, or neighbouring columns), and the wrap drawn as a
// bar; for points further apart the steep line's first and last pixels were still drawn.
// uPlot asks for gaps only of a series that does not span its nulls (spanGaps false); the nulls
// (columns where a source has no sample) are spanned here all the same: their gaps are not kept.
function wrapGaps(u, si, i0, i1, _nullGaps) {
  const xs = u.data[0], ys = u.data[si], gaps = [], pad = Math.ceil(devicePixelRatio);
  let prev = -1;
  for (let i = i0; i <= i1; i++) {
    if (ys[i] == null) continue;
    if (prev >= 0 && Math.abs(ys[i] - ys[prev]) > 180) {
      const from = u.valToPos(xs[prev], "x", true), to = u.valToPos(xs[i], "x", true);
      gaps.push([Math.floor(from) - pad, Math.ceil(to) + pad]);
    }
    prev = i;
  }
  return gaps.sort((a, b) => a[0] - b[0]);
}

// One uPlot chart of one axis for a list of series. No uPlot legend (it took half of each
// chart's height): the colours are the table's, and the values under the cursor are one line in
// the chart's title.
class Chart {
  constructor(parent, title, lines, axis, hooks, height) {
    this.lines = lines; this.axis = axis; this.key = "";
    const box = document.createElement("div"); box.className = "chart";
    const h3 = document.createElement("h3"); h3.textContent = title;
    this.readout = document.createElement("span"); this.readout.className = "readout";
    h3.appendChild(this.readout); box.appendChild(h3); parent.appendChild(box);
    this.box = box;
    const opts = {
      width: this.widthFor(), height,
      scales: { x: { time: false } },
      cursor: { sync: { key: "gcs" }, drag: { x: true, y: false, setScale: false } },
      legend: { show: false },
      series: [{}, ...lines.map((l) => ({ label: l.label, stroke: l.color, width: 1, dash: l.dash || [], spanGaps: axis !== 2,
                                           gaps: axis === 2 ? wrapGaps : undefined, points: { show: false } }))],
      axes: [{ size: 22 }, { size: 46, values: (u, ticks) => ticks.map((t) => t + "°") }],
      hooks: { setSelect: [(u) => hooks.select(u)], setCursor: [(u) => this.showCursor(u)] },
    };
    this.u = new uPlot(opts, [[], ...lines.map(() => [])], box);
    this.u.over.addEventListener("dblclick", hooks.live);
    this.binners = lines.map((l) => new Binner(l.series, axis, 8192));
  }
  // The values under the cursor: "t 12.34 s  onboard 17.39°  dcm 17.46° ...", each in its colour.
  showCursor(u) {
    const i = u.cursor.idx, parts = [];
    if (i != null && u.data[0][i] != null) {
      parts.push(`t ${u.data[0][i].toFixed(2)} s`);
      this.lines.forEach((l, k) => {
        const v = u.data[k + 1][i];
        if (v == null) return;
        const span = document.createElement("span"); span.style.color = l.color;
        span.textContent = `${l.label} ${v.toFixed(2)}°`; parts.push(span);
      });
    }
    this.readout.replaceChildren(...parts.flatMap((x, k) => (k ? [" ", x] : [x])));
  }
  widthFor() { return Math.max(150, this.box.clientWidth - 2); }
  draw(t0, t1, live) {
    const ncols = Math.max(50, Math.round(this.u.bbox.width / devicePixelRatio)), dt = (t1 - t0) / ncols;
    const key = `${dt}|${live ? "" : t0}`;
    if (key !== this.key) { this.key = key; for (const b of this.binners) b.reset(dt, t0); }
    const c0 = Math.floor(t0 / dt), n = Math.floor(t1 / dt) - c0 + 1;
    const xs = new Float64Array(2 * n);
    for (let k = 0; k < n; k++) { xs[2 * k] = (c0 + k + 0.25) * dt; xs[2 * k + 1] = (c0 + k + 0.75) * dt; }
    const data = [xs];
    for (const b of this.binners) { b.update(t1); const ys = new Array(2 * n); b.fill(c0, n, ys); data.push(ys); }
    this.u.batch(() => { this.u.setData(data); this.u.setScale("x", { min: t0, max: t1 }); });
  }
  resize(height) { this.u.setSize({ width: this.widthFor(), height }); this.key = ""; }
}

// Everything the page plots: the sources, the error series, six charts and the draw loop.
class Plots {
  // A phone's one column of charts scrolls, 140 px each. Wider, the three rows share the height the
  // window has left under everything above them, as laid out (`fit`): a warning or a reboot note
  // above takes its lines from the charts rather than pushing the yaw row off screen (at 1366×768
  // it did, with one line); 90 to 220 px each.
  static NARROW = 1100;
  constructor(parent, estimators, onRestart) {
    this.parent = parent; this.estimators = estimators; this.onRestart = onRestart || (() => {});
    this.sources = {}; this.errors = [];
    for (const s of [...REFERENCES, ...estimators]) this.sources[s] = new Series();
    for (const e of estimators) for (const r of ERROR_REFERENCES)
      this.errors.push({ name: `${e} − ${r}`, e, r, series: new ErrorSeries(this.sources[e], this.sources[r]) });
    this.window = 30; this.paused = false; this.view = null;  // view: {t0, t1} when zoomed or paused
    this.dirty = true; this.frames = 0; this.draws = 0; this.fps = 0; this.nextDraw = 0;
    this.restarts = [];
    this.height = 140;  // until the first `fit`, which the observer below calls when it starts
    this.build();
    addEventListener("resize", () => this.fit(true));
    const above = new ResizeObserver(() => this.fit(false));
    for (let el = parent; el && el !== document.body; el = el.parentElement)
      for (let s = el.previousElementSibling; s; s = s.previousElementSibling) above.observe(s);
    requestAnimationFrame((ts) => this.frame(ts));
    setInterval(() => { this.fps = this.frames; this.frames = 0; this.trim(); }, 1000);
  }
  // Each chart's height for the room left (see NARROW); every chart again when the window resized.
  fit(resized) {
    let height = 140;
    if (innerWidth > Plots.NARROW) {
      const bottom = Math.max(...this.charts.map((c) => c.box.getBoundingClientRect().bottom)) + scrollY;
      height = Math.max(90, Math.min(220, this.height + Math.floor((innerHeight - 1 - bottom) / 3)));
    }
    if (height === this.height && !resized) return;
    this.height = height;
    for (const c of this.charts) c.resize(height);
    this.dirty = true;
  }
  build() {
    this.parent.innerHTML = "";
    const hooks = { select: (u) => this.zoom(u), live: () => this.goLive() };
    const srcLines = Object.keys(this.sources).map((s) => ({ label: s, color: COLORS[s] || "#888", dash: DASH[s], series: this.sources[s] }));
    const errLines = this.errors.map((x) => ({ label: x.name, color: COLORS[x.e] || "#888", dash: x.r === "truth" ? [6, 3] : [], series: x.series }));
    this.charts = [
      ...AXES.map((a, i) => new Chart(this.parent, `${a} (°)`, srcLines, i, hooks, this.height)),
      ...AXES.map((a, i) => new Chart(this.parent, `${a} error (°): solid − onboard, dashed − truth`, errLines, i, hooks, this.height)),
    ];
  }
  newest() { let t = -Infinity; for (const s of Object.values(this.sources)) t = Math.max(t, s.last()); return t; }
  // Append live samples [[t...],[r...],[p...],[y...]] of a source; returns how many were new.
  add(source, cols) {
    let s = this.sources[source];
    if (!s) return 0;
    const [ts, r, p, y] = cols;
    let n = 0;
    for (let i = 0; i < ts.length; i++) {
      if (ts[i] <= s.last()) {
        if (ts[i] < s.last() - 5) { this.restart(s.last(), ts[i]); } else continue;  // vehicle clock went back: reboot
      }
      s.push(ts[i], r[i], p[i], y[i]); n++;
    }
    if (n) this.dirty = true;
    return n;
  }
  // Merge a GET /api/history answer: sources and errors, in place (the charts keep their series).
  load(h) {
    const merge = (series, cols) => { if (series && cols) (h.resolution_s ? series.mergeColumns(cols) : series.mergeRaw(cols)); };
    for (const [source, cols] of Object.entries(h.points)) merge(this.sources[source], cols);
    for (const x of this.errors) merge(x.series, (h.errors || {})[`${x.e}|${x.r}`]);
    for (const x of this.errors) x.series.resync();
    for (const c of this.charts) c.key = "";  // indices moved: bin again
    this.dirty = true;
  }
  restart(from, to) {  // the vehicle rebooted: start every series afresh, and say so
    for (const s of Object.values(this.sources)) s.clear();
    for (const x of this.errors) { x.series.clear(); x.series.next = 0; }
    for (const c of this.charts) c.key = "";
    this.restarts.push({ at: new Date(), from, to });
    this.onRestart(this.restarts[this.restarts.length - 1]);
  }
  trim() { const t0 = this.newest() - KEEP_S; for (const s of [...Object.values(this.sources), ...this.errors.map((x) => x.series)]) s.trim(t0); }
  zoom(u) {
    if (u.select.width < 3) return;
    const t0 = u.posToVal(u.select.left, "x"), t1 = u.posToVal(u.select.left + u.select.width, "x");
    u.setSelect({ left: 0, width: 0, top: 0, height: 0 }, false);
    this.view = { t0, t1 }; this.dirty = true;
    document.getElementById("pause").textContent = "live";  // it said "pause" over a view already held
  }
  goLive() { this.view = null; this.paused = false; this.dirty = true; document.getElementById("pause").textContent = "pause"; }
  togglePause() {
    if (this.paused || this.view) { this.goLive(); return; }
    const t1 = this.newest(); this.view = { t0: t1 - this.window, t1 }; this.paused = true;
    document.getElementById("pause").textContent = "live";
  }
  setWindow(seconds) { this.window = seconds; if (this.view && this.paused) this.view.t0 = this.view.t1 - seconds; this.dirty = true; }
  // Drawing takes at most about half of the page's main thread: after a draw, the next waits the
  // draw's own JavaScript time (binning and uPlot's setData/paint of six canvases). On a slow or
  // loaded machine the plots draw less often while the WebSocket frames, the status poll and the
  // controls still get their turn (nothing is skipped: the next draw shows every sample that
  // arrived meanwhile). Only the draw's own time counts, not the time to the next animation frame.
  // Twice the draw's time (a third of the thread) held a 7 ms draw to every third animation frame
  // on a loaded machine, 17 redraws/s, with the main thread 80 % idle (bench.page_fps).
  frame() {
    const now = performance.now();
    if (this.dirty && now >= this.nextDraw) {
      this.dirty = false;
      for (const x of this.errors) x.series.update();
      const live = !this.view, t1 = live ? this.newest() : this.view.t1, t0 = live ? t1 - this.window : this.view.t0;
      if (Number.isFinite(t1)) { for (const c of this.charts) c.draw(t0, t1, live); this.frames++; this.draws++; }
      const end = performance.now();
      this.nextDraw = end + (end - now);
    }
    requestAnimationFrame((ts) => this.frame(ts));
  }
}
