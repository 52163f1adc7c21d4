// The vehicle's onboard log: one button that downloads the latest log into the recording folder
// (POST /api/onboard-logs/download) and follows its progress (GET /api/onboard-logs); when done,
// the sessions and replay lists are refreshed so the log can be opened next to the live session.
// Uses call() and oneAtATime() from panels.js and $ from dashboard.js.
"use strict";

(() => {
  const button = $("onboard-log-btn"), status = $("onboard-log-status");
  const kb = (n) => `${(n / 1000).toFixed(1)} kB`;
  let timer = null;

  function show(p) {
    if (p.state === "downloading") {
      status.textContent = `log ${p.log_id}: ${kb(p.bytes_received)} of ${kb(p.size)} `
        + `(${(100 * p.fraction).toFixed(0)} %), ${kb(p.rate_bps)}/s, ${p.re_requests} re-requests`;
    } else if (p.state === "done") {
      status.textContent = `log ${p.log_id} downloaded (${kb(p.size)} at ${kb(p.rate_bps)}/s): `
        + `${p.path.split("/").pop()} is in the Replay list`;
    } else if (p.state === "failed") {
      status.textContent = `log download failed: ${p.error}`;
    } else if (p.state === "listing") {
      status.textContent = "asking the vehicle for its logs…";
    }
  }

  // A failed request (a 5xx, a network blip) is said once, after the last progress shown, and the
  // following goes on: it stopped for good at the first one, the page frozen on a part-done download.
  let failing = false;
  const poll = oneAtATime(async () => {
    const r = await call("GET", "/api/onboard-logs");
    if (!r.ok) {
      if (!failing) status.textContent += ` · ${r.message}; still following`;
      failing = true;
      return;
    }
    failing = false;
    show(r.data.progress);
    if (!["listing", "downloading"].includes(r.data.progress.state)) {
      clearInterval(timer);
      timer = null;
      button.disabled = !canChange();  // a read-only page follows a download, it never starts one
      $("sessions-refresh").click();  // the new log appears among the replay sources
    }
  });  // one request waiting at a time: a server that stops answering must not gather one a second

  // A download already running (started before a reload, or from another page) is followed from
  // the start: the page said nothing of it, and offered to start it again.
  call("GET", "/api/onboard-logs").then((r) => {
    if (!r.ok || !["listing", "downloading"].includes(r.data.progress.state) || timer !== null) return;
    button.disabled = true;
    show(r.data.progress);
    timer = setInterval(poll, 1000);
  });

  button.addEventListener("click", async () => {
    const r = await call("POST", "/api/onboard-logs/download", {});
    if (!r.ok) { status.textContent = r.message; return; }
    button.disabled = true;
    show(r.data.progress);
    if (timer === null) timer = setInterval(poll, 1000);
  });
})();
