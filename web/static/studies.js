// Studies (POST /api/studies: one spec over seeds and methods): the list, and the picked study's
// learning-curve figure (reloaded while its jobs run), its table over seeds and its jobs, each a
// link that opens the job beside it. Uses the helpers of app.js ($, el, api, errorText).
"use strict";

const studyState = { selected: null, timer: null };

function pm(s, scale = 1, digits = 1) {
  if (!s || s.mean == null) return "-";
  const part = s.n < s.of ? ` (${s.n} of ${s.of} runs)` : "";  // e.g. a slew time where no slew landed
  return `${(scale * s.mean).toFixed(digits)} \u00b1 ${(scale * s.std).toFixed(digits)}${part}`;
}

function studyCounts(counts) {
  return Object.entries(counts).map(([k, v]) => `${v} ${k}`).join(", ") || "no jobs";
}

async function loadStudies() {
  const r = await api("/api/studies?limit=20");
  if (!r.ok) { $("studies-info").textContent = "cannot list the studies: " + errorText(r); return; }
  const rows = $("study-rows");
  rows.replaceChildren();
  for (const s of r.body.items) {
    const tr = el("tr", { id: "study-" + s.id, tabindex: "0", "data-id": s.id,
      class: String(s.id) === String(studyState.selected) ? "selected" : null },
      el("td", { class: "num", text: s.id }), el("td", { class: "name", text: s.name || "(no name)" }),
      el("td", { text: s.algorithms.join(" vs ") }), el("td", { class: "num", text: s.seeds.length }),
      el("td", { class: "counts", text: studyCounts(s.counts) }));
    tr.addEventListener("click", () => selectStudy(s.id));
    tr.addEventListener("keydown", (e) => { if (e.key === "Enter") selectStudy(s.id); });
    rows.append(tr);
  }
  $("studies-info").textContent = r.body.total
    ? `${r.body.items.length} of ${r.body.total}` : "no studies yet (POST /api/studies)";
}

function studyTable(agg) {
  const cols = [["method", null], ["finished", null], ["success @0.25 deg (%)", "success_0.25"],
    ["success @1 deg (%)", "success_1"], ["return", "return"], ["slew / bound", "slew_ratio"],
    ["PD on its designs @0.25 deg (%)", "pd"], ["modules", "modules"], ["actuators", "actuators"],
    ["mirror planes", "mirror_planes"]];
  const head = el("tr", {}, ...cols.map(([t]) => el("th", { text: t })));
  const body = Object.entries(agg.algorithms).map(([label, a]) => {
    const p = a.policy, m = a.design_means;
    const cells = [label, `${a.finished} of ${a.seeds.length}`, pm(p["success_0.25"], 100), pm(p.success_1, 100),
      pm(p.return), pm(p.slew_ratio, 1, 2), pm(a.pd_on_designs["success_0.25"], 100), pm(m.modules),
      pm(m.actuators), pm(m.mirror_planes)];
    return el("tr", { "data-method": label }, el("th", { text: cells[0] }), ...cells.slice(1).map((c) => el("td", { class: "num", text: c })));
  });
  return el("table", { class: "eval study-table" }, el("thead", {}, head), el("tbody", {}, ...body));
}

function studyJobs(jobs) {
  const rows = jobs.map((j) => {
    const ret = j.last_eval && j.last_eval.mean_return != null ? j.last_eval.mean_return.toFixed(1) : "";
    const pct = j.total_env_steps ? Math.round((100 * j.env_steps) / j.total_env_steps) : 0;
    const link = el("a", { href: `#job=${j.id}`, text: `#${j.id}` });
    link.addEventListener("click", () => $("detail").scrollIntoView({ block: "start" })); // app.js opens it
    return el("tr", {}, el("td", { class: "num" }, link),
      el("td", { text: j.algorithm }), el("td", { class: "num", text: j.seed }),
      el("td", {}, el("span", { class: "badge " + j.status, text: j.status })),
      el("td", { class: "num", text: pct + " %" }), el("td", { class: "num", text: ret }));
  });
  const head = el("tr", {}, ...["job", "method", "seed", "status", "progress", "eval return"].map((t) => el("th", { text: t })));
  return el("table", { class: "study-jobs" }, el("thead", {}, head), el("tbody", {}, ...rows));
}

async function selectStudy(id) {
  id = String(id);
  studyState.selected = id;
  clearTimeout(studyState.timer);
  for (const tr of document.querySelectorAll("#study-rows tr")) tr.classList.toggle("selected", tr.dataset.id === id);
  const r = await api(`/api/studies/${id}`);
  if (studyState.selected !== id) return; // another study was picked meanwhile
  $("study-body").hidden = false;
  if (!r.ok) { $("study-head").textContent = errorText(r); return; }
  const s = r.body;
  $("study-head").textContent = `Study ${s.id}: ${s.name || "(no name)"}, seeds ${s.seeds.join(", ")}, ${studyCounts(s.counts)}`;
  $("study-fig").src = `${s.figure_url}?at=${Date.now()}`; // a new figure as its runs report
  $("study-fig-link").href = s.figure_url;
  $("study-fig").alt = `learning curves of study ${s.id}, mean and std over seeds`;
  $("study-table").replaceChildren(studyTable(s.aggregate));
  $("study-jobs").replaceChildren(studyJobs(s.jobs));
  loadStudies(); // the list's counts too
  if (s.status !== "ended") studyState.timer = setTimeout(() => { if (studyState.selected === id) selectStudy(id); }, 5000);
}

loadStudies();
setInterval(() => { if (!document.hidden) loadStudies(); }, 10000);
