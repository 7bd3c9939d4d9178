// The modsat web UI: job list (paginated, live progress over server-sent events), submit form
// (presets + JSON schema), a job's learning curves, evaluation, downloads and 3D view.
// Plain JavaScript talking to the REST API under /api; nothing is loaded from elsewhere.
"use strict";

const $ = (id) => document.getElementById(id);
const PAGE_SIZE = 20;
const MAX_LIST_STREAMS = 3; // browsers allow ~6 connections per host; keep room for fetches
const TERMINAL = new Set(["succeeded", "failed", "cancelled"]);
// Spec fields shown as form inputs (built from the JSON schema); everything else is in the JSON editor.
const FIELD_PATHS = ["name", "algorithm", "seed", "training.total_env_steps", "training.num_envs",
  "training.device", "design.grid_size", "evaluation.episodes"];

const state = {
  offset: 0, status: "", total: 0,
  schema: null, presetSpec: null,
  presets: new Map(), // preset name -> GET /api/presets's entry (its measured time per run)
  viewer: null,
  listStreams: new Map(), // job id -> EventSource
  selected: null, job: null, detailStream: null, evalPoints: [], curveFromFile: null, reference: null,
  view: null, compare: "",
  designs: new Map(), // job id -> design.json's grid (null: none), kept: a finished job's design never changes
  outcomes: new Map(), // job id -> GET /api/jobs/{id}/outcome of a finished job (null: asked for), kept too
  progress: newProgress(), // what the ETA and the timings need of the selected job's progress records
};

// ------------------------------------------------------------------ helpers

function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else e.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children) if (c !== null && c !== undefined) e.append(c);
  return e;
}

// How a run's learner is named beside the viewer (web/viewer/run.py's learner_label says the same).
function shortAlgorithm(a) {
  if (a === "ga") return "GA";
  if (a.startsWith("td3")) return "RL";
  if (a.startsWith("diffsim")) return "diffsim";
  return a || "run";
}

function authHeaders() {
  const t = localStorage.getItem("modsat.token");
  return t ? { Authorization: "Bearer " + t } : {};
}

async function api(path, opts) {
  let r;
  try {
    r = await fetch(path, opts);
  } catch (e) {
    return { ok: false, status: 0, body: { detail: "cannot reach the server: " + e.message } };
  }
  const ct = r.headers.get("content-type") || "";
  const body = ct.includes("json") ? await r.json().catch(() => null) : await r.text();
  return { ok: r.ok, status: r.status, body };
}

function errorText(r) {
  const b = r.body;
  if (b && Array.isArray(b.messages)) return b.messages.join("\n");
  if (b && typeof b.detail === "string") return b.detail;
  return `HTTP ${r.status}`;
}

const fmt = {
  int: (v) => (v == null ? "-" : Math.round(v).toLocaleString("en")),
  pct: (v) => (v == null ? "-" : (100 * v).toFixed(0) + " %"),
  num: (d) => (v) => (v == null || !Number.isFinite(v) ? "-" : v.toFixed(d)),
  bytes: (n) => (n < 1024 ? n + " B" : n < 1048576 ? (n / 1024).toFixed(1) + " KiB" : (n / 1048576).toFixed(1) + " MiB"),
  // 62 s, 4 min 30 s, 2 h 05 min
  dur: (s) => {
    if (s == null || !Number.isFinite(s)) return "-";
    s = Math.max(0, Math.round(s));
    if (s < 90) return s + " s";
    if (s < 3600) return `${Math.floor(s / 60)} min` + (s % 60 ? ` ${s % 60} s` : "");
    const m = Math.round(s / 60);
    return `${Math.floor(m / 60)} h ${String(m % 60).padStart(2, "0")} min`;
  },
};

function getPath(obj, path) {
  return path.split(".").reduce((o, k) => (o && typeof o === "object" ? o[k] : undefined), obj);
}

function setPath(obj, path, value) {
  const keys = path.split(".");
  let o = obj;
  for (const k of keys.slice(0, -1)) {
    if (!o[k] || typeof o[k] !== "object") o[k] = {};
    o = o[k];
  }
  o[keys[keys.length - 1]] = value;
}

// ------------------------------------------------------------------ routing (#job=ID&view=live&compare=ID)

function readHash() {
  const q = new URLSearchParams(location.hash.slice(1));
  return { job: q.get("job"), view: q.get("view"), compare: q.get("compare") || "" };
}

function writeHash() {
  const q = new URLSearchParams();
  if (state.selected) q.set("job", state.selected);
  if (state.view) q.set("view", state.view);
  if (state.compare) q.set("compare", state.compare);
  const h = "#" + q.toString();
  if (location.hash !== h) history.replaceState(null, "", h === "#" ? location.pathname : h);
}

// ------------------------------------------------------------------ job list

function progressCell(job) {
  const p = job.progress;
  const pct = Math.round(100 * p.fraction);
  return el("div", { class: "progress", title: `${fmt.int(p.env_steps)} / ${fmt.int(p.total_env_steps)} env steps` },
    el("div", { style: `width:${pct}%` }), el("span", { text: pct + " %" }));
}

function statusBadge(job) {
  const s = job.status + (job.cancel_requested && job.status === "running" ? " (cancelling)" : "");
  return el("span", { class: "badge " + job.status, text: s });
}

// The picture of a finished job's satellite, from its design.json (fetched once per job).
function thumbFor(job) {
  const grid = state.designs.get(String(job.id));
  const svg = grid ? window.modsatCharts.designThumb(grid) : null;
  return svg || el("span", { class: "thumb-none", "aria-hidden": "true" });
}

async function loadThumbs(items) {
  const want = items.filter((j) => j.status === "succeeded" && !state.designs.has(String(j.id)));
  await Promise.all(want.map(async (j) => {
    const id = String(j.id);
    state.designs.set(id, null); // asked for: not again
    const r = await api(`/api/jobs/${id}/artifacts/design.json`);
    const grid = r.ok && r.body && Array.isArray(r.body.grid) ? r.body.grid : null;
    state.designs.set(id, grid);
    const cell = document.querySelector(`#job-${id} .name-wrap`);
    if (grid && cell) cell.firstChild.replaceWith(thumbFor(j));
  }));
}

function nameCell(j) {
  return el("td", { class: "name" }, el("div", { class: "name-wrap" }, thumbFor(j),
    el("div", { class: "name-text" }, el("span", { class: "job-name", title: j.name || "", text: j.name || "(no name)" }),
      el("span", { class: "algo", text: j.algorithm }))));
}

// What a user compares jobs by: success at the mission's tolerance in the final evaluation and, for
// co-design, the kept design's objective (a trade-off: its mass and settling). A running job shows its
// latest curve point's success, marked as such; never a raw return (its scale differs between presets).
function resultText(j) {
  const o = state.outcomes.get(String(j.id));
  if (o && o.success_rate != null) {
    const tol = o.tolerance_deg != null ? ` @ ${+o.tolerance_deg.toFixed(3)}\u00b0` : "";
    const parts = [`${fmt.pct(o.success_rate)}${tol}`];
    if (o.objective_s != null) parts.push(`J ${o.objective_s.toFixed(2)} s`);
    if (o.mass_kg != null) parts.push(`${o.mass_kg.toFixed(2)} kg, ${fmt.num(1)(o.median_settling_s)} s`);
    return parts.join(" \u00b7 ");
  }
  if (j.status !== "succeeded" && j.last_eval && j.last_eval.success_rate != null) {
    return `curve ${fmt.pct(j.last_eval.success_rate)}`;
  }
  return "";
}

