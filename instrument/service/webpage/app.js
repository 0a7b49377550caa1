// The solitonde page: upload a recording (with an instrument set-up), the set-ups and their chain
// calibration, plates, a plate's map (inverted position by position or
// as one unknown, with the next positions to measure marked), one estimate per position, its
// measurements, and every shot's trace with the picks marked. Everything comes from the REST API
// under /v1; the API key, when the server asks for one, is kept for this browser tab only
// (sessionStorage) and sent as X-API-Key. The page looks for new measurements every few seconds
// (GET /v1/plates is cheap) and redraws what changed.
"use strict";

const $ = (id) => document.getElementById(id);
const KEY = "solitonde-api-key";
const POLL_MS = 2000;
let tables = null; // table id -> its family, from GET /v1/tables (once)
let seen = null; // what GET /v1/plates said last time: the live update redraws on a change
let busy = false;
let again = false; // a forced redraw asked while one was running

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
  // the old picture goes first: a failed load never leaves another measurement's on show
  if (img.src.startsWith("blob:")) URL.revokeObjectURL(img.src);
  img.removeAttribute("src");
  const blob = await (await api(path)).blob();
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
  return button;
}

function mm(value) {
  return value === null || value === undefined ? "-" : (value * 1e3).toFixed(2);
}

function num(value, digits) {
  return value === null || value === undefined ? "-" : Number(value).toFixed(digits);
}

// A length in mm with its unit, or "-" alone: never a unit after a missing number.
function mmUnit(value) {
  return value === null || value === undefined ? "-" : `${mm(value)} mm`;
}

// One parameter's answer in words; `unit`: with "mm" after each number (a table's column says it
// otherwise). A status without numbers (inconsistent, unconstrained) is said as it is.
function answer(p, unit = true) {
  if (!p) return "-";
  const v = unit ? mmUnit : mm;
  const ci = p.ci95 || [null, null];
  if (p.status === "constrained") return `${v(p.median)} (95 % ${mm(ci[0])}..${v(ci[1])})`;
  if (p.status === "lower_bound_only") return `at least ${v(ci[0])}`;
  if (p.status === "upper_bound_only") return `at most ${v(ci[1])}`;
  if (p.status === "ambiguous") {
    let span = "";
    if (ci[0] !== null && ci[1] !== null) span = ` ${mm(ci[0])}..${v(ci[1])}`;
    else if (ci[0] !== null) span = ` from ${v(ci[0])}`;
    else if (ci[1] !== null) span = ` up to ${v(ci[1])}`;
    return `ambiguous${span} (see the readings)`;
  }
  return p.status;
}

// What an estimate should be read with: the reason it is inconsistent, an ambiguous answer's
// readings, its warnings; one line each.
function estimateNotes(est) {
  if (!est) return [];
  const lines = [];
  if (est.reason) lines.push(`Why: ${est.reason}`);
  (est.readings || []).forEach((r, k) => {
    lines.push(`Reading ${k + 1} (weight ${num(r.weight, 2)}): thickness ` +
               `${answer(r.thickness_m)}, distance to the support ${answer(r.distance_m)}`);
  });
  for (const w of est.warnings || []) lines.push(`Warning: ${w}`);
  return lines;
}

// A set-up's chain calibration in words: per sphere size the TOF offset, ARR factor and damping,
// and how many distances it follows.
function calibrationText(cal) {
  if (!cal) return "not calibrated";
  return (cal.per_diameter || []).map((e) => {
    const parts = [`D ${num(e.diameter_m * 1e3, 2)} mm: TOF offset ` +
                   `${num(e.tof_offset_s * 1e6, 2)} us, ARR factor ${num(e.arr_factor, 3)}`];
    if (e.damping_s !== undefined && e.damping_s !== null) {
      parts.push(`damping ${Number(e.damping_s).toExponential(2)} s`);
    }
    if (e.by_distance) parts.push(`by distance at ${e.by_distance.length} references`);
    return parts.join(", ");
  }).join("; ") || "calibrated";
}

