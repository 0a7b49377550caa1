// The solitonde page: plates, a plate's map and measurements, a shot's trace.
// Everything comes from the REST API under /v1; the API key, when the server asks for one, is
// kept for this browser tab only (sessionStorage) and sent as X-API-Key.
"use strict";

const $ = (id) => document.getElementById(id);
const KEY = "solitonde-api-key";

function headers() {
  const key = sessionStorage.getItem(KEY);
  return key ? { "X-API-Key": key } : {};
}

function say(text, isError = false) {
  $("status").textContent = text;
  $("status").className = isError ? "error" : "";
}

async function api(path, options = {}) {
  const response = await fetch(path, { ...options, headers: { ...headers(), ...(options.headers || {}) } });
  if (response.status === 401) {
    $("key-form").hidden = false;
    say("this server needs its API key", true);
    throw new Error("unauthorized");
  }
  if (!response.ok && response.status !== 204) {
    let detail = response.statusText;
    try { detail = (await response.json()).detail || detail; } catch (_) { /* not JSON */ }
    throw new Error(`${response.status}: ${detail}`);
  }
  return response;
}

async function image(img, path) {
  const blob = await (await api(path)).blob();
  if (img.src.startsWith("blob:")) URL.revokeObjectURL(img.src);
  img.src = URL.createObjectURL(blob);
}

function cell(row, text) {
  const td = document.createElement("td");
  td.textContent = text === null || text === undefined ? "-" : String(text);
  row.appendChild(td);
  return td;
}

function link(td, text, onClick) {
  td.textContent = "";
  const button = document.createElement("button");
  button.className = "link";
  button.type = "button";
  button.textContent = text;
  button.addEventListener("click", onClick);
  td.appendChild(button);
}

function mm(value) {
  return value === null || value === undefined ? "-" : (value * 1e3).toFixed(2);
}

function answer(p) {
  if (!p) return "-";
  if (p.status === "constrained") return `${mm(p.median)} (95 % ${mm(p.ci95[0])}..${mm(p.ci95[1])})`;
  if (p.status === "lower_bound_only") return `at least ${mm(p.ci95[0])}`;
  if (p.status === "upper_bound_only") return `at most ${mm(p.ci95[1])}`;
  return p.status;
}

async function loadPlates() {
  const plates = (await (await api("/v1/plates")).json()).items;
  const body = $("plates").querySelector("tbody");
  body.textContent = "";
  for (const p of plates) {
    const row = document.createElement("tr");
    link(cell(row, ""), p.plate_id, () => { location.hash = `plate=${encodeURIComponent(p.plate_id)}`; });
    cell(row, p.n_positions);
    cell(row, p.n_measurements);
    cell(row, p.n_shots);
    cell(row, p.last_activity);
    body.appendChild(row);
  }
  say(`${plates.length} plate${plates.length === 1 ? "" : "s"}`);
}

async function showPlate(plateId) {
  $("plate-panel").hidden = false;
  $("trace-panel").hidden = true;
  $("plate-title").textContent = `Plate ${plateId}`;
  const id = encodeURIComponent(plateId);
  const map = await (await api(`/v1/plates/${id}/map`)).json();
  const s = map.support;
  $("support").textContent = s
    ? `Located support: normal ${s.normal_angle_deg.toFixed(1)} deg, offset ${mm(s.offset_m)} mm ` +
      `(95 % ${mm(s.ci95_offset_m[0])}..${mm(s.ci95_offset_m[1])} mm) from ${s.n_positions} positions, ` +
      `rms residual ${mm(s.residual_m)} mm`
    : `Support not located: ${map.support_reason || "-"}`;
  await image($("map"), `/v1/plates/${id}/map.png`);
  const items = (await (await api(`/v1/measurements?plate_id=${id}&limit=500`)).json()).items;
  const body = $("measurements").querySelector("tbody");
  body.textContent = "";
  for (const m of items) {
    const row = document.createElement("tr");
    link(cell(row, ""), m.id, () => showTrace(m.id));
    cell(row, m.position);
    const loc = m.location || {};
    cell(row, loc.x_m === undefined ? "-" : `${mm(loc.x_m)}, ${mm(loc.y_m)}`);
    cell(row, m.n_shots);
    const agg = (m.aggregates || [])[0] || {};
    cell(row, agg.tof_s && agg.tof_s.mean !== null ? (agg.tof_s.mean * 1e6).toFixed(2) : "-");
    cell(row, agg.arr && agg.arr.mean !== null ? agg.arr.mean.toFixed(4) : "-");
    const flags = cell(row, "");
    for (const [name, count] of Object.entries(agg.flag_counts || {})) {
      const span = document.createElement("span");
      span.className = "flag";
      span.textContent = `${name} x${count}`;
      flags.appendChild(span);
    }
    const est = m.estimate || {};
    cell(row, answer(est.thickness_m));
    cell(row, answer(est.distance_m));
    link(cell(row, ""), "delete", () => remove(m.id, plateId));
    body.appendChild(row);
  }
}

async function showTrace(measurementId) {
  $("trace-panel").hidden = false;
  $("trace-title").textContent = `Measurement ${measurementId}, shot 0`;
  await image($("trace"), `/v1/measurements/${measurementId}/plot.png?shot=0`);
}

async function remove(measurementId, plateId) {
  if (!confirm(`Delete measurement ${measurementId} and its shots?`)) return;
  await api(`/v1/measurements/${measurementId}`, { method: "DELETE" });
  await loadPlates();
  await showPlate(plateId);
}

async function route() {
  try {
    await loadPlates();
    const match = location.hash.match(/^#plate=(.+)$/);
    if (match) await showPlate(decodeURIComponent(match[1]));
  } catch (error) {
    if (error.message !== "unauthorized") say(error.message, true);
  }
}

$("key-form").addEventListener("submit", (event) => {
  event.preventDefault();
  sessionStorage.setItem(KEY, $("key").value);
  $("key-form").hidden = true;
  route();
});
window.addEventListener("hashchange", route);
route();