async function loadOutcomes(items) {
  const want = items.filter((j) => j.status === "succeeded" && !state.outcomes.has(String(j.id)));
  await Promise.all(want.map(async (j) => {
    const id = String(j.id);
    state.outcomes.set(id, null);
    const r = await api(`/api/jobs/${id}/outcome`);
    if (r.ok) state.outcomes.set(id, r.body);
    else state.outcomes.delete(id);  // asked again at the next refresh
    const cell = document.querySelector(`#job-${id} td.ret`);
    if (cell) cell.textContent = resultText(j);
  }));
}

function renderRows(items) {
  const rows = $("job-rows");
  rows.replaceChildren();
  for (const j of items) {
    const ret = resultText(j);
    const tr = el("tr", { id: "job-" + j.id, tabindex: "0", "data-id": j.id,
      class: String(j.id) === String(state.selected) ? "selected" : null },
      el("td", { class: "num", text: j.id }), nameCell(j), el("td", { class: "status" }, statusBadge(j)),
      el("td", { class: "prog" }, progressCell(j)), el("td", { class: "opt num ret", text: ret }));
    const open = () => selectJob(j.id).then(() => {
      if (window.innerWidth <= 900) $("detail").scrollIntoView({ block: "start" }); // one column: show it
    });
    tr.addEventListener("click", open);
    tr.addEventListener("keydown", (e) => { if (e.key === "Enter") open(); });
    rows.append(tr);
  }
  if (!items.length) rows.append(el("tr", {}, el("td", { colspan: "5", class: "hint", text: "no jobs" })));
  loadThumbs(items);
  loadOutcomes(items);
}

async function loadJobs() {
  const q = new URLSearchParams({ limit: PAGE_SIZE, offset: state.offset });
  if (state.status) q.append("status", state.status);
  const r = await api("/api/jobs?" + q);
  if (!r.ok) {
    $("page-info").textContent = "cannot list the jobs: " + errorText(r);
    return;
  }
  const page = r.body;
  state.total = page.total;
  if (state.offset > 0 && state.offset >= page.total) {
    state.offset = Math.max(0, Math.floor((page.total - 1) / PAGE_SIZE) * PAGE_SIZE);
    return loadJobs();
  }
  renderRows(page.items);
  $("page-info").textContent = page.total
    ? `${page.offset + 1}\u2013${page.offset + page.items.length} of ${page.total}` : "no jobs yet";
  $("prev-page").disabled = state.offset === 0;
  $("next-page").disabled = page.next_offset == null;
  syncListStreams(page.items);
}

function updateRow(id, fields) {
  const tr = $("job-" + id);
  if (!tr) return;
  if (fields.progress) tr.querySelector("td.prog").replaceChildren(progressCell(fields));
  if (fields.status) tr.querySelector("td.status").replaceChildren(statusBadge(fields));
  if (fields.last_eval || fields.status) tr.querySelector("td.ret").textContent = resultText(fields);
}

// One event stream per running job on the page (at most MAX_LIST_STREAMS), for live progress.
function syncListStreams(items) {
  const want = new Map(items.filter((j) => j.status === "running")
    .slice(0, MAX_LIST_STREAMS).map((j) => [String(j.id), j]));
  for (const [id, es] of state.listStreams) {
    if (!want.has(id)) { es.close(); state.listStreams.delete(id); }
  }
  for (const [id, job] of want) {
    if (state.listStreams.has(id)) continue;
    let last = job;
    const es = openEvents(id, 0, {
      metrics: (m) => {
        const total = m.total_env_steps || last.progress.total_env_steps;
        last = { ...last, progress: { ...last.progress, env_steps: m.env_steps, total_env_steps: total,
          fraction: total ? Math.min(1, m.env_steps / total) : 0 } };
        if (m.eval) last.last_eval = m.eval;
        updateRow(id, last);
      },
      status: (s) => { last = s; updateRow(id, s); },
      end: () => { state.listStreams.delete(id); loadJobs(); },
    });
    state.listStreams.set(id, es);
  }
}

function openEvents(id, after, on) {
  const es = new EventSource(`/api/jobs/${id}/events?after=${after}`);
  es.addEventListener("metrics", (e) => on.metrics && on.metrics(JSON.parse(e.data)));
  es.addEventListener("status", (e) => on.status && on.status(JSON.parse(e.data)));
  es.addEventListener("end", (e) => { es.close(); on.end && on.end(JSON.parse(e.data)); });
  // "timeout": the server ends long streams; EventSource reconnects by itself with Last-Event-ID.
  return es;
}

// ------------------------------------------------------------------ submit form

function resolve(node) {
  let n = node || {};
  for (let i = 0; i < 10; i++) {
    if (n.$ref) n = state.schema.$defs[n.$ref.split("/").pop()] || {};
    else if (n.allOf && n.allOf.length === 1) n = { ...n.allOf[0], description: n.description };
    else if (n.anyOf) n = { ...(n.anyOf.find((a) => a.type !== "null") || {}), description: n.description };
    else return n;
  }
  return n;
}

function schemaAt(path) {
  let node = state.schema;
  for (const key of path.split(".")) {
    const props = resolve(node).properties;
    if (!props || !props[key]) return null;
    node = props[key];
  }
  const r = resolve(node);
  return { ...r, description: node.description || r.description, title: node.title || r.title };
}

function buildFields() {
  const box = $("fields");
  box.replaceChildren();
  for (const path of FIELD_PATHS) {
    const s = schemaAt(path);
    if (!s) continue;
    const value = getPath(state.presetSpec, path);
    let input;
    if (s.enum) {
      input = el("select", {}, ...s.enum.map((v) => el("option", { value: v, text: v })));
      input.value = value;
    } else if (s.type === "integer" || s.type === "number") {
      input = el("input", { type: "number", step: s.type === "integer" ? "1" : "any",
        min: s.minimum ?? s.exclusiveMinimum, max: s.maximum ?? s.exclusiveMaximum });
      input.value = value ?? "";
    } else {
      input = el("input", { type: "text", maxlength: s.maxLength });
      input.value = value ?? "";
    }
    input.id = "f-" + path.replace(/\./g, "-");
    input.dataset.path = path;
    input.dataset.kind = s.type || "string";
    input.addEventListener("input", () => fieldToJson(input));
    input.addEventListener("change", () => fieldToJson(input));
    const label = el("label", { for: input.id, title: s.description || "" }, path);
    const err = el("small", { class: "field-error", id: "err-" + path.replace(/\./g, "-") });
    box.append(el("div", { class: "field" }, label, input, err));
  }
}

function fieldValue(input) {
  const v = input.value;
  if (input.dataset.kind === "integer" || input.dataset.kind === "number") {
    if (v.trim() === "") return null;
    const n = Number(v);
    return Number.isFinite(n) ? n : v;
  }
  if (input.dataset.path === "name" && v === "") return null;
  return v;
}