function loadSetups(setups) {
  const body = $("setups").querySelector("tbody");
  body.textContent = "";
  for (const s of setups) {
    const row = document.createElement("tr");
    cell(row, s.id);
    cell(row, s.revision);
    cell(row, s.sphere_diameters_m.map((d) => num(d * 1e3, 2)).join(", "));
    cell(row, s.table);
    cell(row, calibrationText(s.chain_calibration));
    cell(row, Object.entries(s.labels || {}).map(([k, v]) => `${k}: ${v}`).join(", ") || "-");
    body.appendChild(row);
  }
  $("setups-empty").hidden = setups.length > 0;
  const pick = $("f-setup");
  const chosen = pick.value;
  pick.textContent = "";
  const none = document.createElement("option");
  none.value = "";
  none.textContent = "none";
  pick.appendChild(none);
  for (const s of setups) {
    const option = document.createElement("option");
    option.value = s.id;
    option.textContent = `${s.id} (revision ${s.revision})`;
    pick.appendChild(option);
  }
  pick.value = setups.some((s) => s.id === chosen) ? chosen : "";
}

// --- where we are: #plate=ID&m=N&shot=K -------------------------------------------------------

function here() {
  const params = new URLSearchParams(location.hash.slice(1));
  const m = params.get("m");
  return { plate: params.get("plate"), m: m === null ? null : Number(m),
           shot: Number(params.get("shot") || 0), joint: params.get("joint") === "1",
           suggest: Math.max(0, Math.min(20, Number(params.get("suggest") || 0) || 0)) };
}

function go(plate, m = null, shot = 0) {
  const params = new URLSearchParams();
  const { joint, suggest } = here();
  if (plate !== null && plate !== undefined) params.set("plate", plate);
  if (m !== null) params.set("m", String(m));
  if (m !== null && shot) params.set("shot", String(shot));
  if (joint) params.set("joint", "1");
  if (suggest) params.set("suggest", String(suggest));
  location.hash = params.toString();
}

// the map's options (#joint=1&suggest=N): the scan inverted as one unknown, the next positions
function mapQuery() {
  const { joint, suggest } = here();
  const params = new URLSearchParams();
  if (joint) params.set("joint", "true");
  if (suggest) params.set("suggest", String(suggest));
  const text = params.toString();
  return text ? `?${text}` : "";
}

function setMapOptions() {
  const params = new URLSearchParams(location.hash.slice(1));
  if ($("joint").checked) params.set("joint", "1"); else params.delete("joint");
  const n = Math.max(0, Math.min(20, Number($("suggest").value) || 0));
  if (n) params.set("suggest", String(n)); else params.delete("suggest");
  location.hash = params.toString();
}

// --- tables and plate material ------------------------------------------------------------------

function materialName(material) {
  if (!material) return "?";
  return material.name || `E ${(material.youngs_modulus / 1e9).toFixed(0)} GPa`;
}

async function tableText(tableId) {
  if (!tableId) return "no model table";
  if (tables === null) {
    tables = {};
    try {
      for (const t of (await (await api("/v1/tables")).json()).items) tables[t.id] = t.family || {};
    } catch (error) {
      if (error.message === "unauthorized") throw error;
    }
  }
  const family = tables[tableId];
  if (!family) return `table ${tableId}`;
  return `table ${tableId} (plate ${materialName(family.plate_material)}, spheres ` +
         `${materialName(family.sphere_material)})`;
}

// --- plates -------------------------------------------------------------------------------------

async function loadPlates(plates) {
  const body = $("plates").querySelector("tbody");
  body.textContent = "";
  for (const p of plates) {
    const row = document.createElement("tr");
    link(cell(row, ""), p.plate_id, () => go(p.plate_id));
    cell(row, p.n_positions);
    cell(row, p.n_measurements);
    cell(row, p.n_shots);
    cell(row, p.last_activity);
    body.appendChild(row);
  }
  say(`${plates.length} plate${plates.length === 1 ? "" : "s"}`);
}

