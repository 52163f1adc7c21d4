// The vehicle selector. With several vehicles (GET /api/vehicles) a <select> in the header
// switches the page to one vehicle's URLs (/api/vehicles/{sysid}/status, .../ws/live, ...):
// the page reloads with ?vehicle=N. Without ?vehicle the page uses the one-vehicle URLs, which
// serve the first vehicle heard. Hidden while there is one vehicle.
"use strict";

const gcsVehicle = (window.gcsVehicle = new URLSearchParams(location.search).get("vehicle"));

// The URL of `path` (/api/... or /ws/...) for the vehicle this page shows.
function vehicleUrl(path) {
  if (!gcsVehicle || path.startsWith("/api/vehicles") || !/^\/(api|ws)\//.test(path)) return path;
  return `/api/vehicles/${encodeURIComponent(gcsVehicle)}${path.replace(/^\/api\//, "/")}`;
}

async function refreshVehicles() {
  const select = document.getElementById("vehicle-select");
  let list;
  try {
    const res = await fetch("/api/vehicles");
    if (!res.ok) return;
    list = (await res.json()).filter((v) => v.sysid !== null);
  } catch (e) { return; }
  select.hidden = list.length < 2;
  const shown = gcsVehicle || String((list.find((v) => v.first) || {}).sysid ?? "");
  const labels = list.map((v) => `sysid ${v.sysid} ${(v.autopilot || "").replace("MAV_AUTOPILOT_", "")} ${(v.vehicle_type || "").replace("MAV_TYPE_", "")} (${v.state})`);
  if (select.dataset.labels === labels.join("|")) return;
  select.dataset.labels = labels.join("|");
  select.replaceChildren(...list.map((v, i) => {
    const option = document.createElement("option");
    option.value = String(v.sysid);
    option.textContent = labels[i];
    option.selected = String(v.sysid) === shown;
    return option;
  }));
}

document.getElementById("vehicle-select").addEventListener("change", (ev) => {
  const query = new URLSearchParams(location.search);
  query.set("vehicle", ev.target.value);
  query.delete("token");
  location.search = query.toString();
});
// one request waiting at a time: a server that stops answering must not gather one every 2 s
let vehiclesPoll = refreshVehicles().finally(() => { vehiclesPoll = null; });
setInterval(() => { vehiclesPoll ??= refreshVehicles().finally(() => { vehiclesPoll = null; }); }, 2000);