function fieldToJson(input) {
  let spec;
  try { spec = JSON.parse($("overrides").value); } catch { return; } // the editor's own error shows on submit
  setPath(spec, input.dataset.path, fieldValue(input));
  $("overrides").value = JSON.stringify(spec, null, 2);
}

function jsonToFields() {
  let spec;
  try { spec = JSON.parse($("overrides").value); } catch { return; }
  for (const input of $("fields").querySelectorAll("[data-path]")) {
    const v = getPath(spec, input.dataset.path);
    if (document.activeElement !== input) input.value = v ?? "";
  }
}

async function choosePreset(name) {
  const r = await api("/api/presets/" + encodeURIComponent(name));
  if (!r.ok) { showSubmitErrors([errorText(r)]); return; }
  state.presetSpec = r.body;
  $("overrides").value = JSON.stringify(r.body, null, 2);
  const info = $("preset").selectedOptions[0];
  $("preset-info").textContent = info ? info.title : "";
  $("preset-time").textContent = presetTimeText(state.presets.get(name));
  buildFields();
  clearSubmitMessages();
}

// The preset's measured time per run, CPU named (modsat_core/spec/preset_times.py, the README's table).
function presetTimeText(p) {
  if (!p) return "";
  if (!p.time_per_run || !p.time_per_run.length) return `Time per run: ${p.time_text}.`;
  return `Time per run, as measured: ${p.time_text}; ${p.time_measured}. Other CPUs, or more jobs at once, differ.`;
}

async function loadPresets() {
  const [p, s] = await Promise.all([api("/api/presets"), api("/api/schema")]);
  if (!p.ok || !s.ok) { showSubmitErrors(["cannot load the presets: " + errorText(p.ok ? s : p)]); return; }
  state.schema = s.body;
  state.presets = new Map(p.body.map((x) => [x.name, x]));
  const sel = $("preset");
  sel.replaceChildren(...p.body.map((x) => el("option", { value: x.name,
    title: `${x.algorithm}, ${x.grid_size}x${x.grid_size}x${x.grid_size} grid, ${fmt.int(x.total_env_steps)} env steps`,
    text: `${x.name} (${x.algorithm}, ${fmt.int(x.total_env_steps)} steps)` })));
  sel.value = p.body.some((x) => x.name === "quick") ? "quick" : p.body[0].name;
  await choosePreset(sel.value);
}

// What differs from the preset: sent as overrides (nested objects merge on the server).
function diff(base, edited) {
  const isObj = (x) => x && typeof x === "object" && !Array.isArray(x);
  if (isObj(base) && isObj(edited)) {
    const out = {};
    for (const k of Object.keys(edited)) {
      const d = diff(base[k], edited[k]);
      if (d !== undefined) out[k] = d;
    }
    return Object.keys(out).length ? out : undefined;
  }
  return JSON.stringify(base) === JSON.stringify(edited) ? undefined : edited;
}

function clearSubmitMessages() {
  $("submit-errors").hidden = true;
  $("submit-errors").replaceChildren();
  $("submit-ok").hidden = true;
  for (const e of document.querySelectorAll(".field-error")) e.textContent = "";
  for (const i of document.querySelectorAll("[aria-invalid]")) i.removeAttribute("aria-invalid");
}

function showSubmitErrors(messages, detail) {
  const box = $("submit-errors");
  box.replaceChildren(el("strong", { text: "The spec was not accepted:" }),
    el("ul", {}, ...messages.map((m) => el("li", { text: m }))));
  box.hidden = false;
  for (const d of detail || []) {
    const loc = (d.loc || []).filter((x) => x !== "body" && x !== "overrides").join(".");
    const input = document.querySelector(`[data-path="${CSS.escape(loc)}"]`);
    if (input) {
      input.setAttribute("aria-invalid", "true");
      const err = $("err-" + loc.replace(/\./g, "-"));
      if (err) err.textContent = d.msg.replace(loc + ": ", "");
    }
  }
}

async function submitForm(ev) {
  ev.preventDefault();
  clearSubmitMessages();
  let edited;
  try {
    edited = JSON.parse($("overrides").value);
  } catch (e) {
    showSubmitErrors(["the spec is not valid JSON: " + e.message]);
    return;
  }
  if (!edited || typeof edited !== "object" || Array.isArray(edited)) {
    showSubmitErrors(["the spec must be a JSON object"]);
    return;
  }
  const body = { preset: $("preset").value, overrides: diff(state.presetSpec, edited) || {} };
  $("submit-btn").disabled = true;
  const r = await api("/api/jobs", { method: "POST", body: JSON.stringify(body),
    headers: { "content-type": "application/json", ...authHeaders() } });
  $("submit-btn").disabled = false;
  if (!r.ok) {
    const detail = r.body && Array.isArray(r.body.detail) ? r.body.detail : [];
    let msgs = r.body && Array.isArray(r.body.messages) ? r.body.messages : [errorText(r)];
    if (r.status === 401) msgs = [...msgs, "Set the API token (top right) and submit again."];
    showSubmitErrors(msgs, detail);
    return;
  }
  $("submit-ok").textContent = `Job #${r.body.id} queued.`;
  $("submit-ok").hidden = false;
  state.offset = 0;
  await loadJobs();
  selectJob(r.body.id);
}

// ------------------------------------------------------------------ job detail

function renderHead(job) {
  state.job = job;
  $("detail-h").textContent = `Job #${job.id}` + (job.name ? ` \u2014 ${job.name}` : "");
  const b = $("d-status");
  b.className = "badge " + job.status;
  b.textContent = job.status + (job.cancel_requested && job.status === "running" ? " (cancelling)" : "");
  $("d-meta").textContent = `${job.algorithm}, created ${new Date(job.created_at).toLocaleString()}` +
    (job.attempt > 1 ? `, attempt ${job.attempt}` : "");
  $("cancel-btn").hidden = TERMINAL.has(job.status);
  $("d-times").textContent = timesText(job);
  renderProgress(job.progress, job.latest_metrics);
  renderAttempts(job);
  const err = $("d-error");
  err.hidden = !job.error;
  err.textContent = job.error || "";
  if (job.error_detail) err.append(el("details", {}, el("summary", { text: "traceback" }),
    el("pre", { text: job.error_detail })));
}

// Seconds each attempt ran, from the job's attempts (server times). One still running counts
// up to `now` (the newest progress report's time, else the clock here).
function attemptSeconds(job, now) {
  return (job.attempts || []).map((a) => {
    const t0 = Date.parse(a.started_at);
    const t1 = a.ended_at ? Date.parse(a.ended_at) : a.outcome === "running" ? Math.max(t0, now || Date.now()) : t0;
    return (t1 - t0) / 1000;
  });
}

// What the job page keeps of a job's progress records, updated as each one arrives instead of keeping
// them all (a long run has tens of thousands): the final evaluation's first record (its start, the
// training's elapsed_s) and latest one with a stage, and the latest attempt's first and latest
// training records with elapsed_s (the training speed).
function newProgress() {
  return { evaluating: null, staged: null, attemptFirst: null, training: null };
}

function noteRecord(p, r) {
  if (r.phase === "evaluating") {
    if (!p.evaluating) p.evaluating = r;
    if (r.stage) p.staged = r;
  } else if (r.elapsed_s != null) {
    if (!p.attemptFirst || p.attemptFirst.attempt !== r.attempt) p.attemptFirst = r;
    p.training = r;
  }
}

