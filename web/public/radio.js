// The telemetry radio's budget under the stream table (Live tab), from GET /api/status: the radio's
// signal and free buffer, what the link carries, and per stream the wanted, predicted (to fit),
// requested and achieved rates with their cost. Hidden until a radio reports (RADIO_STATUS), or
// while RADIO_STATUS comes only from components that are not a radio (then a line says so). Drawn
// from the status dashboard.js polls (its "gcs:status" event): a second poll would double a page's
// load on the server (issue 17). Uses $ and escapeHtml from dashboard.js.
"use strict";

(() => {
  const section = document.createElement("section");
  section.id = "radio";
  section.hidden = true;
  $("streams").insertAdjacentElement("afterend", section);
  const hz = (x) => Number(x).toFixed(1);

  function show(radio) {
    section.hidden = !(radio && ((radio.present && radio.status) || radio.ignored_status));
    if (section.hidden) return;
    if (!(radio.present && radio.status)) {
      section.innerHTML = `<h2>Radio</h2><p class="hint">no radio: ${radio.ignored_status} RADIO_STATUS `
        + "from components other than a telemetry radio's (68) ignored; no rate is capped</p>";
      return;
    }
    const s = radio.status;
    const rows = Object.entries(radio.streams).map(([name, x]) =>
      `<tr><td>${escapeHtml(name)}</td><td>${hz(x.wanted_hz)}</td><td>${hz(x.predicted_hz)}</td>`
      + `<td>${hz(x.requested_hz)}</td><td>${hz(x.achieved_hz)}</td><td>${Math.round(x.cost_bps)}</td></tr>`);
    section.innerHTML = `<h2>Radio</h2><p class="hint">rssi ${s.rssi}/${s.remrssi}, noise ${s.noise}/${s.remnoise}, `
      + `txbuf ${s.txbuf} % free; ${Math.round(radio.used_bps)} of ${Math.round(radio.capacity_bps)} B/s used`
      + (radio.shared_by > 1 ? ` (shared by ${radio.shared_by} vehicles: this one plans on ${Math.round(radio.budget_bps)})` : "")
      + `. `
      + (radio.ignored_status ? `${radio.ignored_status} RADIO_STATUS from other components ignored. ` : "")
      + `${escapeHtml(radio.choice)}</p><table><tr><th>stream</th><th>wanted</th><th>predicted</th>`
      + `<th>requested</th><th>achieved Hz</th><th>B/s</th></tr>${rows.join("")}</table>`;
  }

  document.addEventListener("gcs:status", (e) => show(e.detail.radio));
})();