function downloads(plateId) {
  const id = encodeURIComponent(plateId);
  for (const kind of ["estimates", "shots"]) {
    for (const format of ["csv", "parquet"]) {
      const a = $(`dl-${kind}-${format}`);
      a.href = `/v1/measurements/export?kind=${kind}&format=${format}&plate_id=${id}`;
      a.download = `${plateId}-${kind}.${format}`;
    }
  }
  for (const format of ["pdf", "html", "json"]) {
    const a = $(`dl-report-${format}`);
    a.href = `/v1/plates/${id}/report.${format}`;
    a.download = `${plateId}-report.${format}`;
  }
}

async function showPlate(plateId) {
  $("plate-panel").hidden = false;
  $("plate-title").textContent = `Plate ${plateId}`;
  downloads(plateId);
  const id = encodeURIComponent(plateId);
  const { joint, suggest } = here();
  $("joint").checked = joint;
  $("suggest").value = String(suggest);
  const query = mapQuery();
  const map = await (await api(`/v1/plates/${id}/map${query}`)).json();
  const s = map.support;
  $("support").textContent = s
    ? `Located support${map.joint ? " (joint)" : ""}: normal ${num(s.normal_angle_deg, 1)} deg, ` +
      `offset ${mmUnit(s.offset_m)} (95 % ${mm(s.ci95_offset_m[0])}..${mmUnit(s.ci95_offset_m[1])}) ` +
      `from ${s.n_positions} positions, rms residual ${mmUnit(s.residual_m)}`
    : `Support not located: ${map.support_reason || "-"}`;
  const notes = [];
  if (map.joint && map.fit) {
    notes.push(`Joint fit: chi2 ${num(map.fit.chi2, 2)} for ${num(map.fit.dof, 1)} degrees of ` +
               `freedom, p = ${num(map.fit.p_value, 3)}; thickness ${(map.thickness_prior || {}).kind}`);
  }
  for (const w of map.warnings || []) notes.push(`Warning: ${w}`);
  $("joint-notes").textContent = notes.join("\n");
  const next = $("suggestions").querySelector("tbody");
  next.textContent = "";
  (map.suggestions || []).forEach((p, k) => {
    const row = document.createElement("tr");
    cell(row, `next ${k + 1}`);
    cell(row, `${mm(p.x_m)}, ${mm(p.y_m)}`);
    cell(row, mm(p.distance_m));
    cell(row, mm(p.expected_gain));
    next.appendChild(row);
  });
  $("suggestions-panel").hidden = !(map.suggestions || []).length;
  await image($("map"), `/v1/plates/${id}/map.png${query}`);
  const positions = $("positions").querySelector("tbody");
  positions.textContent = "";
  for (const p of map.positions || []) {
    const row = document.createElement("tr");
    cell(row, p.position);
    cell(row, p.x_m === null || p.x_m === undefined ? "-" : `${mm(p.x_m)}, ${mm(p.y_m)}`);
    cell(row, p.n_shots);
    cell(row, answer(p.thickness_m, false));
    cell(row, answer(p.distance_m, false));
    cell(row, mm(p.distance_to_located_support_m));
    const ids = cell(row, "");
    for (const mid of p.measurement_ids || []) {
      link(ids.appendChild(document.createElement("span")), mid, () => go(plateId, mid));
    }
    positions.appendChild(row);
  }
  const items = (await (await api(`/v1/measurements?plate_id=${id}&limit=500`)).json()).items;
  const used = new Set();
  const body = $("measurements").querySelector("tbody");
  body.textContent = "";
  for (const m of items) {
    const row = document.createElement("tr");
    link(cell(row, ""), m.id, () => go(plateId, m.id));
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
    // shots left out of the mean as outliers (a flagged shot's rejection shows as its flag)
    const outliers = (agg.rejected || []).filter(r => r.feature === "tof_s" || r.feature === "arr");
    if (outliers.length) {
      const span = document.createElement("span");
      span.className = "flag outlier";
      span.textContent = `outlier x${outliers.length}`;
      span.title = outliers.map(r => `shot ${r.index}: ${r.feature === "tof_s" ? "TOF" : "ARR"} ` +
        `${r.reason}`).join("\n");
      flags.appendChild(span);
    }
    const est = m.estimate || {};
    const answerCell = cell(row, answer(est.thickness_m, false));
    const notes = estimateNotes(m.estimate);
    if (notes.length) {  // the reasons and warnings, one click away on the measurement's view
      answerCell.title = notes.join("\n");
      const mark = document.createElement("span");
      mark.className = "flag";
      mark.textContent = `${(m.estimate.warnings || []).length} note` +
        `${(m.estimate.warnings || []).length === 1 ? "" : "s"}`;
      answerCell.appendChild(mark);
    }
    cell(row, answer(est.distance_m, false));
    cell(row, m.table || "-");
    if (m.table) used.add(m.table);
    link(cell(row, ""), "delete", () => remove(m.id, plateId));
    body.appendChild(row);
  }
  const texts = [];
  for (const t of used) texts.push(await tableText(t));
  $("plate-tables").textContent = texts.length ? `Estimated with ${texts.join("; ")}` :
    "No estimate yet (no model table for these measurements)";
}