// The first progress record of the final evaluation (phase "evaluating"), if there is one.
function evaluationRecord() {
  return state.progress.evaluating;
}

// The job's wall time: queued -> finished, and how it splits (waiting, training, final evaluation).
function timesText(job) {
  const t = (x) => (x ? Date.parse(x) : null);
  const created = t(job.created_at), started = t(job.started_at), finished = t(job.finished_at);
  const ev = evaluationRecord();
  const parts = [];
  if (finished && created) {
    parts.push(`wall time ${fmt.dur((finished - created) / 1000)} (queued \u2192 ${job.status})`);
    if (started) parts.push(`waited ${fmt.dur((started - created) / 1000)}`);
    if (ev && ev.elapsed_s != null) parts.push(`training ${fmt.dur(ev.elapsed_s)}`);
    if (ev && ev.time) parts.push(`final evaluation ${fmt.dur((finished - Date.parse(ev.time)) / 1000)}`);
    else if (job.progress && job.progress.run_seconds) parts.push(`running ${fmt.dur(job.progress.run_seconds)}`);
  } else if (started && created) {
    parts.push(`waited ${fmt.dur((started - created) / 1000)} in the queue`);
  } else if (created && job.status === "queued") {
    parts.push("waiting for a worker");
  }
  return parts.join(" \u00b7 ");
}

// Training speed from the latest attempt's progress records: env steps per second of elapsed_s.
function stepsPerSecond() {
  const last = state.progress.training, first = state.progress.attemptFirst;
  if (!last) return null;
  if (first !== last && last.elapsed_s > first.elapsed_s && last.env_steps > first.env_steps) {
    return (last.env_steps - first.env_steps) / (last.elapsed_s - first.elapsed_s);
  }
  return last.attempt === 1 && last.elapsed_s > 0 && last.env_steps > 0 ? last.env_steps / last.elapsed_s : null;
}

function etaText(seconds) {
  if (!(seconds >= 0) || !Number.isFinite(seconds)) return "";
  if (seconds < 60) return "less than a minute left";
  if (seconds < 5400) return `about ${Math.max(1, Math.round(seconds / 60))} min left`;
  return `about ${fmt.dur(seconds)} left`;
}

function renderProgress(p, m) {
  const evaluating = p.phase === "evaluating" && !(state.job && TERMINAL.has(state.job.status));
  const bar = $("d-bar");
  bar.parentElement.classList.toggle("evaluating", evaluating);
  bar.style.width = evaluating ? "100%" : `${Math.round(100 * p.fraction)}%`;
  const eta = $("d-eta");
  eta.textContent = "";
  if (evaluating) {
    const ev = evaluationRecord();
    const since = ev && ev.time ? (Date.now() - Date.parse(ev.time)) / 1000 : null;
    // the latest record says what it flies now (a trade-off's front first, then the kept design's stages)
    const now = state.progress.staged;
    $("d-progress").textContent = "Final evaluation: " + (now ? `flying ${now.stage}`
      : "flying the policy and the PD baseline on the evaluation's slews, nominal and under each flight condition")
      + (since != null ? ` \u00b7 ${fmt.dur(since)} so far` : "")
      + (ev && ev.elapsed_s != null ? ` \u00b7 training took ${fmt.dur(ev.elapsed_s)}` : "");
    return;
  }
  $("d-bar").style.width = `${Math.round(100 * p.fraction)}%`;
  const parts = [`${fmt.int(p.env_steps)} / ${fmt.int(p.total_env_steps)} env steps`,
    `${Math.round(100 * p.fraction)} %`];
  if (p.phase) parts.push(p.phase);
  const rate = state.job && state.job.status === "running" ? stepsPerSecond() : null;
  if (rate && p.total_env_steps > p.env_steps) {
    eta.textContent = etaText((p.total_env_steps - p.env_steps) / rate) + " in training, then the final evaluation";
  }
  const job = state.job, n = job && job.attempts ? job.attempts.length : 0;
  if (n > 1) {
    // The training's elapsed_s leaves out attempts that ended without reporting (a lost lease):
    // the total here is every attempt's wall time.
    const total = attemptSeconds(job, m && m.time ? Date.parse(m.time) : null).reduce((a, b) => a + b, 0);
    parts.push(`${fmt.dur(total)} over ${n} attempts`);
  } else if (m && m.elapsed_s != null) {
    parts.push(fmt.dur(m.elapsed_s));
  }
  $("d-progress").textContent = parts.join(" \u00b7 ");
}

// One line per job that needed more than one attempt: how long each ran and how it ended.
function renderAttempts(job) {
  const box = $("d-attempts"), list = job.attempts || [];
  box.hidden = list.length < 2;
  const secs = attemptSeconds(job, job.latest_metrics && Date.parse(job.latest_metrics.time));
  box.textContent = list.length < 2 ? "" : list.map((a, i) =>
    `attempt ${a.attempt}: ${fmt.dur(secs[i])}, ${a.outcome}` +
    (a.resumed_from_env_steps ? ` (resumed at ${fmt.int(a.resumed_from_env_steps)} env steps)` : "")).join(" \u00b7 ");
}

const TOL_KEY = /^success_rate_at_(.+)_deg$/;
const TOL_COLORS = ["#17becf", "#9467bd", "#8c564b"];
const PD_COLOR = "#5b6575";

// The PD baseline's figures on the job's design (evaluation.json), drawn as reference lines.
function referenceFrom(ev, job) {
  const pd = ev && ev.pd_baseline && ev.pd_baseline.summary;
  if (!pd) return null;
  const tol = job && job.spec && job.spec.mission ? job.spec.mission.tolerance_deg : null;
  return { pd, tol, episodes: ev.episodes };
}

function drawCurves() {
  const pts = state.curveFromFile || state.evalPoints;
  const box = $("curves");
  const ref = state.reference, pd = ref && ref.pd;
  const tol = ref ? ref.tol : state.job && state.job.spec && state.job.spec.mission && state.job.spec.mission.tolerance_deg;
  const tolText = (t) => `${+Number(t).toFixed(3)} deg`;
  const ret = pts.map((p) => [p.env_steps, p.mean_return]);
  const retRefs = pd ? [{ name: `PD baseline, same design: ${pd.mean_return.toFixed(1)}`, value: pd.mean_return,
    color: PD_COLOR }] : [];
  // The curve points hold the success rate at the mission's tolerance; other tolerances only
  // where a point has them (success_rate_at_<t>_deg). The PD baseline's, from the final
  // evaluation, at each tolerance it was scored at.
  const succ = [{ name: `policy${tol ? ", within " + tolText(tol) : ""}`, color: "#2ca02c",
    points: pts.map((p) => [p.env_steps, 100 * (p.success_rate ?? 0)]) }];
  const extra = [...new Set(pts.flatMap((p) => Object.keys(p).filter((k) => TOL_KEY.test(k))))];
  extra.filter((k) => tol == null || Number(k.match(TOL_KEY)[1]) !== tol).forEach((k, i) => succ.push({
    name: `policy, within ${tolText(k.match(TOL_KEY)[1])}`, color: TOL_COLORS[i % TOL_COLORS.length],
    points: pts.filter((p) => p[k] != null).map((p) => [p.env_steps, 100 * p[k]]) }));
  const succRefs = [];
  if (pd) {
    succRefs.push({ name: `PD baseline${tol ? ", within " + tolText(tol) : ""}: ${fmt.pct(pd.success_rate)}`,
      value: 100 * pd.success_rate, color: PD_COLOR });
    Object.keys(pd).filter((k) => TOL_KEY.test(k) && Number(k.match(TOL_KEY)[1]) !== tol).forEach((k) =>
      succRefs.push({ name: `PD baseline, within ${tolText(k.match(TOL_KEY)[1])}: ${fmt.pct(pd[k])}`,
        value: 100 * pd[k], color: PD_COLOR, dash: "2 3" }));
  }
  box.replaceChildren(
    window.modsatCharts.lineChart([{ name: "policy", color: "#1f77b4", points: ret }],
      { title: "mean evaluation return", xLabel: "environment steps", yLabel: "return", refs: retRefs }),
    window.modsatCharts.lineChart(succ,
      { title: "success rate", xLabel: "environment steps", yLabel: "%", yMin: 0, yMax: 100, refs: succRefs }));
  box.dataset.points = String(pts.length);
  box.dataset.reference = pd ? "pd" : "";
}

function evalTable(ev) {
  const pol = ev.policy && ev.policy.summary, pd = ev.pd_baseline && ev.pd_baseline.summary;
  const cols = [["policy", pol], ["PD baseline", pd]].filter((c) => c[1]);
  const tolKeys = Object.keys(pol || {}).filter((k) => k.startsWith("success_rate_at_"));
  const rows = [
    ["slews", "episodes", fmt.int],
    ["success rate (mission tolerance)", "success_rate", fmt.pct],
    ...tolKeys.map((k) => [`success within ${k.slice(16).replace("_deg", "")} deg`, k, fmt.pct]),
    ["mean return", "mean_return", (v, s) => (v == null ? "-" : `${v.toFixed(1)} \u00b1 ${(s.std_return ?? 0).toFixed(1)}`)],
    ["median final error (deg)", "median_final_error_deg", fmt.num(3)],
    ["median settling time (s)", "median_settling_time_s", fmt.num(2)],
    ["median slew time / eigenaxis bound", "median_slew_time_ratio", fmt.num(2)],
    ["median effort (N m s)", "median_effort_Nms", fmt.num(4)],
    ["max peak rate (rad/s)", "max_peak_rate_rad_s", fmt.num(3)],
    ["rate-limit violations", "safety_violations", fmt.int],
  ];
  return el("table", { class: "eval" },
    el("thead", {}, el("tr", {}, el("th", { text: "" }), ...cols.map((c) => el("th", { class: "num", text: c[0] })))),
    el("tbody", {}, ...rows.map(([name, key, f]) => el("tr", {}, el("th", { text: name }),
      ...cols.map((c) => el("td", { class: "num", text: f(c[1][key], c[1]) }))))));
}

// evaluation.json's flight conditions (docs/robustness.md): the policy and PD on the same slews
// under sensor noise, delay, inertia error, weak wheels, tumble, disturbance, out-of-range slews.
function conditionsTable(ev) {
  const conds = Array.isArray(ev.conditions) ? ev.conditions : [];
  if (!conds.length) return null;
  const pol = ev.policy && ev.policy.summary, pd = ev.pd_baseline && ev.pd_baseline.summary;
  const rows = [{ name: "nominal", changes: {}, policy: pol, pd_baseline: pd }, ...conds];
  const failed = new Set(flightFailures(ev).map((f) => f.name));
  const what = (c) => Object.entries(c.changes || {}).map(([k, v]) => `${k} ${v}`).join(", ") || "the evaluation's slews";
  const cells = (s) => (s ? [fmt.pct(s.success_rate), fmt.int(s.safety_violations), fmt.num(2)(s.median_settling_time_s)]
    : ["-", "-", "-"]).map((t) => el("td", { class: "num", text: t }));
  // results first; what a condition changes last, wrapped (the combined row's list is long)
  const head = ["condition", "policy success", "viol.", "settling (s)",
    "PD success", "viol.", "settling (s)", "what changes"];
  return el("div", { id: "conditions" },
    el("h3", { text: "Flight conditions (same slews, policy and PD)" }),
    el("table", { class: "eval conditions" },
      el("thead", {}, el("tr", {}, ...head.map((t, i) => el("th", { class: i > 0 && i < 7 ? "num" : "", text: t })))),
      el("tbody", {}, ...rows.map((c) => el("tr", { "data-condition": c.name,
        class: failed.has(c.name) ? "failed" : "" }, el("th", { text: c.name }),
        ...cells(c.policy), ...cells(c.pd_baseline), el("td", { class: "hint changes", text: what(c) }))))));
}

// evaluation.json's flight_failures: the conditions where PD lands and the policy does not.
function flightFailures(ev) {
  return ev && Array.isArray(ev.flight_failures) ? ev.flight_failures : [];
}

// Next to the downloads: the policy they hold is not ready for the conditions it fails.
function flightWarning(ev) {
  const box = $("flight-warning");
  const failed = flightFailures(ev);
  box.hidden = !failed.length;
  box.textContent = failed.length ? "Not flight-ready: this policy fails " + failed.map((f) =>
    `${f.name} (${fmt.pct(f.policy_success)}; PD ${fmt.pct(f.pd_success)})`).join(", ")
    + " of the same slews: not ready to fly under those conditions (docs/robustness.md)." : "";
}

// curve.json's trade-off (docs/requirements.md): the requirements, the front of flown designs over mass
// and median settling time (a click on a point shows its design, figures, flight conditions and files).
function tradeOffView(job, curve, spec) {
  const req = (spec && spec.requirements) || null;
  const front = curve.front, cands = Array.isArray(curve.selection) ? curve.selection : [];
  const reqLine = req ? "Requirements: " + [
    req.slew_max_deg != null ? `slews to ${req.slew_max_deg} deg` : null,
    `settled within ${req.settling_time_s} s on ${Math.round(100 * req.success)} % of the slews under every flight condition`,
    req.mass_budget_kg != null ? `at most ${req.mass_budget_kg} kg` : null,
    req.power_budget_W != null ? `at most ${req.power_budget_W} W` : null,
  ].filter(Boolean).join(", ") + "." : "No requirements stated: the front alone.";
  const meeting = front.filter((p) => p.meets);
  const lightest = meeting.length ? meeting.reduce((a, b) => (b.mass_kg < a.mass_kg ? b : a)) : null;
  const verdict = lightest
    ? `Lightest design meeting them: ${lightest.mass_kg.toFixed(2)} kg, median settling ${lightest.median_settling_s.toFixed(2)} s (kept).`
    : (req ? "No front point meets the requirements; the reasons are listed with each point." : "");
  const detail = el("div", { id: "front-point", class: "front-point-detail" },
    el("p", { class: "hint", text: "Click a point of the front to see its design." }));
  const chart = window.modsatCharts.frontChart(front, cands, {
    massBudget: req ? req.mass_budget_kg : null,
    settlingLimit: req ? req.settling_time_s : null,
    onPick: (i) => showFrontPoint(detail, job, curve, i),
  });
  return [el("h3", { text: "Trade-off" }), el("p", { class: "hint", text: reqLine }),
    el("p", { text: verdict }), el("div", { class: "curves" }, chart), detail];
}