// --- one measurement: every shot, its trace with the picks ---------------------------------------

async function showMeasurement(measurementId, shot) {
  const m = await (await api(`/v1/measurements/${measurementId}`)).json();
  $("trace-panel").hidden = false;
  const where = [m.plate_id && `plate ${m.plate_id}`, m.position && `position ${m.position}`]
    .filter(Boolean).join(", ");
  $("measurement-title").textContent = `Measurement ${m.id}${where ? ` (${where})` : ""}: ` +
    `${m.n_shots} shot${m.n_shots === 1 ? "" : "s"}; thickness ` +
    `${answer((m.estimate || {}).thickness_m)}, distance ${answer((m.estimate || {}).distance_m)}`;
  const setup = (m.provenance || {}).setup;
  const measuredWith = setup ? `; set-up ${setup.id}, revision ${setup.revision} ` +
    `(${calibrationText(m.provenance.chain_calibration)})` : "";
  $("measurement-table").textContent = (m.estimate ? `Estimated with ${await tableText(m.table)}` :
    `No estimate: ${m.estimate_reason || "-"}`) + measuredWith;
  const notes = $("measurement-notes");
  notes.textContent = "";
  for (const line of estimateNotes(m.estimate)) {
    const item = document.createElement("li");
    item.textContent = line;
    if (line.startsWith("Warning: inconsistent") || line.startsWith("Why: ")) {
      item.className = "error";
    }
    notes.appendChild(item);
  }
  const body = $("shots").querySelector("tbody");
  body.textContent = "";
  for (const s of m.shots) {
    const f = s.features || {};
    const row = document.createElement("tr");
    if (s.shot_index === shot) row.className = "current";
    link(cell(row, ""), `shot ${s.shot_index}`, () => go(m.plate_id, m.id, s.shot_index))
      .id = `shot-${s.shot_index}`;
    cell(row, f.tof_s === null || f.tof_s === undefined ? "-" : (f.tof_s * 1e6).toFixed(2));
    cell(row, num(f.arr, 4));
    cell(row, num(f.snr_db, 1));
    cell(row, (f.flags || []).join(", ") || "-");
    body.appendChild(row);
  }
  $("trace-title").textContent = `Measurement ${m.id}, shot ${shot}: the incident and reflected ` +
    "pulses marked";
  await image($("trace"), `/v1/measurements/${m.id}/plot.png?shot=${shot}`);
}

async function remove(measurementId, plateId) {
  if (!confirm(`Delete measurement ${measurementId} and its shots?`)) return;
  await api(`/v1/measurements/${measurementId}`, { method: "DELETE" });
  go(plateId);
  await refresh(true);
}

// --- upload ----------------------------------------------------------------------------------------