function showFrontPoint(box, job, curve, i) {
  const p = curve.front[i];
  const units = Object.entries(p.wheel_units || {}).map(([k, n]) => `${n} x ${k}`).join(", ") || "none";
  const figures = `Point ${i + 1} of ${curve.front.length}: ${p.mass_kg.toFixed(2)} kg, `
    + `${p.power_W == null ? "power not stated" : p.power_W.toFixed(2) + " W"}, median settling `
    + `${p.median_settling_s.toFixed(2)} s, ${p.modules} modules, wheel units: ${units}.`;
  const conds = Object.entries(p.conditions || {});
  const table = conds.length ? el("table", { class: "eval front-conditions" },
    el("thead", {}, el("tr", {}, el("th", { text: "condition" }), el("th", { class: "num", text: "success" }))),
    el("tbody", {}, el("tr", {}, el("th", { text: "nominal" }), el("td", { class: "num", text: fmt.pct(p.success) })),
      ...conds.map(([k, v]) => el("tr", {}, el("th", { text: k }), el("td", { class: "num", text: fmt.pct(v) }))))) : null;
  const design = new Blob([JSON.stringify({ grid: p.grid, mass_kg: p.mass_kg, wheel_units: p.wheel_units }, null, 1)],
    { type: "application/json" });
  const kept = curve.kept && JSON.stringify(curve.kept.grid) === JSON.stringify(p.grid);
  const files = el("ul", { class: "downloads front-downloads" },
    el("li", {}, el("a", { href: URL.createObjectURL(design), download: `modsat-job-${job.id}-front-${i + 1}-design.json`,
      text: `front-${i + 1}-design.json` }), el("span", { class: "hint", text: " this point's design" })),
    el("li", {}, el("a", { href: `/api/jobs/${job.id}/artifacts/policy.pt`, download: `modsat-job-${job.id}-policy.pt`,
      text: "policy.pt" }), el("span", { class: "hint", text: " the run's controller: it flies every point of the front (design-conditioned)" })),
    ...(kept ? [el("li", { class: "hint", text: "This is the kept design: its standalone exports are in the downloads below." })] : []));
  box.replaceChildren(
    el("div", { class: "design-pic" }, window.modsatCharts.designThumb(p.grid) || el("span"),
      el("p", { class: "hint", text: figures })),
    ...(p.meets === undefined ? [] : [el("p", { class: p.meets ? "" : "errors",
      text: p.meets ? "Meets the requirements." : "Misses: " + (p.reasons || []).join("; ") })]),
    ...(table ? [table] : []), files);
}

// A co-design run's objective (spec.objective, docs/diffsim.md) in words, its parts for each design.
function objectiveParts(grid, obj) {
  const cells = (grid || []).flat(2);
  const modules = cells.filter((c) => c !== 0).length, wheels = cells.filter((c) => c >= 2).length;
  return { modules, wheels, prices: (obj.module_price_s || 0) * modules + (obj.wheel_price_s || 0) * wheels };
}

// curve.json of diffsim-codesign: the objective and its prices, the payload, the kept design against the
// run's other candidates, the paper's initial design (the full cube, flown by the trained controller; absent
// from older runs and where a payload covers the cube's centre) and the random designs of the untrained
// distribution, the objective over training.
function codesignView(curve, spec, controlDtS, keptGrid) {
  const obj = spec.objective || {}, mission = spec.mission || {};
  // the control step as the server computes it (JobDetail.control_dt_s, Mission.control_dt_s)
  const episodeS = mission.episode_steps && controlDtS ? mission.episode_steps * controlDtS : null;
  const terms = ["the mean settling time over the slews (a slew that does not land, or breaks the rate limit, counts "
    + (episodeS ? `the whole episode, ${episodeS.toFixed(1)} s)` : "the whole episode)")];
  if (obj.module_price_s) terms.push(`${obj.module_price_s} s per module`);
  if (obj.wheel_price_s) terms.push(`${obj.wheel_price_s} s more per wheel unit`);
  if (obj.mass_price_s_per_kg) terms.push(`${obj.mass_price_s_per_kg} s per kg`);
  const payload = Array.isArray(obj.payload_cells) ? obj.payload_cells : [];
  const payloadText = payload.length
    ? `Payload: ${payload.length} cell${payload.length === 1 ? "" : "s"} held as structure in every design (`
      + payload.slice(0, 9).map((c) => `[${c.join(", ")}]`).join(" ") + (payload.length > 9 ? " \u2026" : "") + ")."
    : "No payload: designs grow from the centre cell, a wheel unit.";
  const same = (a, b) => JSON.stringify(a) === JSON.stringify(b);
  const sel = (curve.selection || []).filter((c) => c && c.objective_s != null);
  const kept = sel.find((c) => keptGrid && same(c.grid, keptGrid)) || sel.reduce((a, b) => (!a || b.objective_s < a.objective_s ? b : a), null);
  const row = (label, objective, grid, cls) => {
    const p = grid ? objectiveParts(grid, obj) : null;
    const f2 = fmt.num(2);
    return el("tr", { class: cls || null }, el("th", { text: label }), el("td", { class: "num", text: f2(objective) }),
      el("td", { class: "num", text: p ? f2(objective - p.prices) : "-" }),
      el("td", { class: "num", text: p ? f2(p.prices) : "-" }),
      el("td", { class: "num", text: p ? `${p.modules} / ${p.wheels}` : "-" }));
  };
  const rows = [];
  if (kept) rows.push(row("kept design", kept.objective_s, kept.grid, "kept"));
  sel.filter((c) => c !== kept).forEach((c) => rows.push(row(c.mode ? "the distribution's mode" : "one of the best draws", c.objective_s, c.grid)));
  const cube = curve.initial_design;
  if (cube && cube.objective_s != null) {
    rows.push(row("initial design: the full cube, flown by the same controller", cube.objective_s, cube.grid, "initial"));
  }
  const d = curve.designs.filter((x) => x.mean_objective_s != null);
  if (d.length) {
    const f = d[0];
    rows.push(row(`random designs: mean of ${f.valid_draws ?? "the"} draws of the untrained distribution`, f.mean_objective_s, null, "random"));
    rows.push(row("random designs: best of those draws", f.best_objective_s, null, "random"));
  }
  const table = el("table", { class: "eval codesign-table" },
    el("thead", {}, el("tr", {}, el("th", { text: "design" }), el("th", { class: "num", text: "objective (s)" }),
      el("th", { class: "num", text: "settling part (s)" }), el("th", { class: "num", text: "prices (s)" }),
      el("th", { class: "num", text: "modules / wheels" }))),
    el("tbody", {}, ...rows));
  const chart = window.modsatCharts.lineChart([
    { name: "mean of the draws", color: "#1f77b4", points: d.map((x) => [x.env_steps, x.mean_objective_s]) },
    { name: "best draw", color: "#2ca02c", points: d.map((x) => [x.env_steps, x.best_objective_s]) },
  ], { title: "design objective over training (lower is better)", xLabel: "environment steps", yLabel: "s" });
  return [el("h3", { text: "Co-design: the objective" }),
    el("p", { id: "objective-text", text: "Objective, in seconds (lower is better): " + terms.join(" + ") + "." }),
    el("p", { class: "hint", text: payloadText }),
    el("p", { class: "hint", text: "Candidates and the initial design scored on the validation slews (the mission's "
      + "physics); the random designs' figures are the first design update's draws, on the training slews." }),
    el("div", { class: "table-wrap" }, table), el("div", { class: "curves" }, chart)];
}

// verification.json (evaluation.basilisk): the same slews flown in modsat and in Basilisk.
function verifyView(v) {
  const head = el("h3", { text: "Basilisk verification" });
  if (!v || v.available === false) {
    return [head, el("p", { class: "hint", text: (v && v.reason) || "no verification report" })];
  }
  const ctrls = [["policy", v.controllers.policy], ["PD baseline", v.controllers.pd_baseline]]
    .filter((c) => c[1] && c[1].available !== false);
  const cols = ctrls.flatMap(([, c]) => [["modsat", c.modsat], ["Basilisk", c.basilisk]]);
  const rows = [
    ["success (mission tolerance)", "success_rate", fmt.pct],
    ["success within 0.25 deg", "success_rate_0_25deg", fmt.pct],
    ["success within 1 deg", "success_rate_1deg", fmt.pct],
    ["median final error (deg)", "median_final_error_deg", fmt.num(4)],
    ["median settling (s)", "median_settling_time_s", fmt.num(2)],
    ["max peak rate (rad/s)", "max_peak_rate_rad_s", fmt.num(3)],
    ["rate-limit violations", "safety_violations", fmt.int],
  ];
  const table = el("table", { class: "eval verify" },
    el("thead", {},
      el("tr", {}, el("th", { text: "" }), ...ctrls.map(([name]) => el("th", { class: "num", colspan: "2", text: name }))),
      el("tr", {}, el("th", { text: "" }), ...cols.map((c) => el("th", { class: "num", text: c[0] })))),
    el("tbody", {}, ...rows.map(([name, key, f]) => el("tr", {}, el("th", { text: name }),
      ...cols.map((c) => el("td", { class: "num", text: f(c[1][key], c[1]) }))))));
  const notes = ctrls.map(([name, c]) => el("p", { class: "hint", text:
    `${name}: largest attitude difference modsat vs Basilisk ${c.max_attitude_difference_rad.toExponential(1)} rad`
    + ` over ${v.episodes} slews; ${c.same_success ? "the same slews succeed" : "the simulators disagree on success"}` }));
  const missing = v.controllers.policy && v.controllers.policy.available === false
    ? [el("p", { class: "hint", text: v.controllers.policy.reason })] : [];
  return [head, table, ...notes, ...missing];
}

function designLine(d) {
  if (!d) return null;
  const plural = (n, word) => `${n} ${word}${n === 1 ? "" : "s"}`;
  const parts = [plural(d.modules, "module"), plural(d.actuators, "actuator")];
  if (d.mass_kg != null) parts.push(`${d.mass_kg.toFixed(1)} kg`);
  if (d.principal_inertia_kgm2) parts.push("principal inertia " +
    d.principal_inertia_kgm2.map((v) => v.toFixed(4)).join(", ") + " kg m\u00b2");
  if (d.valid === false) parts.push("not a valid satellite");
  const grid = state.designs.get(String(state.selected));
  const pic = grid ? window.modsatCharts.designThumb(grid) : null;
  const line = el("p", { class: "hint", text: "Design: " + parts.join(", ") });
  return pic ? el("div", { class: "design-pic" }, pic, line) : line;
}

async function renderFiles(job, files) {
  const names = new Set(files.map((f) => f.name));
  const ul = $("downloads");
  ul.replaceChildren(...files.map((f) => el("li", {},
    el("a", { href: f.url, download: `modsat-job-${job.id}-${f.name}`, text: f.name }),
    el("span", { class: "hint", text: ` ${fmt.bytes(f.size)} (${f.kind})` }))));
  if (!files.length) ul.append(el("li", { class: "hint", text: "no files yet" }));
  if (files.some((f) => f.kind === "output")) {
    ul.prepend(el("li", { class: "archive" }, el("a", { id: "archive-link", href: `/api/jobs/${job.id}/archive.zip`,
      text: "all files (zip)" }), el("span", { class: "hint", text: " every output under its plain name, one folder" })));
  }

  // Before the awaits below, so the 3D buttons never show the previous job's (or a default) state.
  const has3d = names.has("design.json") && names.has("trajectories.json");
  const hasRec = names.has("evaluation.viser");
  $("view-live").disabled = !has3d || !(state.viewer && state.viewer.enabled);
  $("view-rec").disabled = !hasRec;
  $("view-note").textContent = !has3d ? "The 3D view is there once the run has succeeded."
    : !(state.viewer && state.viewer.enabled) ? "The live viewer is off on this server (--no-viewer); the recording still plays."
    : "Live: pick slews, play them, see the time plots; compare with another run side by side. "
      + "Recording: the stored replay of the evaluation slews (policy beside the PD baseline).";

  const evBox = $("evaluation");
  if (names.has("design.json") && !state.designs.get(String(job.id))) {
    const r = await api(`/api/jobs/${job.id}/artifacts/design.json`);
    if (r.ok && r.body && Array.isArray(r.body.grid)) state.designs.set(String(job.id), r.body.grid);
  }
  if (names.has("evaluation.json")) {
    const r = await api(`/api/jobs/${job.id}/artifacts/evaluation.json`);
    if (r.ok) state.reference = referenceFrom(r.body, job);
    flightWarning(r.ok ? r.body : null);
    evBox.replaceChildren(...(r.ok ? [designLine(job.evaluation && job.evaluation.design), evalTable(r.body),
      conditionsTable(r.body)]
      : [el("p", { class: "errors", text: errorText(r) })]).filter(Boolean));
  } else {
    flightWarning(null);
    evBox.replaceChildren(el("p", { class: "hint", text: TERMINAL.has(job.status)
      ? "no evaluation for this job" : "the Monte-Carlo evaluation comes when the run has finished" }));
  }
  const vBox = $("verification");
  vBox.hidden = !names.has("verification.json");
  vBox.replaceChildren();
  if (!vBox.hidden) {
    const r = await api(`/api/jobs/${job.id}/artifacts/verification.json`);
    vBox.replaceChildren(...(r.ok ? verifyView(r.body) : [el("p", { class: "errors", text: errorText(r) })]));
  }
  const toBox = $("trade-off"), cdBox = $("codesign");
  toBox.hidden = true;
  toBox.replaceChildren();
  cdBox.hidden = true;
  cdBox.replaceChildren();
  if (names.has("curve.json")) {
    const r = await api(`/api/jobs/${job.id}/artifacts/curve.json`);
    if (r.ok && r.body && Array.isArray(r.body.points)) state.curveFromFile = r.body.points;
    if (r.ok && r.body && Array.isArray(r.body.front) && r.body.front.length) {
      const s = names.has("spec.json") ? await api(`/api/jobs/${job.id}/artifacts/spec.json`) : null;
      toBox.replaceChildren(...tradeOffView(job, r.body, s && s.ok ? s.body : null));
      toBox.hidden = false;
    } else if (r.ok && r.body && Array.isArray(r.body.designs) && r.body.designs.some((d) => d.mean_objective_s != null)) {
      const spec = job.spec || {};
      cdBox.replaceChildren(...codesignView(r.body, spec, job.control_dt_s, state.designs.get(String(job.id))));
      cdBox.hidden = false;
    }
  }
  drawCurves();

  return has3d;
}