async function upload(event) {
  event.preventDefault();
  const file = $("file").files[0];
  if (!file) {
    $("upload-result").textContent = "Choose or drop a file first.";
    $("upload-result").className = "error";
    return;
  }
  const form = new FormData();
  form.append("file", file, file.name);
  for (const input of $("upload-form").querySelectorAll(".fields input, .fields select")) {
    if (input.value.trim() !== "") form.append(input.name, input.value.trim());
  }
  $("upload").disabled = true;
  $("upload-result").className = "";
  $("upload-result").textContent = `Sending ${file.name} ...`;
  try {
    const m = await (await api("/v1/measurements", { method: "POST", body: form })).json();
    const est = m.estimate || {};
    const already = m.duplicate_of ? " (these shots were stored already: not stored again)" : "";
    $("upload-result").textContent = `${file.name}: measurement ${m.id}${already}, ${m.n_shots} ` +
      `shot${m.n_shots === 1 ? "" : "s"}; thickness ${answer(est.thickness_m)}, distance ` +
      `${answer(est.distance_m)}` + (m.estimate ? "" : ` (no estimate: ${m.estimate_reason})`);
    go(m.plate_id, m.id);
    await refresh(true);
  } catch (error) {
    $("upload-result").textContent = `${file.name}: ${error.message}`;
    $("upload-result").className = "error";
  } finally {
    $("upload").disabled = false;
  }
}

function dropZone() {
  const zone = $("drop");
  for (const name of ["dragenter", "dragover"]) {
    zone.addEventListener(name, (event) => { event.preventDefault(); zone.classList.add("over"); });
  }
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (event) => {
    event.preventDefault();
    zone.classList.remove("over");
    if (event.dataTransfer.files.length) {
      $("file").files = event.dataTransfer.files;
      $("drop-text").textContent = `${event.dataTransfer.files[0].name}: fill in what the file ` +
        "does not say, then Upload.";
    }
  });
}

// --- downloads with the key ------------------------------------------------------------------------

async function download(event) {
  if (!sessionStorage.getItem(KEY)) return; // a plain link does it
  event.preventDefault();
  const a = event.currentTarget;
  const blob = await (await api(a.getAttribute("href"))).blob();
  const save = document.createElement("a");
  save.href = URL.createObjectURL(blob);
  save.download = a.download;
  save.click();
  setTimeout(() => URL.revokeObjectURL(save.href), 10000);
}

// --- drawing and the live update ---------------------------------------------------------------------

async function refresh(force = false) {
  if (busy) { // one drawing at a time; a forced one asked meanwhile runs right after
    again = again || force;
    return;
  }
  busy = true;
  try {
    const plates = (await (await api("/v1/plates")).json()).items;
    const setups = (await (await api("/v1/setups")).json()).items;
    const signature = JSON.stringify([plates.map((p) => [p.plate_id, p.n_measurements,
                                                         p.n_shots, p.last_activity]),
                                      setups.map((s) => [s.id, s.revision])]);
    const changed = signature !== seen;
    seen = signature;
    if (!changed && !force) return;
    loadSetups(setups);
    await loadPlates(plates);
    const { plate, m, shot } = here();
    if (plate !== null) await showPlate(plate); else $("plate-panel").hidden = true;
    if (m !== null && force) await showMeasurement(m, shot);
    if (m === null) $("trace-panel").hidden = true;
    $("live").textContent = `live, updated ${new Date().toLocaleTimeString()}`;
  } catch (error) {
    if (error.message !== "unauthorized") say(error.message, true);
  } finally {
    busy = false;
    if (again) {
      again = false;
      await refresh(true);
    }
  }
}

async function poll() {
  await refresh(false);
  setTimeout(poll, POLL_MS);
}

$("key-form").addEventListener("submit", (event) => {
  event.preventDefault();
  sessionStorage.setItem(KEY, $("key").value);
  $("key-form").hidden = true;
  tables = null;
  refresh(true);
});
$("upload-form").addEventListener("submit", upload);
$("map-options").addEventListener("submit", (event) => { event.preventDefault(); setMapOptions(); });
$("joint").addEventListener("change", setMapOptions);
$("suggest").addEventListener("change", setMapOptions);
for (const a of document.querySelectorAll(".downloads a")) a.addEventListener("click", download);
dropZone();
window.addEventListener("hashchange", () => refresh(true));
refresh(true).then(() => setTimeout(poll, POLL_MS));