async function loadCompareOptions() {
  const r = await api("/api/jobs?status=succeeded&limit=100");
  const sel = $("compare");
  const keep = state.compare;
  sel.replaceChildren(el("option", { value: "", text: "(none)" }));
  if (r.ok) {
    for (const j of r.body.items) {
      if (String(j.id) === String(state.selected)) continue;
      sel.append(el("option", { value: j.id, text: `#${j.id} ${j.name || ""} (${shortAlgorithm(j.algorithm)})` }));
    }
  }
  sel.value = keep;
  if (sel.value !== keep) state.compare = "";
}

function showView(mode) {
  const id = state.selected;
  if (!id || !mode) {
    $("view-box").hidden = true;
    $("view-frame").removeAttribute("src");
    state.view = null;
    writeHash();
    return;
  }
  let src;
  if (mode === "live") {
    const q = new URLSearchParams({ run: id });
    if (state.compare) q.set("compare", state.compare);
    const proto = location.protocol === "https:" ? "wss" : "ws";
    const ws = `${proto}://${location.hostname}:${state.viewer.port}/?${q}`;
    src = "/viser-client/?websocket=" + encodeURIComponent(ws);
  } else {
    src = "/viser-client/?playbackPath=" + encodeURIComponent(`/api/jobs/${id}/artifacts/evaluation.viser`);
  }
  state.view = mode;
  $("view-live").classList.toggle("active", mode === "live");
  $("view-rec").classList.toggle("active", mode === "recording");
  $("view-box").hidden = false;
  if ($("view-frame").getAttribute("src") !== src) $("view-frame").src = src;
  writeHash();
}

async function selectJob(id, view) {
  id = String(id);
  const changed = id !== String(state.selected);
  state.selected = id;
  if (changed) {
    state.evalPoints = [];
    state.progress = newProgress();
    state.curveFromFile = null;
    state.reference = null;
    if (view === undefined) state.view = null;
  }
  if (view !== undefined) state.view = view;
  for (const tr of document.querySelectorAll("#job-rows tr")) tr.classList.toggle("selected", tr.dataset.id === id);
  if (state.detailStream) { state.detailStream.close(); state.detailStream = null; }
  const [jr, fr, mr] = await Promise.all([api(`/api/jobs/${id}`), api(`/api/jobs/${id}/artifacts`),
    api(`/api/jobs/${id}/metrics?after=0&limit=5000`)]);
  if (String(state.selected) !== id) return; // another job was picked meanwhile
  $("detail-empty").hidden = jr.ok;
  $("detail-body").hidden = !jr.ok;
  if (!jr.ok) {
    $("detail-empty").textContent = errorText(jr);
    return;
  }
  const job = jr.body;
  const read = await readProgress(id, mr);
  if (String(state.selected) !== id) return;
  state.progress = read.progress;
  state.evalPoints = read.evalPoints;
  renderHead(job);
  const has3d = await renderFiles(job, fr.ok ? fr.body : []);
  await loadCompareOptions();
  showView(has3d && (state.view === "live" ? !$("view-live").disabled : state.view === "recording" ? !$("view-rec").disabled : false)
    ? state.view : null);
  writeHash();
  if (!TERMINAL.has(job.status)) followJob(job, read.lastSeq);
}

// Every progress record of job `id`, a page at a time from the first `page`, folded into the running
// aggregates (noteRecord) and the curve's points; nothing else of a page is kept.
async function readProgress(id, page) {
  const progress = newProgress(), evalPoints = [];
  let r = page, lastSeq = 0;
  while (r.ok) {
    for (const m of r.body.items) {
      noteRecord(progress, m);
      if (m.eval) evalPoints.push(m.eval);
    }
    lastSeq = r.body.last_seq;
    if (!r.body.more || String(state.selected) !== id) break;
    r = await api(`/api/jobs/${id}/metrics?after=${lastSeq}&limit=5000`);
  }
  return { progress, evalPoints, lastSeq };
}

function followJob(job, after) {
  const id = String(job.id);
  state.detailStream = openEvents(id, after, {
    metrics: (m) => {
      if (String(state.selected) !== id) return;
      noteRecord(state.progress, m);
      const total = m.total_env_steps || job.progress.total_env_steps;
      renderProgress({ ...job.progress, env_steps: m.env_steps, total_env_steps: total, phase: m.phase,
        fraction: total ? Math.min(1, m.env_steps / total) : 0 }, m);
      if (m.eval) { state.evalPoints.push(m.eval); drawCurves(); }
    },
    status: (s) => { if (String(state.selected) === id) renderHead({ ...state.job, ...s }); },
    end: () => {
      if (String(state.selected) === id) { state.detailStream = null; selectJob(id); }
      loadJobs();
    },
  });
}

async function cancelSelected() {
  const r = await api(`/api/jobs/${state.selected}/cancel`, { method: "POST", headers: authHeaders() });
  if (!r.ok) { $("d-error").hidden = false; $("d-error").textContent = errorText(r); }
  selectJob(state.selected);
  loadJobs();
}

// ------------------------------------------------------------------ start

async function main() {
  $("token").value = localStorage.getItem("modsat.token") || "";
  $("token").addEventListener("change", () => localStorage.setItem("modsat.token", $("token").value.trim()));
  $("prev-page").addEventListener("click", () => { state.offset = Math.max(0, state.offset - PAGE_SIZE); loadJobs(); });
  $("next-page").addEventListener("click", () => { state.offset += PAGE_SIZE; loadJobs(); });
  $("status-filter").addEventListener("change", (e) => { state.status = e.target.value; state.offset = 0; loadJobs(); });
  $("preset").addEventListener("change", (e) => choosePreset(e.target.value));
  $("reset-btn").addEventListener("click", () => choosePreset($("preset").value));
  $("overrides").addEventListener("input", jsonToFields);
  $("submit-form").addEventListener("submit", submitForm);
  $("cancel-btn").addEventListener("click", cancelSelected);
  $("view-live").addEventListener("click", () => showView("live"));
  $("view-rec").addEventListener("click", () => showView("recording"));
  $("compare").addEventListener("change", (e) => {
    state.compare = e.target.value;
    if (state.view === "live") showView("live"); else writeHash();
  });

  window.addEventListener("hashchange", () => {  // a link to another job (#job=ID), or the address edited
    const h = readHash();
    if (h.job && h.job !== String(state.selected)) { state.compare = h.compare; selectJob(h.job, h.view || null); }
  });

  const v = await api("/api/viewer");
  state.viewer = v.ok ? v.body : { enabled: false };
  const h = readHash();
  state.compare = h.compare;
  await Promise.all([loadJobs(), loadPresets()]);
  if (h.job) await selectJob(h.job, h.view || null);
  setInterval(() => { if (!document.hidden) loadJobs(); }, 3000);
}

main();
